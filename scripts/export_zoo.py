"""Writes configs/rl_zoo3/ppo.yml from configs/ppo.yaml (tendon2r_gym.training.zoo)."""

from pathlib import Path

from tendon2r_gym.training.zoo import zoo_file

if __name__ == "__main__":
    out = Path(__file__).resolve().parent.parent / "configs" / "rl_zoo3" / "ppo.yml"
    out.write_text(zoo_file())
    print("wrote", out)
