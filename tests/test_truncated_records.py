"""A run folder's records cut short (a full disk, a copy stopped half way) are refused whole,
naming the file, wherever a resume reads them, on any executor: config.yaml (YAML cut at a
line end still parses, so it ends with a line of its own) and the JSON records."""

import re

import pytest
import yaml
from test_training import _tiny, _train

from tendon2r_gym.app.cli import train_main
from tendon2r_gym.artifacts.runs import CONFIG, CONFIG_END, CONFIG_HEAD, RunFolder, read_record

SEEDS = ("0", "1")
#: The records a --resume reads (config.yaml, then the summaries and evaluations).
RECORDS = (CONFIG, "run.json", "summary.json", "evaluations.json", "best_metrics.json",
           "pd_eval.json")  # fmt: skip


def _files(folder):
    return {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Two seeds of a tiny training: the records as tendon2r-train writes them."""
    tmp = tmp_path_factory.mktemp("trained")
    _train(_tiny(tmp), tmp / "run", "--seeds", *SEEDS)
    return tmp / "run"


@pytest.mark.parametrize("name", RECORDS)
def test_every_record_cut_short_anywhere_is_refused_naming_it(trained, name, tmp_path):
    """Each proper prefix of a record (at every byte, line ends included) is a ValueError
    naming the file; the whole record, with or without its last newline, reads."""
    text = (trained / "seed_0" / name).read_text()
    path = tmp_path / name
    whole = text.rstrip("\n")
    for end in (len(text), len(whole)):
        path.write_text(text[:end])
        assert read_record(path) == read_record(trained / "seed_0" / name)
    for end in range(len(whole)):
        path.write_text(text[:end])
        with pytest.raises(ValueError, match=rf"^{re.escape(str(path))} is corrupt: "):
            read_record(path)


def test_config_yaml_is_written_whole_and_an_earlier_one_still_reads(trained, tmp_path):
    """config.yaml opens with CONFIG_HEAD and ends with CONFIG_END; one written before them
    (no head) is read as it is."""
    text = (trained / "seed_0" / CONFIG).read_text()
    assert text.startswith(CONFIG_HEAD + "\n") and text.endswith("\n" + CONFIG_END + "\n")
    earlier = tmp_path / CONFIG
    values = read_record(trained / "seed_0" / CONFIG)
    earlier.write_text(yaml.safe_dump(values, sort_keys=False))
    assert read_record(earlier) == values


@pytest.mark.parametrize("workers", ["1", "2"])
@pytest.mark.parametrize("name", [CONFIG, "summary.json"])
def test_resume_of_a_record_cut_short_is_refused_naming_it_on_any_executor(
    trained, tmp_path, name, workers
):
    """seed_1's record cut at the line end half way: --resume (in one process or on two
    workers) is a ValueError naming the file and how to recover, before anything is
    written; today's config.yaml cut so would have resumed with defaults and trained 0
    steps."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    record = RunFolder(run / "seed_1").file(name)
    lines = record.read_text().splitlines(keepends=True)
    record.write_text("".join(lines[: len(lines) // 2]))
    before = _files(run)
    with pytest.raises(ValueError, match=rf"^{re.escape(str(record))} is corrupt: ") as err:
        train_main(["--run-dir", str(run), "--resume", "--workers", workers])
    assert "; to recover: " in str(err.value)
    assert _files(run) == before
