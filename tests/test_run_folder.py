"""A training run's folder under failures: a resume of nothing, refused starts, corrupt records,
a folder that cannot be written mid-training, and the accounting of a killed run's resume."""

import errno
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import zipfile

import pytest
import yaml
from stable_baselines3 import PPO
from test_training import _tiny, _train

from tendon2r_gym.app.args import parse
from tendon2r_gym.app.cli import TrainArgs, experiment, train_main
from tendon2r_gym.artifacts.runs import REMOVED, RunFolder, saved_steps, training_record
from tendon2r_gym.policies.residual import Residual
from tendon2r_gym.training import Experiment, Hyperparams, manager
from tendon2r_gym.training.records import RunWriteError, training_lock


def _files(folder):
    """Every file under ``folder`` with its bytes (what a refused command must not change)."""
    return {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_resume_of_a_folder_without_runs_is_refused_naming_it(tmp_path):
    for folder in (tmp_path / "never_started", tmp_path):  # missing, and present without runs
        with pytest.raises(
            ValueError, match=rf"run_dir = '{folder}' .*holds none: without --resume"
        ):
            train_main(["--run-dir", str(folder), "--resume"])
    assert not (tmp_path / "never_started").exists()
    assert list(tmp_path.iterdir()) == []


def test_a_refused_start_leaves_the_run_folder_as_it_was(tmp_path):
    """A start refused for its init_from writes nothing (no config.yaml, run.json, command.txt
    or seeds_summary.json), so the same command with a good source is not refused."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "notes.txt").write_text("mine")
    before = _files(run)
    for source in ("nope", str(tmp_path / "missing.zip")):
        with pytest.raises(ValueError, match="init_from = "):
            _train(_tiny(tmp_path), run, "--init-from", source, "--seeds", "0", "1")
        assert _files(run) == before
    exp = experiment(parse(TrainArgs, ["--config", str(_tiny(tmp_path)), "--hyperparams", "tiny",
                                       "--run-dir", str(run)]))  # fmt: skip
    assert [exp.run_folder(0).read_config()] == [None], "the folder holds no run"


# -- corrupt records ---------------------------------------------------------------------------
def _started_run(tmp_path):
    """A run folder as a killed training leaves it (its records and one checkpoint), written
    without training: seed_0 of the returned base."""
    base = tmp_path / "run"
    run = RunFolder(base / "seed_0")
    run.checkpoints.mkdir(parents=True)
    run.write_config(yaml.safe_load(_tiny(tmp_path).read_text())["tiny"])
    run.write_json("run.json", {"seed": 0, "env_kwargs": {}, "env_config": {}})
    run.write_json("evaluations.json", [{"timesteps": 128, "wall_time_s": 1.0,
                                         "rms_deg": [0.1, 0.1], "beats_pd": False}])  # fmt: skip
    run.write_json("summary.json", {"timesteps": 128, "wall_time_s": 1.0, "segments": [
        {"start_timesteps": 0, "end_timesteps": 128, "wall_time_s": 1.0}]})  # fmt: skip
    with zipfile.ZipFile(run.checkpoints / "rl_model_128_steps.zip", "w") as z:
        z.writestr("data", json.dumps({"num_timesteps": 128}))
    (run.checkpoints / "rl_model_vecnormalize_128_steps.pkl").write_bytes(b"stats")
    run.file("best_model.zip").write_bytes(b"model")
    run.file("best_model_vecnormalize.pkl").write_bytes(b"stats")
    return base, run


CORRUPT = [
    ("config.yaml", "n_envs: [2\n", r"it is not valid YAML \(while parsing"),
    ("config.yaml", "\n", "it is empty"),
    ("config.yaml", "- 1\n- 2\n", "its top level is a list, not a mapping"),
    ("config.yaml", "n_envs: 2\n", r"hyperparameters are invalid .*also has \['env_kwargs'"),
    ("config.yaml", "{}", r"hyperparameters are invalid .*also has"),
    ("summary.json", "{\"timesteps\": 1", r"it is not valid JSON \(Expecting"),
    ("summary.json", b"\xff\xfe{}", "it is not UTF-8 text"),
    ("summary.json", "[]", "its top level is a list, not a mapping"),
    ("summary.json", '{"timesteps": 128, "wall_time_s": 1.0}', "it lacks 'segments'"),
    ("summary.json", '{"timesteps": 1, "wall_time_s": 1, "segments": [{"start_timesteps": 0}]}',
     "segments\\[0\\] lacks 'end_timesteps'"),
    ("evaluations.json", "\x00\x01garbage", r"it is not valid JSON"),
    ("evaluations.json", "{}", "its top level is a dict, not a list"),
    ("evaluations.json", '[{"timesteps": 1, "wall_time_s": 1, "rms_deg": [1, 1]}]',
     "row 0 lacks 'beats_pd'"),
    ("evaluations.json", '[{"timesteps": "x", "wall_time_s": 1, "rms_deg": [], "beats_pd": 0}]',
     "row 0's timesteps = 'x' is not a number"),
    ("best_metrics.json", '{"rms_deg": [1, 1]}', "it lacks 'timesteps'"),
]  # fmt: skip


@pytest.mark.parametrize(("name", "text", "what"), CORRUPT)
def test_resume_on_a_corrupt_record_names_the_file_and_the_way_back(tmp_path, name, text, what):
    """--resume on a corrupt record: a ValueError naming the file, what is wrong with it and
    how to recover, and the run folder as it was."""
    base, run = _started_run(tmp_path)
    if isinstance(text, bytes):
        run.file(name).write_bytes(text)
    else:
        run.file(name).write_text(text)
    before = _files(base)
    where = re.escape(str(run.file(name)))
    with pytest.raises(ValueError, match=rf"^{where}( is corrupt)?: ") as err:
        train_main(["--run-dir", str(base), "--resume"])
    message = str(err.value)
    assert re.search(what, message), message
    assert "; to recover: " in message and "\n" not in message
    assert _files(base) == before


@pytest.mark.parametrize(
    ("text", "what"),
    [("{", "it is not valid JSON"), ('[{"seed": 0}]', "its top level is a list, not a mapping"),
     ('{"seed": 0, "env_kwargs": {}}', "it lacks 'env_config'"),
     ('{"seed": 0, "env_kwargs": [], "env_config": {}}', "env_kwargs is a list, not a mapping")],
)  # fmt: skip
def test_a_corrupt_run_json_is_named_where_a_model_is_read(tmp_path, text, what):
    """run.json beside a model (read by --init-from, the bundles and the evaluations): a
    ValueError naming it, and a refused fine-tune writes nothing."""
    _, run = _started_run(tmp_path)
    run.file("run.json").write_text(text)
    model = run.file("best_model.zip")
    where = re.escape(str(run.file("run.json")))
    with pytest.raises(ValueError, match=rf"^{where} is corrupt: {what}.*; to recover: restore"):
        training_record(model)
    with pytest.raises(ValueError, match=rf"{where} is corrupt: {what}"):
        _train(_tiny(tmp_path), tmp_path / "tuned", "--init-from", str(model))
    assert not (tmp_path / "tuned").exists()


# -- a run folder that cannot be written ---------------------------------------------------------
#: Runs tendon2r-train, after whose first checkpoint the run folder (argv[1]) fails every write
#: with errno argv[2]: as after chmod -R a-w (which does not stop root, so it is simulated at
#: the level of open, os.replace, ...), or a full disk; errno 0 stands for a SIGKILL there.
DRIVER = """
import builtins, io, os, signal, sys
from tendon2r_gym.training import manager

folder, err = os.path.abspath(sys.argv[1]), int(sys.argv[2])
del sys.argv[1:3]

def blocked(path):
    if not isinstance(path, (str, bytes, os.PathLike)):
        return False
    return os.path.abspath(os.fsdecode(path)).startswith(folder)

def fail(path):
    raise OSError(err, os.strerror(err), os.fsdecode(path))

def guard_open(real):
    def opener(file, mode="r", *args, **kwargs):
        if blocked(file) and any(c in mode for c in "wax+"):
            fail(file)
        return real(file, mode, *args, **kwargs)
    return opener

def guard(real):
    def call(path, *args, **kwargs):
        if blocked(path):
            fail(path)
        return real(path, *args, **kwargs)
    return call

checkpoint = manager.Segment.checkpoint

def after_checkpoint(self, steps):
    checkpoint(self, steps)
    if err == 0:
        os.kill(os.getpid(), signal.SIGKILL)
    builtins.open, io.open = guard_open(builtins.open), guard_open(io.open)
    for name in ("replace", "rename", "mkdir", "makedirs", "remove", "unlink"):
        setattr(os, name, guard(getattr(os, name)))

manager.Segment.checkpoint = after_checkpoint
from tendon2r_gym.app.cli import train
train()
"""


def _run_cli(tmp_path, err, config, *argv):
    """Runs tendon2r-train with DRIVER's failure of tmp_path/run; returns the process."""
    env = {**os.environ, "MUJOCO_GL": "egl"}
    cmd = [sys.executable, "-W", "ignore", "-c", DRIVER, str(tmp_path / "run"), str(err),
           "--config", str(config), "--hyperparams", "tiny", "--run-dir", str(tmp_path / "run"),
           *argv]  # fmt: skip
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)


def test_a_folder_that_cannot_be_written_stops_training_with_one_line(tmp_path):
    """The run folder turns read-only after the first checkpoint: the command exits 2 with one
    line (no traceback, TensorBoard's writer thread's included) naming the folder, the OS
    error and the checkpoint a --resume continues from (last_model could not be written),
    which loads.  (A full disk: the next test.)"""
    err = errno.EACCES
    proc = _run_cli(tmp_path, err, _tiny(tmp_path, steps=2048))
    assert proc.returncode == 2, proc.stderr[-3000:]
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, proc.stderr[-3000:]  # one line: no traceback of any thread
    run = RunFolder(tmp_path / "run" / "seed_0")
    assert lines[0].startswith(f"error: writing to the run folder {run.path} failed at ")
    assert str(OSError(err, os.strerror(err))) in lines[0]  # the OS error, as Python states it
    (kept, _), *_ = run.checkpoint_candidates()
    assert kept.parent == run.checkpoints and not run.file("last_model.zip").exists()
    assert lines[0].endswith(
        f"--resume continues from {kept.relative_to(run.path)} ({saved_steps(kept)} steps)"
    )
    assert PPO.load(kept).num_timesteps == saved_steps(kept) > 0


def test_a_failed_write_keeps_the_last_state_and_the_run_resumes(tmp_path, monkeypatch):
    """A full disk while recording an evaluation: training stops with a RunWriteError (a
    ValueError: the command's one-line error) naming the folder and the OS error, after
    saving last_model where the run stood, from which --resume continues."""
    from tendon2r_gym.artifacts.runs import RunFolder as Folder

    append = Folder.append_evaluation

    def full_disk_on_the_second(self, row):
        if row["timesteps"] > 128:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self.file("x.tmp")))
        append(self, row)

    config, base = _tiny(tmp_path, steps=512), tmp_path / "run"
    monkeypatch.setattr(Folder, "append_evaluation", full_disk_on_the_second)
    with pytest.raises(RunWriteError, match=r"No space left on device") as err:
        _train(config, base)
    assert isinstance(err.value, ValueError)
    run = RunFolder(base / "seed_0")
    steps = saved_steps(run.file("last_model.zip"))
    assert run.read_json("summary.json")["timesteps"] == steps > 128
    assert f"continues from last_model.zip ({steps} steps)" in str(err.value)
    monkeypatch.undo()
    resumed = _train(config, base, "--resume")["runs"][0]
    assert resumed["segments"][1]["start_timesteps"] == steps
    assert resumed["timesteps"] >= 512 and not resumed["interrupted"]


def test_the_writer_thread_of_tensorboard_keeps_quiet_and_its_error_is_raised(
    tmp_path, monkeypatch
):
    """TensorBoard's writer thread failing to write reaches no thread excepthook (which
    prints a traceback) inside quiet_writer_threads; the writing thread raises its error.
    Another thread's error still does."""
    import io
    import threading

    from torch.utils.tensorboard import SummaryWriter

    from tendon2r_gym.training.callbacks import quiet_writer_threads

    reported = []
    monkeypatch.setattr(threading, "excepthook", lambda args: reported.append(args.exc_type))
    real = io.open

    def read_only(file, mode="r", *args, **kwargs):
        if "a" in mode:
            raise PermissionError(errno.EACCES, "Permission denied", str(file))
        return real(file, mode, *args, **kwargs)

    with quiet_writer_threads():
        writer = SummaryWriter(str(tmp_path / "tb"))
        with monkeypatch.context() as m:
            m.setattr(io, "open", read_only)
            with pytest.raises(PermissionError):
                for step in range(1000):
                    writer.add_scalar("x", 1.0, step)
                    writer.flush()
        other = threading.Thread(target=lambda: 1 / 0)
        other.start()
        other.join()
    assert reported == [ZeroDivisionError]


# -- a killed run's resume -------------------------------------------------------------------------
def test_a_killed_runs_resume_counts_every_segment_and_keeps_the_evaluation_grid(tmp_path):
    """SIGKILL right after the first checkpoint (320 steps, off the 128-step evaluation
    grid), then --resume: summary.json counts the killed segment's steps and wall time as
    recorded at its checkpoint, and the evaluations fall on every multiple of eval_freq of the
    run's steps (plus the final one), their wall times rising across the segments."""
    config = _tiny(tmp_path, steps=768)
    cfg = yaml.safe_load(config.read_text())
    cfg["tiny"].update(checkpoint_freq=320, checkpoint_minutes=60)
    config.write_text(yaml.safe_dump(cfg))
    proc = _run_cli(tmp_path, 0, config)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-3000:]
    run = RunFolder(tmp_path / "run" / "seed_0")
    killed = run.read_json("summary.json")["segments"]
    assert [(s["end_timesteps"], s["interrupted"]) for s in killed] == [(320, True)]
    assert not run.file("last_model.zip").exists(), "the kill saved nothing more"
    summary = _train(config, tmp_path / "run", "--resume")["runs"][0]
    first, second = summary["segments"]
    assert first == killed[0]
    assert second["start_timesteps"] == 320 and not second["interrupted"]
    assert summary["wall_time_s"] == round(first["wall_time_s"] + second["wall_time_s"], 1)
    assert first["wall_time_s"] > 0
    rows = run.read_json("evaluations.json")
    steps = [r["timesteps"] for r in rows]
    grid = [s for s in steps if s % 128 == 0]
    assert grid == list(range(128, summary["timesteps"] + 1, 128)), steps
    assert set(steps) - set(grid) <= {summary["timesteps"]}, steps
    walls = [r["wall_time_s"] for r in rows]
    assert walls == sorted(walls) and walls[2] >= first["wall_time_s"], walls


def test_a_folder_that_another_process_trains_is_refused_and_freed_when_it_ends(tmp_path):
    """A --resume while another process trains the folder (it holds the folder's lock) is a
    ValueError naming the seed folder, and writes nothing; once that process has ended (here:
    killed, as a crash would), the folder can be taken again."""
    base, run = _started_run(tmp_path)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\n"
         "from tendon2r_gym.artifacts.runs import RunFolder\n"
         "from tendon2r_gym.training.records import training_lock\n"
         "with training_lock([RunFolder(sys.argv[1])]):\n"
         "    print('held', flush=True)\n    time.sleep(120)\n", str(run.path)],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        before = _files(tmp_path)
        where = re.escape(f"run_dir = '{run.path}' is invalid")
        with pytest.raises(ValueError, match=rf"^{where}.*no other process is training"):
            train_main(["--run-dir", str(base), "--resume"])
        assert _files(tmp_path) == before
    finally:
        holder.kill()
        holder.wait()
    with training_lock([run]):
        pass


def test_the_plan_of_a_run_is_checked_for_every_seed_before_any_trains(tmp_path):
    """Experiment.train checks every seed's run before training the first: a corrupt summary
    in seed 1 refuses the resume of both, and seed 0 is not trained."""
    base, run0 = _started_run(tmp_path)
    seed1 = RunFolder(shutil.copytree(run0.path, base / "seed_1"))
    seed1.file("summary.json").write_text("{")
    before = _files(base)
    exp = Experiment.resume(base)
    assert exp.seeds == [0, 1]
    with pytest.raises(ValueError, match="seed_1/summary.json is corrupt"):
        exp.train(resume=True)
    assert _files(base) == before
    assert isinstance(manager.recorded_hyperparams(run0), Hyperparams)


# -- records of removed training options ---------------------------------------------------------
#: A value of each removed option (REMOVED) that a run trained with it on.
ON = {
    "zero_obs": ["error_log"],
    "hide_from_critic": ["arm"],
    "smoothing": {"temporal": 0.03, "spatial": 0.1, "sigma": 0.05, "samples": 512},
    "residual_relative_to": "need",
}


#: Each removed option off, as a run trained before it went recorded it in config.yaml and
#: run.json (the pull-only generalist of 0.5.0 recorded exactly these).
RECORDED_OFF = {
    "zero_obs": [],
    "hide_from_critic": [],
    "smoothing": {"temporal": 0.0, "spatial": 0.0, "sigma": 0.05, "samples": 512},
    "residual_relative_to": "range",
}


def _old_run(tmp_path, config=(), meta=()):
    """seed_0 of a run of the entry ``default`` as a version with the removed options recorded
    it (each off), with ``config`` and ``meta`` on top of its config.yaml and run.json."""
    hp = Hyperparams.from_entry("default")
    run = RunFolder(tmp_path / "run" / "seed_0")
    off = RECORDED_OFF
    run.write_config({**hp.to_dict(), **off, **dict(config)})
    meta = {**hp.residual.to_record(), **off, "seed": 0, "env_kwargs": hp.env_kwargs,
            "env_config": {}, **dict(meta)}  # fmt: skip
    run.write_json("run.json", meta)
    run.file("best_model.zip").write_bytes(b"model")
    run.file("best_model_vecnormalize.pkl").write_bytes(b"stats")
    return hp, run


def test_each_removed_option_is_tested_on_and_recorded_off():
    assert set(ON) == set(REMOVED) == set(RECORDED_OFF)


def test_a_record_holding_the_removed_options_off_loads_and_resumes_as_before(tmp_path):
    """config.yaml and run.json of a run trained before the options went: read without them,
    the run's hyperparameters are its entry's, it resumes with them and its residual is the
    entry's."""
    hp, run = _old_run(tmp_path)
    assert set(REMOVED) <= set(yaml.safe_load(run.file("config.yaml").read_text()))
    for read in (run.read_config(), run.read_json("run.json")):
        assert not set(REMOVED) & set(read)
    assert manager.recorded_hyperparams(run) == hp
    assert Experiment.resume(run.path.parent).hyperparams == hp
    assert Residual.from_record(training_record(run.file("best_model.zip"))) == hp.residual


@pytest.mark.parametrize("key", sorted(ON))
@pytest.mark.parametrize("name", ["config.yaml", "run.json"])
def test_a_record_holding_a_removed_option_on_is_refused_naming_file_key_and_value(
    tmp_path, key, name
):
    """A run that trained with a removed option on is not read as if it had been off: its
    config.yaml (a resume) or run.json (a fine-tune from its model) is a ValueError naming the
    record, the option and its value, and nothing is written."""
    _, run = _old_run(tmp_path, **{"config" if name == "config.yaml" else "meta": {key: ON[key]}})
    config, before = _tiny(tmp_path), _files(tmp_path)
    where = re.escape(f"{run.file(name)}: {key} = {ON[key]!r} is invalid; allowed: ")
    match = rf"^{where}.*no longer has the option {key} .*research/results/"
    if name == "config.yaml":
        with pytest.raises(ValueError, match=match):
            run.read_config()
        with pytest.raises(ValueError, match=match):
            train_main(["--run-dir", str(run.path.parent), "--resume"])
    else:
        model = run.file("best_model.zip")
        with pytest.raises(ValueError, match=match):
            training_record(model)
        with pytest.raises(ValueError, match=match):
            _train(config, tmp_path / "tuned", "--init-from", str(model))
    assert _files(tmp_path) == before
