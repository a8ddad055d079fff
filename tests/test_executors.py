"""Seeds trained at once: local worker processes (--workers N) and a real two-node Ray cluster
on this machine (--cluster), against the same seeds trained in one process: the same bits, a
lost node's seed finished elsewhere, Ctrl-C then --resume, and the clear errors."""

import contextlib
import importlib.util
import io
import json
import math
import os
import signal
import socket
import sys
import tempfile
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from test_training import _start_training, _tiny, _train, _wait_for

from tendon2r_gym.app.args import parse
from tendon2r_gym.app.cli import TrainArgs, experiment, train_main
from tendon2r_gym.artifacts.runs import RunFolder
from tendon2r_gym.training.executors import JobError, LocalWorkers, RayCluster
from tendon2r_gym.training.jobs import train_experiment

HAS_RAY = importlib.util.find_spec("ray") is not None
needs_ray = pytest.mark.skipif(not HAS_RAY, reason='needs pip install "tendon2r_gym[cluster]"')


def on_cluster(test):
    """A test on the two-node Ray cluster: marked ``cluster`` (together they take about two
    minutes: pytest -m cluster), skipped without Ray."""
    return pytest.mark.cluster(needs_ray(test))


SEEDS = (0, 1)


def _files(folder):
    return {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def bits(run_dir, seed):
    """What a seed's training decides: its evaluations (wall times aside), best metrics, and
    the best model's weights and observation statistics, as plain data."""
    run = RunFolder(run_dir / f"seed_{seed}")
    rows = [{k: v for k, v in r.items() if k != "wall_time_s"}
            for r in run.read_json("evaluations.json")]  # fmt: skip
    with zipfile.ZipFile(run.file("best_model.zip")) as z:
        weights = torch.load(io.BytesIO(z.read("policy.pth")), weights_only=True)
    stats = run.file("best_model_vecnormalize.npz")  # plain arrays
    summary = run.read_json("summary.json")
    return {
        "evaluations": rows,
        "best": run.read_json("best_metrics.json"),
        "weights": {k: v.numpy().tobytes() for k, v in weights.items()},
        "stats": {k: v.tobytes() for k, v in np.load(stats).items()},
        "config": run.read_config(),
        "timesteps": summary["timesteps"],
        "interrupted": summary["interrupted"],
    }


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The tiny training of SEEDS in one process (--workers 1): what every executor gives."""
    tmp = tmp_path_factory.mktemp("reference")
    config = _tiny(tmp)
    _train(config, tmp / "run", "--seeds", *map(str, SEEDS))
    return config, {seed: bits(tmp / "run", seed) for seed in SEEDS}


# -- local workers -----------------------------------------------------------------------------
def test_two_local_workers_give_the_same_bits_as_one_process_and_name_a_failing_seed(
    tmp_path, reference
):
    """Seeds 0 and 1 on two workers: the same bits as in one process.  Seed 2's TensorBoard
    folder is a file: its job fails at the start of its training, in its worker; the error
    names seed 2 and its folder once the other seeds have trained to their end."""
    config, expected = reference
    run = tmp_path / "run"
    (run / "seed_2").mkdir(parents=True)
    (run / "seed_2" / "tb").write_text("not a folder")
    with pytest.raises(ValueError, match=r"^seed 2: writing to the run folder .*seed_2") as err:
        _train(config, run, "--seeds", *map(str, SEEDS), "2", "--workers", "2")
    assert isinstance(err.value, JobError)
    assert json.loads((run / "seeds_summary.json").read_text())["finished"] == list(SEEDS)
    for seed in SEEDS:
        assert bits(run, seed) == expected[seed], seed
    assert [p.name for p in run.iterdir() if p.name.startswith(".")] == []


def report_threads(job: int) -> tuple[str | None, str | None, int, int]:
    """A worker's thread settings: its environment, torch's once imported, and the MuJoCo
    batch threads of a 64-arm vector env."""
    import torch as worker_torch

    from tendon2r_gym.envs.vector_env import default_nthread

    return (os.environ.get("OMP_NUM_THREADS"), os.environ.get("MKL_NUM_THREADS"),
            worker_torch.get_num_threads(), default_nthread(64))  # fmt: skip


def test_a_local_worker_pins_torch_blas_and_mujoco_to_its_share_and_names_a_failing_job():
    assert LocalWorkers(2, cpus=1).map(report_threads, [0, 1]) == [("1", "1", 1, 1)] * 2
    with pytest.raises(JobError, match=r"^job 1: math domain error") as err:
        LocalWorkers(2).map(math.sqrt, [4.0, -1.0])
    assert isinstance(err.value, ValueError) and isinstance(err.value.__cause__, ValueError)


@pytest.mark.parametrize(("argv", "field", "allowed"), [
    (["--workers", "0"], "--workers = 0", r"an integer in \[1, 256\]"),
    (["--workers", "2", "--cluster", "auto"], "--workers = 2", "1 with --cluster"),
    (["--seeds", "0", "0"], r"seeds = \[0, 0\]", "distinct seeds"),
    (["--seeds", "4294967296"], "seeds = 4294967296", r"an integer in \[0, 4294967295\]"),
])  # fmt: skip
def test_bad_executor_settings_are_refused_before_anything_is_written(
    tmp_path, argv, field, allowed
):
    with pytest.raises(ValueError, match=rf"^{field} is invalid; allowed: {allowed}"):
        _train(_tiny(tmp_path), tmp_path / "run", *argv)
    assert not (tmp_path / "run").exists()


def test_without_ray_the_cluster_option_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray fails, as when not installed
    with pytest.raises(ValueError, match=r'pip install "tendon2r_gym\[cluster\]"'):
        _train(_tiny(tmp_path), tmp_path / "run", "--cluster", "auto")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("phase", [
    pytest.param("run.json", id="set-up"),
    pytest.param("evaluations.json", id="training", marks=pytest.mark.slow),
])  # fmt: skip
def test_ctrl_c_stops_every_worker_with_its_state_saved_and_resume_finishes_them(
    tmp_path, phase
):
    """SIGINT to the driver alone (as `kill -INT`), while the seeds set up (their run folders
    just made: no handler of the training's own yet) or train: each worker saves its seed and
    stops well within the driver's grace, the command exits 130; --resume on two workers
    continues both from their saved states."""
    proc = _start_training(tmp_path, SEEDS, 256, "--total-timesteps", "10000000",
                           "--workers", "2")  # fmt: skip
    for seed in SEEDS:
        _wait_for(tmp_path / "run" / f"seed_{seed}" / phase, proc)
    proc.send_signal(signal.SIGINT)
    out = proc.communicate(timeout=50)[0].decode()  # the driver's grace is 60 s
    assert proc.returncode == 130, out[-3000:]
    runs = [RunFolder(tmp_path / "run" / f"seed_{seed}") for seed in SEEDS]
    saved = []
    for run in runs:
        summary = run.read_json("summary.json")
        assert summary["interrupted"] is True and run.file("last_model.zip").is_file()
        saved.append(summary["timesteps"])
    budget = max(saved) + 128
    agg = train_main(["--run-dir", str(tmp_path / "run"), "--resume", "--workers", "2",
                      "--total-timesteps", str(budget)])  # fmt: skip
    assert agg["finished"] == list(SEEDS)
    for run, steps in zip(runs, saved, strict=True):
        segments = run.read_json("summary.json")["segments"]
        assert segments[0]["interrupted"] and segments[-1]["start_timesteps"] == steps
        assert segments[-1]["end_timesteps"] >= budget and not segments[-1]["interrupted"]


# -- a Ray cluster of two nodes on this machine --------------------------------------------------
@pytest.fixture(scope="module")
def cluster():
    """A real Ray cluster of two one-CPU nodes (two raylets), every node on 127.0.0.1, and
    nothing sent elsewhere (Ray's usage statistics off; the driver's own address taken as the
    loopback one, as on a machine without a cluster network)."""
    if not HAS_RAY:
        pytest.skip('needs pip install "tendon2r_gym[cluster]"')
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RAY_USAGE_STATS_ENABLED", "0")
        mp.setenv("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")  # for the processes Ray starts
        import ray._private.ray_constants as constants
        from ray.cluster_utils import Cluster

        mp.setattr(constants, "ENABLE_RAY_CLUSTER", False)  # this process: 127.0.0.1
        nodes = Cluster(initialize_head=True, head_node_args={
            "num_cpus": 1, "include_dashboard": False, "node_ip_address": "127.0.0.1"})  # fmt: skip
        try:
            nodes.add_node(num_cpus=1, node_ip_address="127.0.0.1")
            nodes.wait_for_nodes()
            yield nodes
        finally:
            nodes.shutdown()


def _train_on_cluster(config, run, address, shared_files=True, *argv):
    """Trains SEEDS of ``config`` on the cluster at ``address``, as tendon2r-train does."""
    args = parse(TrainArgs, ["--config", str(config), "--hyperparams", "tiny", "--run-dir",
                             str(run), "--seeds", *map(str, SEEDS), *argv])  # fmt: skip
    with RayCluster(address, shared_files=shared_files) as executor:
        return train_experiment(experiment(args), args.resume, executor)


@on_cluster
@pytest.mark.parametrize("shared_files", [True, False], ids=["in-place", "sent-back"])
def test_a_two_node_cluster_gives_the_same_bits_as_one_process(
    tmp_path, cluster, reference, shared_files, monkeypatch
):
    """Both seeds train on the cluster (found through RAY_ADDRESS by --cluster auto), in the
    driver's run folder or each in a folder of its own sent back whole: the same bits as in
    one process, and nothing left beside the seed folders."""
    config, expected = reference
    monkeypatch.setenv("RAY_ADDRESS", cluster.address)
    agg = _train_on_cluster(config, tmp_path / "run", "auto", shared_files)
    assert agg["finished"] == list(SEEDS)
    for seed in SEEDS:
        assert bits(tmp_path / "run", seed) == expected[seed], seed
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == [
        "seed_0", "seed_1", "seeds_summary.json"]  # fmt: skip


@on_cluster
def test_a_job_that_raises_on_the_cluster_names_it(cluster):
    with (
        RayCluster(cluster.address) as executor,
        pytest.raises(ValueError, match=r"^seed 1: math domain error"),
    ):
        executor.map(math.sqrt, [4.0, -1.0], ["seed 0", "seed 1"])


@on_cluster
def test_a_cluster_job_runs_mujoco_in_its_cpu_share(cluster):
    from tendon2r_gym.envs.vector_env import default_nthread

    with RayCluster(cluster.address) as executor:
        assert executor.map(default_nthread, [64, 64]) == [1, 1]


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@needs_ray
def test_a_cluster_that_cannot_be_reached_is_refused_before_anything_is_written(
    tmp_path, monkeypatch
):
    """A named address, or the one RAY_ADDRESS gives --cluster auto, where nothing listens
    (a closed port of 127.0.0.1)."""
    config, address = _tiny(tmp_path), f"127.0.0.1:{_closed_port()}"
    with pytest.raises(ValueError, match=rf"^--cluster = '{address}' is invalid; .*unreachable"):
        _train(config, tmp_path / "run", "--cluster", address)
    monkeypatch.setenv("RAY_ADDRESS", address)
    with pytest.raises(ValueError, match=rf"^--cluster = 'auto' is invalid; .*{address} is unr"):
        _train(config, tmp_path / "run", "--cluster", "auto")
    assert not (tmp_path / "run").exists()


@on_cluster
def test_a_cluster_without_the_cpus_of_a_job_is_refused_before_training(tmp_path, cluster):
    two_threads = _tiny(tmp_path, torch_threads=2)  # each job asks for 2 CPUs: no node has them
    with pytest.raises(ValueError, match=r"a node of at least 2 CPU.*have \['1', '1'\] CPUs"):
        _train(two_threads, tmp_path / "run", "--cluster", cluster.address)
    assert not (tmp_path / "run").exists()


@on_cluster
def test_a_lost_node_s_seed_finishes_elsewhere_from_its_last_checkpoint(tmp_path, cluster):
    """The second node is removed while both seeds train: its seed runs again on the head
    node, from the last checkpoint it wrote in the shared run folder, and the command ends
    with both seeds done."""
    config = _tiny(tmp_path, steps=2048)  # a checkpoint every 128 steps
    run = tmp_path / "run"
    out: dict = {}

    def train() -> None:
        try:
            out["agg"] = _train(config, run, "--seeds", *map(str, SEEDS),
                                "--cluster", cluster.address)  # fmt: skip
        except BaseException as e:  # noqa: BLE001 (reported below)
            out["error"] = e

    driver = threading.Thread(target=train)
    driver.start()
    second = cluster.list_all_nodes()[1]
    try:
        start = time.monotonic()
        while not all(list((run / f"seed_{s}" / "checkpoints").glob("*.zip")) for s in SEEDS):
            assert driver.is_alive() and time.monotonic() - start < 180, out
            time.sleep(0.1)
        cluster.remove_node(second)
        driver.join(timeout=300)
    finally:
        with contextlib.suppress(Exception):
            cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1")
            cluster.wait_for_nodes()
    assert "error" not in out, out.get("error")
    assert out["agg"]["finished"] == list(SEEDS)
    summaries = [RunFolder(run / f"seed_{s}").read_json("summary.json") for s in SEEDS]
    assert all(s["timesteps"] == 2048 and not s["interrupted"] for s in summaries)
    continued = [s["segments"] for s in summaries if len(s["segments"]) > 1]
    assert len(continued) == 1, summaries  # the lost node's seed, continued once
    (segments,) = continued
    assert segments[0]["interrupted"] and segments[1]["start_timesteps"] > 0


@on_cluster
@pytest.mark.parametrize("shared_files", [True, False], ids=["in-place", "sent-back"])
def test_ctrl_c_on_the_driver_stops_every_cluster_job_and_resume_finishes_them(
    tmp_path, cluster, shared_files
):
    """Ctrl-C while both seeds train on the cluster: every job is stopped and saves its state
    (into the driver's run folder, or sent back), the command raises KeyboardInterrupt, and
    --resume continues both from their saved states."""
    import _thread

    config, run = _tiny(tmp_path, steps=10**7), tmp_path / "run"
    # where the jobs train: the run folder, or each a temporary folder of its own
    where = run if shared_files else Path(tempfile.gettempdir())
    pattern = "seed_{}/evaluations.json" if shared_files else "tendon2r-seed-*/run/seed_{}/ev*"
    started = time.monotonic()

    def interrupt() -> None:  # Ctrl-C once both seeds have evaluated
        while time.monotonic() - started < 120 and not all(
            list(where.glob(pattern.format(s))) for s in SEEDS
        ):
            time.sleep(0.1)
        _thread.interrupt_main()

    threading.Thread(target=interrupt, daemon=True).start()
    with pytest.raises(KeyboardInterrupt):
        _train_on_cluster(config, run, cluster.address, shared_files)
    saved = []
    for seed in SEEDS:
        summary = RunFolder(run / f"seed_{seed}").read_json("summary.json")
        assert summary["interrupted"] is True, seed
        saved.append(summary["timesteps"])
    budget = max(saved) + 128
    agg = train_main(["--run-dir", str(run), "--resume", "--total-timesteps", str(budget)])
    assert agg["finished"] == list(SEEDS)
    for seed, steps in zip(SEEDS, saved, strict=True):
        segments = RunFolder(run / f"seed_{seed}").read_json("summary.json")["segments"]
        assert segments[-1]["start_timesteps"] == steps and not segments[-1]["interrupted"]
