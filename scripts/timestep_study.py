"""Time step study: python scripts/timestep_study.py --help (tendon2r_gym.studies.timestep)."""

from tendon2r_gym.studies.timestep import main

if __name__ == "__main__":
    main()
