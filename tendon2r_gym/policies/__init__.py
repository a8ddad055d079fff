"""Policies: the controllers.  The PD and computed-torque baselines (baselines), the residual
wrapper that puts PD inside an env (residual), trained PPO models (learned) with their
observation history (history) and their float64 inference (inference)."""
