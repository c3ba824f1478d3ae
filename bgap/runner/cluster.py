"""Ray: where heavy work runs when it leaves this machine.

    python -m bgap.evaluate ... cluster.address=local        # Ray started in-process
    python -m bgap.evaluate ... cluster.address=auto         # the cluster `ray start` made

``cluster.*`` changes where work runs, never what it computes: the settings stay out of
run-folder names, study names and the pipeline's parameters (:data:`bgap.common.runs.VOLATILE`),
and a task returns its results to the driver, which writes them where the local path would.
Ray is an optional extra (``pip install -e ".[cluster]"``); without it, only the local path.

Why Ray: the distributed engine the RL field already runs on (RLlib, Tune), with tasks,
resources per task, retries on a lost node and a dashboard; written against its task API
only (``ray.init``, ``ray.remote``, ``ray.get``, ``ray.cancel``).
"""

from __future__ import annotations

import io
import os
import socket
import tarfile
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from bgap.common.cli import ENV_COMMAND, command
from bgap.common.errors import ConfigError, Interrupted, TrajectoryError, check
from bgap.common.runs import CHECKPOINT_STATE, LOCK
from bgap.runner.interrupt import CtrlC
from bgap.runner.numerics import pinned

ENV_ADDRESS, ENV_STORAGE = "BGAP_CLUSTER_ADDRESS", "BGAP_CLUSTER_STORAGE"
"""Environment variables that give ``cluster.address`` and ``cluster.storage`` when a command
leaves them empty: how ``dvc repro`` sends the pipeline's stages to a cluster
(``BGAP_CLUSTER_ADDRESS=auto dvc repro``) without touching their commands."""


@dataclass
class ClusterConfig:
    """Where heavy work runs (``cluster.*``; none of it changes a result)."""

    address: str = ""
    """Empty: this process (and its worker processes), no Ray. ``local``: a Ray instance
    started in this process over this machine's cores (the tests; one big machine).
    ``auto`` or ``HOST:PORT``: an existing cluster (``ray start --head``)."""
    cpus: float = 1.0
    """CPUs each task asks for (a training, an evaluation chunk)."""
    gpus: float = 0.0
    """GPUs each task asks for (fractions share one)."""
    retries: int = 3
    """Times a task is retried when its node dies (Ray's ``max_retries``)."""
    storage: Optional[str] = None
    """A path every node sees (a shared file system, or a bucket mounted on every node):
    where tasks keep checkpoints, so a retried task resumes where the lost one stopped.
    Default: none (a retried task starts its training again)."""

    def __post_init__(self) -> None:
        # The pipeline's stages take their cluster from the environment: a setting in their
        # commands would change them, and DVC would run them again
        self.address = self.address or os.environ.get(ENV_ADDRESS, "")
        self.storage = self.storage or os.environ.get(ENV_STORAGE) or None
        check(
            not self.storage or "://" not in self.storage,
            "cluster.storage",
            self.storage,
            "takes a path every node sees; mount the bucket on every node (s3fs, gcsfuse, "
            "blobfuse2) and give its mount point",
        )
        check(self.cpus > 0, "cluster.cpus", self.cpus, "must be > 0")
        check(self.gpus >= 0, "cluster.gpus", self.gpus, "must be >= 0")
        check(self.retries >= 0, "cluster.retries", self.retries, "must be >= 0")

    @property
    def enabled(self) -> bool:
        return bool(self.address)


def writable(storage: str, where: str = "here") -> Path:
    """``storage`` made and written to (a probe file, removed), or one line saying it cannot
    be: checked on the driver before any task starts and by each task on its node."""
    path = Path(storage)
    probe = path / f".bgap-probe-{os.getpid()}"
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        raise ConfigError(
            f"cluster.storage={storage!r} cannot be written {where} ({err.strerror or err}); "
            "give a path every node can write"
        ) from None
    return path


@contextmanager
def task_folder(storage: str | None) -> Iterator[Path]:
    """On a node: the folder a training task works in, ``storage`` (checked writable there;
    kept, so that a retried task finds the lost one's checkpoints) or a temporary one."""
    with tempfile.TemporaryDirectory(prefix="bgap-") as tmp:
        yield writable(storage, f"on node {socket.gethostname()}") if storage else Path(tmp)


def pack(folder: Path) -> bytes:
    """A folder as a gzipped tar in memory (a run folder sent to or from a cluster's node);
    an absent folder as an empty archive."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as archive:
        if folder.exists():
            for path in sorted(folder.rglob("*")):
                if path.name != LOCK:
                    archive.add(path, arcname=str(path.relative_to(folder)), recursive=False)
    return buffer.getvalue()


def unpack(data: bytes, folder: Path) -> None:
    """:func:`pack`'s archive into ``folder`` (created; files it holds are replaced)."""
    folder.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as archive:
        archive.extractall(folder, filter="data")


def ship_in(packed: bytes, folder: Path) -> None:
    """A run folder shipped to a node (:func:`pack`) unpacked into
    ``folder``, unless a lost attempt left a checkpoint there to resume from."""
    if not (folder / "checkpoints" / CHECKPOINT_STATE).exists():
        unpack(packed, folder)


def kept_trainings(storage: str | None) -> str:
    """What Ctrl-C on the driver keeps of trainings sent to a cluster."""
    if storage:
        return (
            f"the finished trainings are in their run folders, the others' last checkpoints "
            f"in {storage} (cluster.storage): rerun the same command with resume=true"
        )
    return (
        "the finished trainings are in their run folders; the others kept nothing "
        "(cluster.storage keeps their checkpoints): rerun the same command with resume=true"
    )


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError(
            "cluster.address needs Ray: pip install -e '.[cluster]' (or leave cluster.address "
            "empty to run here)"
        ) from None
    return ray


@contextmanager
def connected(cfg: ClusterConfig) -> Iterator[Any]:
    """Ray connected as ``cfg`` says for the duration (None when ``cfg`` is the local path);
    an unreachable address, or a ``storage`` that cannot be written here, is one line,
    before any work starts."""
    if not cfg.enabled:
        yield None
        return
    if cfg.storage:  # before Ray starts: a task would find out on its node
        writable(cfg.storage)
    ray = _ray()
    started = not ray.is_initialized()
    if started:
        kwargs: dict[str, Any] = {"log_to_driver": False, "configure_logging": False}
        if cfg.address == "local":
            kwargs |= {"num_cpus": os.cpu_count(), "include_dashboard": False}
        else:
            _reachable(cfg.address)
            kwargs["address"] = cfg.address
        try:
            with _quiet_stderr():
                context = ray.init(**kwargs)
        except (ConnectionError, RuntimeError, ValueError, _auth_error(ray)) as err:
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise ConfigError(
                f"cluster.address={cfg.address!r}: cannot connect to a Ray cluster ({first}); "
                f"start one with `ray start --head`, check the address, {_token_hint()}, or "
                "use cluster.address=local"
            ) from None
        url = getattr(context, "dashboard_url", None)
        if url:
            print(f"Ray cluster {cfg.address}: dashboard at http://{url}", flush=True)
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()


def _auth_error(ray: Any) -> type[Exception]:
    """Ray's error for a driver without the cluster's token (RAY_AUTH_MODE=token here)."""
    return getattr(ray.exceptions, "AuthenticationError", ConnectionError)


@contextmanager
def _quiet_stderr() -> Iterator[None]:
    """File descriptor 2 into a temporary file while Ray connects: its core (C++) logs each
    failed attempt there (a refused token: a line a second for 20 s) beside the one line
    bgap gives for the failure."""
    import sys

    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)


def _token_hint() -> str:
    """What to check about Ray's token authentication (on by default from Ray 2.59 for
    local clusters): every node and every driver needs the cluster's token."""
    token_file = Path(os.environ.get("RAY_AUTH_TOKEN_PATH", Path.home() / ".ray" / "auth_token"))
    if os.environ.get("RAY_AUTH_TOKEN") or token_file.exists():
        return "check that this machine's token (RAY_AUTH_TOKEN) is the cluster's"
    return (
        "and set the cluster's token here (RAY_AUTH_TOKEN=..., or RAY_AUTH_TOKEN_PATH; `ray "
        "get-auth-token` on the head prints it): none is set"
    )


def _reachable(address: str) -> None:
    """A ``HOST:PORT`` that does not answer is refused here in a few seconds (Ray itself keeps
    retrying for minutes)."""
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit():
        return  # "auto" and Ray's own address forms: Ray's check
    try:
        socket.create_connection((host or "127.0.0.1", int(port)), timeout=5).close()
    except OSError as err:
        raise ConfigError(
            f"cluster.address={address!r}: cannot connect to a Ray cluster "
            f"({err.strerror or err}); start one with `ray start --head`, check the address, "
            "or use cluster.address=local"
        ) from None


def _limited(fn: Callable[..., Any], cpus: float, driver: str, *args: Any) -> Any:
    """``fn(*args)`` with torch's and numba's thread pools cut to the task's CPUs: a pool of
    one thread per core of the machine in each of several tasks oversubscribes the cores,
    and numba's parallel kernels wait for their slowest thread (2 one-CPU nodes on 2 cores
    ran 0.42x one node's throughput so). Results do not depend on the number of threads.
    ``driver``: the driver's command, which the run folders the task writes record (a node's
    worker process has Ray's own command line, and another machine's environment)."""
    os.environ[ENV_COMMAND] = driver
    # Imported here: it loads torch, which a driver that only waits does not need
    from bgap.runner.threads import set_threads

    threads = max(1, int(cpus))
    set_threads(threads, threads)
    return fn(*args)


def run_tasks(
    cfg: ClusterConfig,
    fn: Callable[..., Any],
    calls: Sequence[tuple],
    done: Callable[[int, Any], None] | None = None,
    kept: str = "",
) -> list[Any]:
    """``fn(*call)`` for every call as Ray tasks of ``cfg``'s resources; the results in the
    order of ``calls`` (``done(k, result)`` as each arrives, for progress). Ctrl-C cancels
    the tasks still running and says so, and what was kept (``kept``)."""
    with connected(cfg) as ray:
        options: dict[str, Any] = {
            "num_cpus": cfg.cpus,
            "num_gpus": cfg.gpus,
            "max_retries": cfg.retries,
        }
        if kernels := pinned():  # the driver's (bgap.runner.numerics), before torch loads
            options["runtime_env"] = {"env_vars": kernels}
        remote = ray.remote(_limited).options(**options)
        driver = command()
        refs = [remote.remote(fn, cfg.cpus, driver, *call) for call in calls]
        index = {ref: k for k, ref in enumerate(refs)}
        results: list[Any] = [None] * len(refs)
        pending = list(refs)
        try:
            # Ctrl-C as a flag the wait loop polls, not a KeyboardInterrupt raised wherever
            # the main thread is (inside Ray's blocking wait, where one was once lost)
            with CtrlC() as ctrl_c:
                while pending:
                    ready, pending = ray.wait(pending, num_returns=1, timeout=POLL_SECONDS)
                    if ctrl_c.requested:
                        raise KeyboardInterrupt
                    for ref in ready:
                        k = index[ref]
                        results[k] = ray.get(ref)
                        if done is not None:
                            done(k, results[k])
        except ray.exceptions.RayTaskError as err:  # a task's own one-line error, as such
            cause = getattr(err, "cause", None)
            if isinstance(cause, (ConfigError, TrajectoryError)):
                raise cause from None
            raise
        except KeyboardInterrupt:
            for ref in pending:
                ray.cancel(ref, force=True)
            raise Interrupted(
                f"stopped: {len(refs) - len(pending)} of {len(refs)} tasks had finished; the "
                "cluster's others were cancelled" + (f"; {kept}" if kept else "")
            ) from None
        return results


POLL_SECONDS = 0.5
"""How often the driver, waiting for its tasks, looks whether Ctrl-C was pressed."""


def ship_folders(
    cfg: ClusterConfig,
    place: Callable[..., list[Path]],
    work: Callable[..., None],
    jobs: Sequence[tuple[tuple, list[Path]]],
    done: Callable[[int], None] | None = None,
) -> None:
    """Each job ``(args, folders)`` as one Ray task that works in run folders: the
    ``folders`` of this machine travel to the node, where ``place(base, *args)`` names
    their places under the task's folder ``base`` (:func:`task_folder`: ``cfg.storage``
    when set, so that a retried task resumes from the lost one's checkpoints), ``work(base,
    *args)`` writes them, and they come back whole over this machine's. ``done(k)`` as job
    ``k``'s folders are back. Ctrl-C says what was kept (:func:`kept_trainings`)."""
    calls = [
        (place, work, [pack(d) for d in folders], cfg.storage, *args) for args, folders in jobs
    ]

    def back(k: int, packed: list[bytes]) -> None:
        for data, folder in zip(packed, jobs[k][1], strict=True):
            unpack(data, folder)
        if done is not None:
            done(k)

    run_tasks(cfg, _in_folders, calls, back, kept_trainings(cfg.storage))


def _in_folders(
    place: Callable[..., list[Path]],
    work: Callable[..., None],
    packed: list[bytes],
    storage: str | None,
    *args: Any,
) -> list[bytes]:
    """On a node: :func:`ship_folders`' job, its folders sent back packed."""
    with task_folder(storage) as base:
        placed = place(base, *args)
        for data, folder in zip(packed, placed, strict=True):
            ship_in(data, folder)
        work(base, *args)
        return [pack(folder) for folder in placed]
