"""rl_zoo3 Optuna search: python scripts/optuna_search.py --help."""

from tendon2r_gym.studies.optuna_search import main

if __name__ == "__main__":
    main()
