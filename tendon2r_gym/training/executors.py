"""Where jobs run: in this process, in local worker processes, or on a Ray cluster.

Every executor has one interface, ``Executor.map``: ``fn(job)`` for each job, the results
in job order, ``done(i, result)`` called in this process as each job finishes (a training
command writes a job's run folder there).  A job is anything picklable, ``fn`` a module-level
function (a worker imports it by name).  No scheduler of our own: the local executor is
``concurrent.futures.ProcessPoolExecutor`` (spawned workers), the cluster executor Ray's
remote tasks.

- A job that raises: the other jobs run to their end, then ``JobError`` names the job
  (its label, e.g. ``seed 1``) and the error; a ValueError stays a ValueError
  (``JobValueError``).  In-process, a job's error propagates as it is (today's one-process
  training).
- Ctrl-C (KeyboardInterrupt in the caller): jobs not yet started are cancelled, the running
  ones are asked to stop (SIGINT for local workers, Ray's cancel), which lets a training save
  its state and return; those still running after ``grace_s`` are stopped at once (terminated,
  or ``ray.cancel(force=True)``).  Then KeyboardInterrupt is raised again.
- Local workers pin torch and BLAS to ``cpus`` threads each (``OMP_NUM_THREADS``,
  ``MKL_NUM_THREADS``, ``OPENBLAS_NUM_THREADS`` in their environment from the start); Ray
  gives each task ``num_cpus=cpus`` and runs a lost node's jobs again elsewhere
  (``max_retries``).  Both give each job its share, ``cpus``, through
  tendon2r_gym.envs.vector_env.CPUS_VAR, which caps its MuJoCo batch threads (in this
  process, a training's batch may use every CPU).

Ray is optional (the ``cluster`` extra) and imported only by ``RayCluster``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any, Protocol, TypeVar

from tendon2r_gym.envs.vector_env import CPUS_VAR
from tendon2r_gym.validation import integer, invalid

J = TypeVar("J")
R = TypeVar("R")

#: The most local worker processes (``--workers``).
MAX_WORKERS = 256
#: The environment variables that size torch's and the BLAS libraries' thread pools.
THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
#: How the cluster extra is installed (named by the error when Ray is missing).
CLUSTER_EXTRA = 'pip install "tendon2r_gym[cluster]"'


class JobError(RuntimeError):
    """A job raised: the message names the job (its label) and the error; the job's own
    exception is the ``__cause__``."""

    def __init__(self, label: str, error: BaseException) -> None:
        super().__init__(f"{label}: {error}" if isinstance(error, ValueError) else
                         f"{label}: {type(error).__name__}: {error}")  # fmt: skip
        self.label, self.error = label, error


class JobValueError(JobError, ValueError):
    """A job raised a ValueError (bad input, a corrupt record, a folder that cannot be
    written): still a ValueError, which the console commands print as one line."""


def job_error(label: str, error: BaseException) -> JobError:
    """Returns the error that names the job ``label`` that raised ``error``."""
    cls = JobValueError if isinstance(error, ValueError) else JobError
    out = cls(label, error)
    out.__cause__ = error
    return out


class Executor(Protocol):
    """Runs jobs; ``map`` returns their results in job order."""

    #: Whether jobs may run on another machine (they then see none of this one's files).
    remote: bool

    def map(
        self,
        fn: Callable[[J], R],
        jobs: Sequence[J],
        labels: Sequence[str] | None = None,
        done: Callable[[int, R], Any] | None = None,
    ) -> list[R]: ...


def thread_env(threads: int) -> dict[str, str]:
    """Returns the environment variables that size torch's and BLAS's thread pools."""
    return {name: str(threads) for name in THREAD_VARS}


def pin_threads(threads: int) -> None:
    """Pins this process's torch and BLAS thread pools to ``threads``: the environment
    variables (read when torch or a BLAS library loads) and, if torch is loaded,
    ``torch.set_num_threads``."""
    import sys

    os.environ.update(thread_env(threads))
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(threads)


def _labels(labels: Sequence[str] | None, n: int) -> list[str]:
    labels = [f"job {i}" for i in range(n)] if labels is None else list(labels)
    if len(labels) != n:
        raise invalid("labels", labels, f"one label per job ({n})")
    return labels


def _raise_first(errors: dict[int, JobError]) -> None:
    if errors:
        raise errors[min(errors)]


# -- in this process ---------------------------------------------------------------------------
class InProcess:
    """Runs the jobs one after another in this process (``--workers 1``); a job's error
    propagates as it is, and stops the jobs after it."""

    remote = False

    def map(
        self,
        fn: Callable[[J], R],
        jobs: Sequence[J],
        labels: Sequence[str] | None = None,
        done: Callable[[int, R], Any] | None = None,
    ) -> list[R]:
        results: list[R] = []
        for i, job in enumerate(jobs):
            result = fn(job)
            if done is not None:
                done(i, result)
            results.append(result)
        return results


# -- local worker processes --------------------------------------------------------------------
@contextlib.contextmanager
def _environ(values: Mapping[str, str]) -> Iterator[None]:
    """Sets environment variables for the processes started inside the block (a spawned
    worker starts with them), then puts the old values back."""
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


#: Set in a local worker asked to stop (SIGINT) before its training's own handlers were in
#: place: the training's StopOnSignal then starts stopped.
STOP_REQUESTED = threading.Event()


def _request_stop(signum: int, frame: Any) -> None:
    STOP_REQUESTED.set()


def share_cpus(cpus: int) -> None:
    """Gives this process (a job's worker) its CPU share: ``cpus`` caps its MuJoCo batch
    threads (tendon2r_gym.envs.vector_env.CPUS_VAR)."""
    os.environ[CPUS_VAR] = str(cpus)


def _init_worker(threads: int, parent: int) -> None:
    """Starts a local worker: torch, BLAS and MuJoCo's batch pinned to ``threads``; SIGINT
    outside a training's ``learn`` recorded, not raised (the driver sends each worker one SIGINT on
    Ctrl-C: an idle worker must not die of it, and a job still setting up stops, with its
    state saved, as its training starts); a watchdog that sends this process SIGTERM if the
    driver ``parent`` dies, so that no worker trains on unowned."""
    pin_threads(threads)
    share_cpus(threads)
    signal.signal(signal.SIGINT, _request_stop)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="driver-watchdog", daemon=True).start()


class LocalWorkers:
    """Runs the jobs in ``workers`` spawned processes of this machine, at most ``workers`` at
    once (``--workers N``), each with ``cpus`` torch and BLAS threads."""

    remote = False

    def __init__(self, workers: int, cpus: int = 1, grace_s: float = 60.0) -> None:
        self.workers = integer("workers", workers, 1, MAX_WORKERS)
        self.cpus = integer("cpus", cpus, 1, 256)
        self.grace_s = grace_s

    def map(
        self,
        fn: Callable[[J], R],
        jobs: Sequence[J],
        labels: Sequence[str] | None = None,
        done: Callable[[int, R], Any] | None = None,
    ) -> list[R]:
        import multiprocessing

        labels = _labels(labels, len(jobs))
        if not jobs:
            return []
        results: dict[int, R] = {}
        errors: dict[int, JobError] = {}
        pool = ProcessPoolExecutor(
            min(self.workers, len(jobs)),
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_worker,
            initargs=(self.cpus, os.getpid()),
        )
        futures: dict[Future, int] = {}
        try:
            with _environ(thread_env(self.cpus)):  # each worker starts at its first submit
                for i, job in enumerate(jobs):
                    futures[pool.submit(fn, job)] = i
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    self._collect(future, futures[future], labels, results, errors, done)
        except KeyboardInterrupt:
            self._stop(pool, futures, labels, results, errors, done)
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
        _raise_first(errors)
        return [results[i] for i in range(len(jobs))]

    @staticmethod
    def _collect(
        future: Future,
        i: int,
        labels: list[str],
        results: dict[int, Any],
        errors: dict[int, JobError],
        done: Callable[[int, Any], Any] | None,
    ) -> None:
        if future.cancelled():
            return
        error = future.exception()
        if isinstance(error, KeyboardInterrupt):  # a job stopped by a signal of its own
            raise KeyboardInterrupt(labels[i])
        if error is not None:
            errors[i] = job_error(labels[i], error)
            return
        result = future.result()
        results[i] = result if done is None else (done(i, result) or result)

    def _stop(
        self,
        pool: ProcessPoolExecutor,
        futures: dict[Future, int],
        labels: list[str],
        results: dict[int, Any],
        errors: dict[int, JobError],
        done: Callable[[int, Any], Any] | None,
    ) -> None:
        """Ctrl-C: cancels the queued jobs, sends each worker one SIGINT (a training saves
        its state and returns), waits up to grace_s for them, then terminates the workers."""
        running = {f for f in futures if not f.cancel() and not f.done()}
        processes = list(getattr(pool, "_processes", {}).values())  # the pool's own workers
        for process in processes:
            with contextlib.suppress(ProcessLookupError, TypeError):
                os.kill(process.pid, signal.SIGINT)
        with contextlib.suppress(KeyboardInterrupt):  # a second Ctrl-C: stop at once
            wait(running, timeout=self.grace_s)
        for future in futures:
            if future.done() and futures[future] not in results:
                with contextlib.suppress(KeyboardInterrupt):
                    self._collect(future, futures[future], labels, results, errors, done)
        for process in processes:
            if process.is_alive():
                process.terminate()


# -- a Ray cluster -----------------------------------------------------------------------------
def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ValueError(
            f"--cluster needs Ray, which is not installed; allowed: install it with "
            f"{CLUSTER_EXTRA}, or train on local workers with --workers N"
        ) from None
    return ray


def _apply(fn: Callable[[J], R], job: J, cpus: int = 1) -> R:
    """A Ray task: ``fn(job)`` (any callable, builtins included; the task is named by the job's
    label), in the task's CPU share ``cpus`` (`share_cpus`)."""
    share_cpus(cpus)
    return fn(job)


def _reachable(address: str, timeout_s: float) -> str | None:
    """Returns why ``host:port`` takes no TCP connection within ``timeout_s``, or None."""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        return "it is not HOST:PORT"
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s):
            return None
    except OSError as e:
        return str(e) or type(e).__name__


class RayCluster:
    """Runs each job as a Ray task of ``num_cpus=cpus`` on the cluster at ``address``
    (``auto``: the one ``ray start`` made on this machine, or that ``RAY_ADDRESS`` names;
    else ``HOST:PORT`` of its head).  A task on a node that is lost runs again elsewhere, up
    to ``max_retries`` times.  Use as a context manager: entering connects and checks that the
    cluster has a node with ``cpus`` CPUs (a ValueError otherwise, before any job runs).

    ``shared_files``: a job that sees the caller's files (this machine, a shared file system)
    works in them; False: every job works in a folder of its own and sends its results back
    (a shared file system too slow, or untrusted, for a training's writes)."""

    remote = True

    def __init__(
        self,
        address: str = "auto",
        cpus: int = 1,
        max_retries: int = 3,
        grace_s: float = 60.0,
        connect_timeout_s: float = 10.0,
        shared_files: bool = True,
    ) -> None:
        if not isinstance(address, str) or not address.strip():
            raise invalid("cluster", address, "'auto' or the HOST:PORT of a Ray head node")
        self.address = address.strip()
        self.cpus = integer("cpus", cpus, 1, 256)
        self.max_retries = integer("max_retries", max_retries, 0, 1000)
        self.grace_s, self.connect_timeout_s = grace_s, connect_timeout_s
        self.shared_files = bool(shared_files)
        self._ray: Any = None
        self._connected = False

    # -- connection --------------------------------------------------------------------------
    def _bootstrap_address(self, ray: Any) -> str | None:
        """Returns the HOST:PORT that ``auto`` stands for (RAY_ADDRESS, or the cluster that
        ``ray start`` recorded), or the given address; None if ``auto`` finds none."""
        if self.address != "auto":
            return self.address
        if os.environ.get("RAY_ADDRESS"):
            return os.environ["RAY_ADDRESS"]
        try:
            from ray._private.services import canonicalize_bootstrap_address

            return canonicalize_bootstrap_address("auto")
        except (ImportError, ConnectionError, ValueError):
            return None

    def __enter__(self) -> RayCluster:
        import logging

        ray = self._ray = _import_ray()
        if ray.is_initialized():  # a caller's own connection: used as it is
            self._check_cpus()
            return self
        address = self._bootstrap_address(ray)
        allowed = (
            "'auto' (a cluster started with ray start --head on this machine, or named by "
            "RAY_ADDRESS) or the HOST:PORT of a running Ray head node"
        )
        if address is None:
            raise invalid("--cluster", self.address, f"{allowed}; no running cluster was found")
        if address.startswith("ray://"):
            raise invalid("--cluster", self.address, f"{allowed} (Ray Client is not supported)")
        if (why := _reachable(address, self.connect_timeout_s)) is not None:
            raise invalid("--cluster", self.address, f"{allowed}; {address} is unreachable ({why})")
        try:
            ray.init(address=address, logging_level=logging.WARNING, log_to_driver=True)
        except (ConnectionError, RuntimeError, TimeoutError) as e:
            raise invalid(
                "--cluster", self.address, f"{allowed}; connecting failed ({e})"
            ) from None
        self._connected = True
        try:
            self._check_cpus()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        if self._connected:
            self._ray.shutdown()
            self._connected = False

    def _check_cpus(self) -> None:
        """Raises unless an alive node has ``cpus`` CPUs (a job would wait for ever)."""
        nodes = [n for n in self._ray.nodes() if n.get("Alive")]
        cpus = sorted((float(n.get("Resources", {}).get("CPU", 0)) for n in nodes), reverse=True)
        if not cpus or cpus[0] < self.cpus:
            raise invalid(
                "--cluster",
                self.address,
                f"a cluster with a node of at least {self.cpus} CPU(s) for each job (torch "
                f"threads); its {len(nodes)} node(s) have {[f'{c:g}' for c in cpus]} CPUs",
            )

    # -- jobs --------------------------------------------------------------------------------
    def map(
        self,
        fn: Callable[[J], R],
        jobs: Sequence[J],
        labels: Sequence[str] | None = None,
        done: Callable[[int, R], Any] | None = None,
    ) -> list[R]:
        ray = self._ray if self._ray is not None else _import_ray()
        if not ray.is_initialized():
            raise RuntimeError("RayCluster.map: enter the executor first (with RayCluster(...))")
        labels = _labels(labels, len(jobs))
        task = ray.remote(num_cpus=self.cpus, max_retries=self.max_retries)(_apply)
        refs = {
            task.options(name=labels[i]).remote(fn, job, self.cpus): i for i, job in enumerate(jobs)
        }
        results: dict[int, R] = {}
        errors: dict[int, JobError] = {}
        pending = list(refs)
        try:
            while pending:
                ready, pending = ray.wait(pending, num_returns=1)
                for ref in ready:
                    self._collect(ref, refs[ref], labels, results, errors, done)
        except KeyboardInterrupt:
            self._stop(pending, refs, labels, results, errors, done)
            raise
        _raise_first(errors)
        return [results[i] for i in range(len(jobs))]

    def _collect(
        self,
        ref: Any,
        i: int,
        labels: list[str],
        results: dict[int, Any],
        errors: dict[int, JobError],
        done: Callable[[int, Any], Any] | None,
    ) -> None:
        ray = self._ray
        try:
            result = ray.get(ref)
        except ray.exceptions.TaskCancelledError:
            return
        except ray.exceptions.RayTaskError as e:  # the job raised: its own exception
            cause = getattr(e, "cause", None)
            errors[i] = job_error(labels[i], cause if cause is not None else e)
            return
        except ray.exceptions.RayError as e:  # lost more often than max_retries, ...
            errors[i] = job_error(labels[i], e)
            return
        results[i] = result if done is None else (done(i, result) or result)

    def _stop(
        self,
        pending: list[Any],
        refs: dict[Any, int],
        labels: list[str],
        results: dict[int, Any],
        errors: dict[int, JobError],
        done: Callable[[int, Any], Any] | None,
    ) -> None:
        """Ctrl-C: cancels every job (a running training gets a KeyboardInterrupt, saves its
        state and returns), waits up to grace_s for them, then cancels the rest by force."""
        ray = self._ray
        for ref in pending:
            ray.cancel(ref, force=False)
        finished: list[Any] = []
        with contextlib.suppress(KeyboardInterrupt):  # a second Ctrl-C: stop at once
            finished, pending = ray.wait(pending, num_returns=len(pending), timeout=self.grace_s)
        for ref in pending:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        for ref in finished:
            with contextlib.suppress(Exception):
                self._collect(ref, refs[ref], labels, results, errors, done)


def make_executor(workers: int = 1, cluster: str | None = None, cpus: int = 1) -> Any:
    """Returns the executor of a command's ``--workers`` and ``--cluster``: in-process
    (``workers`` 1, no cluster), local workers, or a Ray cluster (enter it to connect)."""
    integer("--workers", workers, 1, MAX_WORKERS)
    if cluster is not None:
        if workers != 1:
            raise invalid(
                "--workers", workers, "1 with --cluster (the cluster's CPUs decide how many "
                "jobs run at once)"
            )  # fmt: skip
        return RayCluster(cluster, cpus)
    return InProcess() if workers == 1 else LocalWorkers(workers, cpus)


#: The flags that choose where jobs run, not what they compute.
EXECUTOR_FLAGS = ("--workers", "--cluster")


def without_executor_flags(argv: Sequence[str]) -> list[str]:
    """Returns ``argv`` without ``--workers N`` and ``--cluster ADDRESS`` (or ``--flag=value``):
    the command a results file records, the same on every executor."""
    out: list[str] = []
    skip = False
    for a in argv:
        if skip:
            skip = False
        elif a in EXECUTOR_FLAGS:
            skip = True
        elif not a.startswith(tuple(f"{flag}=" for flag in EXECUTOR_FLAGS)):
            out.append(a)
    return out


@contextlib.contextmanager
def entered(executor: Any) -> Iterator[Any]:
    """Enters ``executor`` if it is a context manager (a Ray cluster connects), else yields
    it as it is."""
    if hasattr(executor, "__enter__"):
        with executor as ex:
            yield ex
    else:
        yield executor
