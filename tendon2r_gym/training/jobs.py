"""One training job: (hyperparameters, seed) -> the run folder ``base/seed_<n>/`` and its
summary, the same on every executor (tendon2r_gym.training.executors).

``train_seed`` trains exactly one seed with the run owner's own steps (manager.plan_run,
then manager.train_planned: the same folder, checkpoints, summaries and ``--resume``), with
torch and BLAS pinned to the run's ``torch_threads``.  ``run_seed_job`` is what an executor
runs: where the driver's run folder is visible (this machine, or a shared file system: the
driver's marker file is found there), the job trains in it, so that a job run again after a
lost node continues from the last checkpoint; elsewhere it trains in a temporary folder of its
own, seeded with what the driver sent (the seed folder to continue, the experiment file the
hyperparameters name), and returns the finished folder whole, which the driver puts in place
(``install_folder``: written beside it, then renamed).  A Ctrl-C of a training ends the job
with its state saved (``interrupted``), not an exception, so that the driver keeps it.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any

from tendon2r_gym.artifacts.runs import RunFolder, model_files, seed_dir, stem_of
from tendon2r_gym.training.executors import Executor, InProcess, pin_threads
from tendon2r_gym.training.hyperparams import Hyperparams
from tendon2r_gym.training.records import training_lock

if TYPE_CHECKING:
    from tendon2r_gym.training.manager import Experiment, RunPlan

#: The driver's marker in the base folder: a job that reads it sees the driver's files.
MARKER_PREFIX = ".driver-"
#: A job's marker in its seed folder while it trains there: found by a job run again (a lost
#: node), which then continues from the last checkpoint.
ATTEMPT_PREFIX = ".attempt-"


@dataclass(frozen=True)
class SeedSpec:
    """What every seed of a training command shares: the hyperparameters, where the runs go
    and how the driver can be seen."""

    hyperparams: Hyperparams
    base: str  # the run folder of the command (absolute, as the driver sees it)
    resume: bool = False  # continue a seed that has a saved state
    command: str = ""
    progress_bar: bool = False
    cwd: str = ""  # the driver's working directory: relative paths of the hyperparameters
    # "": train in base (local workers); else the name of the driver's marker in base
    # (base/.driver-<token>): a job that finds it trains in base, one that does not (or any
    # job, without shared_files) in a folder of its own, which it sends back
    token: str = ""
    shared_files: bool = True
    # For a node that does not see the driver's files: the files the hyperparameters name
    # (path relative to cwd -> bytes).
    inputs: Mapping[str, bytes] = field(default_factory=dict)
    trust_pickle: bool = False  # the driver's --trust-pickle (artifacts.files.trusting_pickle)


@dataclass(frozen=True)
class SeedJob:
    """One seed of a command, as an executor runs it."""

    spec: SeedSpec
    seed: int
    # For a node that does not see the driver's files: the seed folder to continue.
    folder: Mapping[str, bytes] | None = None


@dataclass
class SeedResult:
    """What a job returns: its run's summary (None if it was stopped before training), and,
    from a node that does not see the driver's files, the run folder (relative path ->
    bytes)."""

    seed: int
    summary: dict[str, Any] | None
    interrupted: bool = False
    folder: dict[str, bytes] | None = None


def train_seed(spec: SeedSpec, seed: int, base: str | Path | None = None) -> dict[str, Any]:
    """Trains one seed in ``base/seed_<n>/`` (``base``: default ``spec.base``) and returns its
    summary: the run owner's plan_run and train_planned, torch and BLAS pinned to the run's
    ``torch_threads``.  A resume continues the newest saved state; a job run again (its
    attempt marker found) continues from the state the lost attempt saved, or starts again
    clean if it saved none.  Ctrl-C saves, then raises KeyboardInterrupt (train_planned)."""
    pin_threads(spec.hyperparams.torch_threads)
    from tendon2r_gym.llvm import load_triton

    load_triton()  # before torch (tendon2r_gym.training's own order)
    from tendon2r_gym.artifacts.files import trusting_pickle

    with trusting_pickle(spec.trust_pickle):
        return _train_seed(spec, seed, base)


def _train_seed(spec: SeedSpec, seed: int, base: str | Path | None) -> dict[str, Any]:
    from tendon2r_gym.training.manager import plan_run, train_planned

    run = RunFolder(seed_dir(base if base is not None else spec.base, seed))
    attempt = run.file(f"{ATTEMPT_PREFIX}{spec.token}") if spec.token else None
    again = attempt is not None and attempt.is_file()
    if again and not spec.resume and not run.checkpoint_candidates():
        _clear(run.path, keep=attempt)  # the lost attempt's records, with nothing to continue
    resume = bool(run.checkpoint_candidates()) and (spec.resume or again)
    plan = plan_run(spec.hyperparams, run, seed, resume)
    if attempt is not None:
        run.path.mkdir(parents=True, exist_ok=True)
        attempt.write_text(f"{os.getpid()}\n")
    try:
        return train_planned(plan, spec.command, spec.progress_bar)
    finally:
        if attempt is not None:
            with contextlib.suppress(OSError):
                attempt.unlink(missing_ok=True)


def train_experiment(
    exp: Experiment, resume: bool = False, executor: Executor | None = None
) -> dict[str, Any]:
    """Trains the seeds of ``exp`` (continuing those with a saved state if ``resume``) on
    ``executor`` and writes SEEDS_SUMMARY: in this process one after another (None,
    InProcess: ``Experiment.train``), or one job per seed (``run_seed_job``) on local
    workers or a Ray cluster.  Every seed is checked before anything is written
    (``Experiment.plan``) and its folder held by this process from the start.  A Ctrl-C
    stops every job (each saves its state), writes the summary of the finished seeds, then
    re-raises; a job's error names its seed, after the other jobs end."""
    if executor is None or isinstance(executor, InProcess):
        return exp.train(resume)
    plans = exp.plan(resume)
    results: dict[int, dict[str, Any]] = {}  # by the seed's index
    with training_lock([plan.run for plan in plans]), contextlib.ExitStack() as held:
        try:
            _run_jobs(exp, plans, resume, executor, results, held)
        except BaseException:
            exp.record_seeds([results[i] for i in sorted(results)], failing=True)
            raise
    return exp.record_seeds([results[i] for i in sorted(results)])


def _run_jobs(
    exp: Experiment,
    plans: list[RunPlan],
    resume: bool,
    executor: Executor,
    results: dict[int, dict[str, Any]],
    held: contextlib.ExitStack,
) -> None:
    """Runs one job per planned seed: each finished job's summary goes into ``results`` as it
    ends, and a run folder that a job sent back (from a node that does not see this one's
    files) is put in place then.  Raises KeyboardInterrupt after the jobs if one was stopped
    by Ctrl-C."""
    from tendon2r_gym.artifacts.files import trusted

    remote = bool(getattr(executor, "remote", False))
    shared = bool(getattr(executor, "shared_files", True))
    cwd, base = Path.cwd(), exp.base.resolve()
    spec = SeedSpec(
        exp.hyperparams,
        str(base),
        resume,
        exp.command,
        progress_bar=False,  # one bar per job would garble the terminal
        cwd=str(cwd),
        token=held.enter_context(driver_marker(base, shared)) if remote else "",
        shared_files=shared,
        inputs=inputs_of(exp.hyperparams, cwd) if remote else {},
        trust_pickle=trusted(),  # the command's --trust-pickle, for each job's process
    )
    jobs = [SeedJob(spec, plan.seed, read_files(plan.run.path) if remote else None)
            for plan in plans]  # fmt: skip
    stopped: list[int] = []

    def done(i: int, result: SeedResult) -> None:
        run = plans[i].run
        if result.folder is not None:
            install_folder(result.folder, run.path)
            held.enter_context(training_lock([run]))  # the folder put in place
        if result.interrupted:
            stopped.append(result.seed)
        elif result.summary is not None:
            results[i] = result.summary

    executor.map(run_seed_job, jobs, [f"seed {plan.seed}" for plan in plans], done)
    if stopped:
        raise KeyboardInterrupt(f"seeds {sorted(stopped)} stopped")


def run_seed_job(job: SeedJob) -> SeedResult:
    """An executor's job: trains ``job.seed`` where the driver's run folder is visible (no
    token, or the driver's marker found), else in a temporary folder whose run folder it
    returns whole.  A Ctrl-C returns the state saved so far, marked ``interrupted``."""
    spec = job.spec
    if not spec.token or (spec.shared_files and _sees_driver(spec)):
        with _working_dir(spec.cwd):
            return _trained(job, None)
    with tempfile.TemporaryDirectory(prefix="tendon2r-seed-") as tmp:
        work, base = Path(tmp, "work"), Path(tmp, "run")
        write_files(spec.inputs, work)
        run = seed_dir(base, job.seed)
        run.mkdir(parents=True)
        write_files(job.folder or {}, run)
        with _working_dir(str(work)):
            result = _trained(job, base)
        result.folder = read_files(run)
        return result


def _trained(job: SeedJob, base: Path | None) -> SeedResult:
    try:
        summary = train_seed(job.spec, job.seed, base)
    except KeyboardInterrupt:
        folder = RunFolder(seed_dir(base if base is not None else job.spec.base, job.seed))
        summary = None
        with contextlib.suppress(OSError, ValueError):
            summary = folder.read_json("summary.json")
        return SeedResult(job.seed, summary, interrupted=True)
    return SeedResult(job.seed, summary)


def _sees_driver(spec: SeedSpec) -> bool:
    """Whether this node sees the driver's run folder: the driver's marker is there."""
    marker = Path(spec.base, f"{MARKER_PREFIX}{spec.token}")
    try:
        return marker.read_text().strip() == spec.token
    except OSError:
        return False


@contextlib.contextmanager
def driver_marker(base: Path, write: bool = True) -> Iterator[str]:
    """Writes the driver's marker in ``base`` (made if missing) for the block, if ``write``;
    yields its token."""
    token = uuid.uuid4().hex
    marker = base / f"{MARKER_PREFIX}{token}"
    if not write:
        yield token
        return
    base.mkdir(parents=True, exist_ok=True)
    marker.write_text(f"{token}\n")
    try:
        yield token
    finally:
        with contextlib.suppress(OSError):
            marker.unlink()


@contextlib.contextmanager
def _working_dir(path: str) -> Iterator[None]:
    """Runs the block in ``path`` (if given and present): the hyperparameters' relative paths
    (an experiment file) mean what they meant to the driver."""
    if not path or not os.path.isdir(path):
        yield
        return
    old = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


def _clear(folder: Path, keep: Path) -> None:
    """Removes everything in ``folder`` but ``keep``."""
    for path in folder.iterdir():
        if path == keep:
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()


# -- folders as data ---------------------------------------------------------------------------
def read_files(folder: Path) -> dict[str, bytes]:
    """Returns every file under ``folder``: its path relative to the folder (POSIX) -> bytes."""
    return {
        path.relative_to(folder).as_posix(): path.read_bytes()
        for path in sorted(folder.rglob("*"))
        if path.is_file()
    }


def _safe(relative: str) -> PurePosixPath:
    """Returns ``relative`` as a path inside its folder, or raises (absolute, or with ..)."""
    path = PurePosixPath(relative)
    if path.is_absolute() or ".." in path.parts or not path.parts:
        raise ValueError(f"{relative!r} is invalid; allowed: a path inside the run folder")
    return path


def write_files(files: Mapping[str, bytes], folder: Path) -> None:
    """Writes ``files`` (relative path -> bytes) under ``folder``."""
    for relative, data in files.items():
        path = folder.joinpath(*_safe(relative).parts)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)


def install_folder(files: Mapping[str, bytes], target: Path) -> None:
    """Puts a run folder sent by a job at ``target``: written whole into a hidden sibling,
    then renamed into place (the folder it replaces is renamed aside first, then removed), so
    that ``target`` never holds half of it."""
    stamp = uuid.uuid4().hex[:12]
    incoming = target.with_name(f".{target.name}.incoming-{stamp}")
    write_files(files, incoming)
    if not files:
        incoming.mkdir(parents=True, exist_ok=True)
    old = target.with_name(f".{target.name}.replaced-{stamp}")
    if target.exists():
        os.replace(target, old)
    os.replace(incoming, target)
    shutil.rmtree(old, ignore_errors=True)


def inputs_of(hp: Hyperparams, cwd: Path) -> dict[str, bytes]:
    """Returns the files that ``hp`` names by a path relative to ``cwd`` (path -> bytes), for
    a node that does not see them: the experiment file (``env_kwargs.preset``) and the files
    beside an ``init_from`` model.  Absolute paths, and paths out of ``cwd``, must be where
    the node sees them (a shared file system)."""
    named = []
    preset = hp.env_kwargs.get("preset")
    if isinstance(preset, str) and preset.endswith((".yaml", ".yml")):
        named.append(Path(preset))
    if isinstance(hp.init_from, str) and not Path(hp.init_from).is_absolute():
        zip_path = model_files(stem_of(hp.init_from))[0]  # a model file (not a bundle name)
        if (cwd / zip_path).is_file():
            named += [zip_path.parent / p.name for p in _beside(cwd / zip_path)]
    out: dict[str, bytes] = {}
    for path in named:
        if path.is_absolute() or ".." in path.parts:
            continue
        full = cwd / path
        if full.is_file():
            out[path.as_posix()] = full.read_bytes()
    return out


def _beside(path: Path) -> list[Path]:
    """Returns the files in the folder of ``path`` (a model and its records)."""
    folder = path.parent
    return [p for p in folder.iterdir() if p.is_file()] if folder.is_dir() else []
