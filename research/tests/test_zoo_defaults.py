"""The rl_zoo3 study runs end to end (a tiny budget; outputs, never figures)."""

import json
import math

import pytest
import yaml

from research.studies import zoo_defaults
from tests.reading import figures, rows_by_name


def test_zoo_defaults_end_to_end(tmp_path, short_episodes):
    out, runs = tmp_path / "out", tmp_path / "runs"
    result = zoo_defaults.main(
        ["--steps", "256", "--seeds", "0", "--out", str(out), "--run-dir", str(runs)]
    )
    saved = json.loads((out / "zoo_defaults.json").read_text())
    assert saved == json.loads(json.dumps(result))
    assert [r["env_id"] for r in saved["runs"]] == list(zoo_defaults.ENV_IDS)
    assert set(saved["pd"]) == set(zoo_defaults.ENV_IDS)
    for row in [*saved["runs"], *saved["pd"].values()]:
        assert len(row["rms_deg"]) == 2 and all(math.isfinite(x) for x in row["rms_deg"])
    assert saved["env_defaults"]["Tendon2R-v0"] != saved["env_defaults"]["Tendon2R-v1"]
    # rl_zoo3 trained on the entry copied from its own file, with the study's budget
    shipped = yaml.safe_load(zoo_defaults.zoo_file().read_text())[zoo_defaults.ZOO_ENTRY]
    for run in saved["runs"]:
        conf = yaml.safe_load((runs / run["env_id"] / "seed_0" / "ppo.yml").read_text())
        assert conf == {run["env_id"]: {**shipped, "n_timesteps": 256}}
    md = (out / "zoo_defaults.md").read_text()
    shown = rows_by_name(md)
    assert list(shown) == list(zoo_defaults.ENV_IDS)
    for run in saved["runs"]:
        cells = shown[run["env_id"]]
        assert figures(cells[2]) == [run["seed"]]
        assert figures(cells[3]) == pytest.approx(run["rms_deg"], abs=5e-4)
    words = saved["command"].split()
    assert words[words.index("--steps") + 1] == "256" and saved["command"] in md
    with pytest.raises(ValueError, match="run_dir = .* without an earlier run"):
        zoo_defaults.main(["--steps", "256", "--env-ids", "Tendon2R-v0", "--out", str(out),
                           "--run-dir", str(runs)])  # fmt: skip


def test_an_unknown_zoo_entry_names_the_field():
    with pytest.raises(ValueError, match="zoo_entry = 'NoSuchEnv-v0' is invalid"):
        zoo_defaults.zoo_hyperparams("NoSuchEnv-v0", 256)
