"""Arm parameters -> MuJoCo model: cable routings, the mechanism's fields, the compiled model
(MjSpec), the tendons' force map, the realism effects and the integrator's stability limits."""
