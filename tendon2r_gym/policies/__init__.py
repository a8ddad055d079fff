"""Policies: the PD and computed-torque baselines, trained PPO models (their files, run
folders, bundles and float64 inference) and the registry of shipped models."""
