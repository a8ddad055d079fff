"""The console commands (tendon2r-*), the benchmark and its plots."""
