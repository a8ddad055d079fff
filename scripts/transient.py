"""Transient study: python scripts/transient.py --help (tendon2r_gym.studies.transient)."""

from tendon2r_gym.studies.transient import main

if __name__ == "__main__":
    main()
