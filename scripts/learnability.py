"""Learnability study: python scripts/learnability.py --help (tendon2r_gym.studies.learnability)."""

from tendon2r_gym.studies.learnability import main

if __name__ == "__main__":
    main()
