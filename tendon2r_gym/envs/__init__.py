"""The Gymnasium envs: the experiment-file record (EnvConfig), the control steps and sensing an
env derives from it (Timing), the task's formulas shared by both envs (Formulas), the single env
and the native vector env (mujoco.batch)."""
