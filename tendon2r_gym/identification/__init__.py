"""Identify your arm: recordings of a physical (or simulated) arm and the fit of its realism
fields (docs: Identify your arm).  It needs the simulation and the experiment record only: the
excitation a user records, which runs policies, is the identify command's
(tendon2r_gym.app.excitation)."""
