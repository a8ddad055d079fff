"""Nothing crashes: every corrupt model-side file (model zip, VecNormalize pkl, bundle.json) is
one ValueError that names it."""

import json
import shutil
import zipfile
from pathlib import Path

import gymnasium as gym
import pytest

import tendon2r_gym  # noqa: F401  (registers Tendon2R-v0)
from tendon2r_gym import cli
from tendon2r_gym.bundle import bundle_meta, bundled_model
from tendon2r_gym.files import load_model, load_vecnormalize
from tendon2r_gym.learned import PPOPolicy
from tendon2r_gym.presets import MODELS_DIR

REPO = Path(__file__).resolve().parents[1]
#: Two bundles of the default arm whose models observe different sizes (24 and 26 entries).
SMALL, OTHER = "default", "default_scratch"


def files_under(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> Path:
    """A copy of the bundled models (never the package's own)."""
    root = tmp_path_factory.mktemp("copy") / "models"
    shutil.copytree(MODELS_DIR, root)
    return root


@pytest.fixture
def runs(tmp_path) -> list[Path]:
    """Two finished run folders (seeds 0 and 1): copies of a bundle's seed folders."""
    out = []
    for seed in (0, 1):
        out.append(tmp_path / "runs" / f"seed_{seed}")
        shutil.copytree(MODELS_DIR / SMALL / f"seed_{seed}", out[-1])
    return out


# -- B: corrupt model-side files --------------------------------------------------------------
@pytest.fixture
def small(tmp_path) -> Path:
    """A copy of a small bundle: its primary seed and bundle.json."""
    root = tmp_path / "models"
    shutil.copytree(MODELS_DIR / SMALL, root / SMALL)
    return root


def truncate(fraction):
    def cut(path: Path) -> None:
        data = path.read_bytes()
        path.write_bytes(data[: int(len(data) * fraction)])

    return cut


def no_model(path: Path) -> None:
    path.unlink()
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("notes.txt", "no model here")


def swapped(path: Path) -> None:
    shutil.copy(MODELS_DIR / OTHER / "seed_0" / path.name, path)


CORRUPT = {
    "zip cut at 50%": ("best_model.zip", truncate(0.5), "is truncated"),
    "zip cut at 99.9%": ("best_model.zip", truncate(0.999), "is truncated"),
    "zip without a model": ("best_model.zip", no_model, "is not an SB3 model zip"),
    "zip of another bundle": ("best_model.zip", swapped,
                              r"does not match .*observation shape \(26,\) in the file, \(24,\)"),
    "pkl cut at 50%": ("best_model_vecnormalize.pkl", truncate(0.5), "is truncated"),
    "empty pkl": ("best_model_vecnormalize.pkl", truncate(0), "is truncated"),
    "pkl of another bundle": ("best_model_vecnormalize.pkl", swapped,
                              r"does not match .*observation shape \(26,\) in the file, \(24,\)"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(CORRUPT))
def test_a_corrupt_model_file_is_one_error_naming_it(small, case):
    name, damage, what = CORRUPT[case]
    path = small / SMALL / "seed_0" / name
    env = gym.make("Tendon2R-v0", preset="default")
    PPOPolicy.load(path.with_name("best_model.zip"), env)  # whole, it loads
    damage(path)
    with pytest.raises(ValueError, match=what) as err:
        PPOPolicy.load(path.with_name("best_model.zip"), env)
    assert str(path) in str(err.value) and "to recover: re-bundle it" in str(err.value)
    # tendon2r-evaluate's --model (and a fine-tune's --init-from, through trained_model).
    with pytest.raises(ValueError, match=what):
        cli.evaluate_main(["--policy", "ppo", "--model", str(path.with_name("best_model.zip")),
                           "--episodes", "1"])  # fmt: skip


def test_the_loaders_name_the_file(small):
    from stable_baselines3.common.vec_env import DummyVecEnv

    folder = small / SMALL / "seed_0"
    other = DummyVecEnv([lambda: gym.make("Tendon2R-v0", preset="default", preview_steps=2)])
    with pytest.raises(ValueError, match=r"best_model.zip does not load \(ValueError: Observ"):
        load_model(folder / "best_model.zip", env=other, device="cpu")
    truncate(0.5)(folder / "best_model.zip")
    with pytest.raises(ValueError, match="best_model.zip is truncated"):
        load_model(folder / "best_model.zip", device="cpu")
    swapped(folder / "best_model_vecnormalize.pkl")
    venv = DummyVecEnv([lambda: gym.make("Tendon2R-v0", preset="default")])
    with pytest.raises(ValueError, match=r"vecnormalize.pkl does not match .*\(26,\).*\(24,\)"):
        load_vecnormalize(folder / "best_model_vecnormalize.pkl", venv)


BUNDLE_JSON = {
    "not JSON": ("{garbage", "is not JSON"),
    "binary": (b"\xff\xfe\x00", "is not JSON"),
    "a list": ("[0, 1]", "is not a JSON object"),
    "missing a key": (json.dumps({"seeds": [0], "train_command": "", "command": ""}),
                      "is missing key 'primary_seed'"),
    "bad seeds": (json.dumps({"seeds": "0", "primary_seed": 0, "train_command": "",
                              "command": ""}), "seeds = '0' is not a list"),
    "primary not a seed": (json.dumps({"seeds": [0], "primary_seed": 3, "train_command": "",
                                       "command": ""}), "primary_seed = 3 is not among"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BUNDLE_JSON))
def test_a_corrupt_bundle_json_is_one_error_naming_it(small, case):
    text, what = BUNDLE_JSON[case]
    path = small / SMALL / "bundle.json"
    (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)
    for read in (lambda: bundle_meta(SMALL, small), lambda: bundled_model(SMALL, root=small)):
        with pytest.raises(ValueError, match=what) as err:
            read()
        assert str(path) in str(err.value) and "tendon2r-bundle --name default --replace" in str(
            err.value
        )
