"""Speed benchmark: python scripts/bench_speed.py --help (tendon2r_gym.studies.speed)."""

from tendon2r_gym.studies.speed import main

if __name__ == "__main__":
    main()
