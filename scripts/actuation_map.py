"""Actuation map: python scripts/actuation_map.py --help (tendon2r_gym.studies.actuation_map)."""

from tendon2r_gym.studies.actuation_map import main

if __name__ == "__main__":
    main()
