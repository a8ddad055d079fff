"""Arm sweep: python scripts/arm_sweep.py --help (tendon2r_gym.studies.arm_sweep)."""

from tendon2r_gym.studies.arm_sweep import main

if __name__ == "__main__":
    main()
