"""Stability limits: python scripts/stability_limits.py --help."""

from tendon2r_gym.studies.stability_limits import main

if __name__ == "__main__":
    main()
