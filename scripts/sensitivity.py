"""Sensitivity study: python scripts/sensitivity.py --help (tendon2r_gym.studies.sensitivity)."""

from tendon2r_gym.studies.sensitivity import main

if __name__ == "__main__":
    main()
