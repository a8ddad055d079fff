"""Generalist study: python scripts/generalist.py --help (tendon2r_gym.studies.generalist)."""

from tendon2r_gym.studies.generalist import main

if __name__ == "__main__":
    main()
