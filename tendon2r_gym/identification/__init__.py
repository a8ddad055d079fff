"""Identify your arm: recordings of a physical (or simulated) arm, the excitation to record, and
the fit of its realism fields (docs: Identify your arm)."""
