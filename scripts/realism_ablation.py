"""Realism ablation: python scripts/realism_ablation.py --help
(tendon2r_gym.studies.realism_ablation)."""

from tendon2r_gym.studies.realism_ablation import main

if __name__ == "__main__":
    main()
