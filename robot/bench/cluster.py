"""Episodes as Ray tasks: ``python -m robot.bench paper --ray [ADDRESS]``.

Without an address a local Ray instance starts, sized to ``--workers`` CPUs (default: every CPU
of this machine); with one (``auto``, ``HOST:PORT``, ``ray://HOST:10001``) the harness joins that
cluster and each episode takes one of its CPUs. Every episode is one task
(:func:`_episode_task`); Ray reruns a task whose worker process or node died, up to
:data:`TASK_RETRIES` times, and the episode then runs again from its start, with the same seeds.

What an episode reads (the map folder, the baseline's head, a world file, the ``--config`` file)
is packed once on the driver and reaches the workers through Ray's object store: each node
unpacks it once into a cache keyed by its content (:func:`materialise`). What an episode writes
(its trace picture, its step log) comes back with its result and the driver writes it where the
trial says. With ``--ray-shared`` the run folder is on a file system every node mounts at the
same path: workers read and write there directly and nothing is shipped.

The worker nodes need this project installed (``pip install -e '.[cluster]'``, with the same
version of Ray and Python as the driver); they need no copy of the run folder.
"""

from __future__ import annotations

import hashlib
import io
import os
import shutil
import socket
import tarfile
import tempfile
from dataclasses import asdict, replace
from pathlib import Path
from typing import Iterator, Optional, Sequence

from core.atomic import AtomicFolder, remove_debris, write_bytes
from robot.bench.runners import Job
from robot.bench.trials import Trial

#: how often Ray reruns an episode whose worker process or node died, or that Ray's memory
#: monitor stopped (not an error the episode raised)
TASK_RETRIES = 3
#: the hint every "Ray is missing" message gives
INSTALL_HINT = "pip install -e '.[cluster]'"
#: a local instance means no address; ``--ray`` alone asks for it
LOCAL = "local"
#: the trial fields naming a file or folder an episode reads
INPUT_FIELDS = ("map_dir", "baseline_path", "world")


class ClusterError(ValueError):
    """Ray is missing, or the cluster cannot be reached; the message names the option."""


class EpisodeLost(RuntimeError):
    """An episode's task failed for good (its worker died more than TASK_RETRIES times)."""


def import_ray():
    """The ``ray`` module, or a :class:`ClusterError` that says how to install it."""
    try:
        import ray
    except ImportError:
        raise ClusterError(f"--ray needs Ray, which is not installed: {INSTALL_HINT}") from None
    return ray


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Refuse an address where nothing listens within ``timeout_s`` (``ray.init`` would retry for
    minutes); ``auto`` is left to Ray, which answers at once when no cluster runs here."""
    if address == "auto":
        return
    target = address.split("://", 1)[1] if "://" in address else address
    host, sep, port = target.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ClusterError(f"--ray {address!r}: expected auto, HOST:PORT or ray://HOST:PORT")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise ClusterError(f"--ray {address}: no Ray cluster answers there ({exc.strerror or exc}); start one "
                           "with `ray start --head` or run --ray without an address for a local one") from None


# -- what episodes read, shipped through the object store ----------------------------------------
def pack(path: str | Path) -> tuple[str, bytes]:
    """``(kind, data)`` of a file (its bytes) or a folder (an uncompressed tar of its content)."""
    path = Path(path)
    if path.is_dir():
        buf = io.BytesIO()
        with tarfile.open(fileobj=buf, mode="w") as tar:
            for child in sorted(path.iterdir()):
                tar.add(child, arcname=child.name)
        return "folder", buf.getvalue()
    return "file", path.read_bytes()


def content_key(kind: str, name: str, data: bytes) -> str:
    """The cache key of a packed input: its kind, name and content."""
    digest = hashlib.sha256(f"{kind}\0{name}\0".encode() + data).hexdigest()[:20]
    return f"{digest}/{name}"


def cache_root() -> Path:
    """Where a node keeps the inputs it unpacked (one folder per content, shared by its workers)."""
    return Path(tempfile.gettempdir()) / "limo-toponav-ray"


def materialise(kind: str, key: str, data: bytes, root: Optional[Path] = None) -> Path:
    """The local path of a packed input, unpacked under ``root`` (default :func:`cache_root`) on
    first use. Concurrent workers race safely: each unpacks into a hidden folder of its own and
    the first to finish is kept (the others may already be reading it)."""
    target = (root or cache_root()) / key
    if target.exists():
        return target
    if kind == "folder":
        with AtomicFolder(target) as folder:
            with tarfile.open(fileobj=io.BytesIO(data), mode="r") as tar:
                tar.extractall(folder.path, filter="data")
            folder.commit_unless_present()
    else:
        write_bytes(target, data)
    return target


def _path_fields(trial: Trial, names: Sequence[str] = INPUT_FIELDS) -> dict[str, str]:
    """``trial``'s fields among ``names`` that name a file or folder (a world given by name is in
    the package)."""
    return {name: value for name in names
            if (value := getattr(trial, name)) and (name != "world" or Path(value).is_file())}


def _input_paths(trial: Trial) -> list[str]:
    """The files and folders ``trial`` reads."""
    return list(_path_fields(trial).values())


# -- the task -------------------------------------------------------------------------------------
_WORKER_READY = False


def _episode_task(trial_fields: dict, config: Optional[tuple], inputs: dict, step_log: Optional[str],
                  shared: bool) -> dict:
    """Run one trial in a Ray worker. ``inputs``: path -> (kind, key, object ref) of what it reads,
    ``config``: the same for the ``--config`` file (in a shared folder: ``(kind, path, None)``).
    Returns the result (the driver puts back the trial it planned) and ``files``: the outputs'
    bytes by the path the driver writes them to."""
    global _WORKER_READY
    import ray

    from robot.bench.trials import run_trial, worker_init
    from robot.episode.step_log import views_path

    if not _WORKER_READY:
        worker_init()
        _WORKER_READY = True

    def local(entry) -> str:
        kind, key, ref = entry
        cached = cache_root() / key
        return str(cached if cached.exists() else materialise(kind, key, ray.get(ref)))

    trial = Trial(**trial_fields)
    config_path = None if config is None else (config[1] if shared else local(config))
    outputs: dict[str, str] = {}          # where the episode writes here -> where the driver wants it
    scratch = None
    if not shared:
        trial = replace(trial, **{name: local(inputs[value]) for name, value in _path_fields(trial).items()
                                  if value in inputs})
        scratch = Path(tempfile.mkdtemp(prefix="limo-toponav-episode-"))
        here_trace = here_log = None
        if trial.trace_png:
            here_trace = str(scratch / "trace.png")
            outputs[here_trace] = trial.trace_png
        if step_log:                     # the step log and the views saved beside it
            here_log = str(scratch / "episode.steps.jsonl")
            outputs[here_log] = step_log
            outputs[str(views_path(here_log))] = str(views_path(step_log))
        trial, step_log = replace(trial, trace_png=here_trace), here_log
    try:
        result = run_trial(trial, config_path, step_log=step_log)
        files = {target: Path(here).read_bytes() for here, target in outputs.items() if Path(here).is_file()}
    finally:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
    result["timing"]["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return {"result": result, "files": files}


class RayRunner:
    """Episodes as Ray tasks on a local instance (``address`` None) of ``num_cpus`` CPUs, or on the
    cluster at ``address``. ``shared``: the run folder is at the same path on every node."""

    def __init__(self, address: Optional[str], num_cpus: Optional[int], config_path: Optional[str],
                 shared: bool = False):
        ray = import_ray()
        if address is not None:
            _check_reachable(address)
        self._ray = ray
        self._started = not ray.is_initialized()     # else a caller's own ray.init: use that one
        self.shared = shared
        self.config_path = config_path
        options = {"include_dashboard": False, "log_to_driver": False, "logging_level": "WARNING"}
        if self._started:
            try:
                if address is None:
                    ray.init(num_cpus=num_cpus, **options)
                else:
                    ray.init(address=address, **options)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise ClusterError(f"--ray {address or '(local instance)'}: {exc}") from None
        cpus = int(ray.cluster_resources().get("CPU", 0))
        nodes = sum(1 for n in ray.nodes() if n.get("Alive"))
        where = "local instance" if address is None else address
        self.label = f"Ray ({where}: {nodes} node(s), {cpus} CPU(s))"
        self._task = ray.remote(num_cpus=1, max_retries=TASK_RETRIES, retry_exceptions=False)(_episode_task)

    def _ship(self, path: str) -> tuple:
        """``(kind, key, object ref)`` of a packed input, put into the object store once."""
        kind, data = pack(path)
        return kind, content_key(kind, Path(path).name, data), self._ray.put(data)

    def results(self, jobs: Sequence[Job]) -> Iterator[tuple[int, dict]]:
        ray = self._ray
        if not jobs:
            return
        inputs: dict = {}
        config = None
        if self.shared:
            if self.config_path is not None:
                config = ("file", str(Path(self.config_path).resolve()), None)
        else:
            for job in jobs:
                for path in _input_paths(job.trial):
                    if path not in inputs:
                        inputs[path] = self._ship(path)
            if self.config_path is not None:
                config = self._ship(self.config_path)
        refs = {}
        for job in jobs:
            needed = {p: inputs[p] for p in _input_paths(job.trial) if p in inputs}
            trial, step_log = job.trial, job.step_log
            if self.shared:          # workers may run in another folder
                trial = _absolute(trial)
                step_log = None if step_log is None else str(Path(step_log).resolve())
            refs[self._task.remote(asdict(trial), config, needed, step_log, self.shared)] = job
        pending = list(refs)
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for ref in done:
                    job = refs[ref]
                    try:
                        answer = ray.get(ref)
                    except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError,
                            ray.exceptions.ObjectLostError, ray.exceptions.OutOfMemoryError) as exc:
                        raise EpisodeLost(f"episode {job.trial.key}: its worker died {TASK_RETRIES + 1} times "
                                          f"({type(exc).__name__}); the finished episodes are kept") from None
                    for target, data in answer["files"].items():
                        write_bytes(target, data)
                    if self.shared:      # what an attempt killed mid-write left beside the outputs
                        for target in _outputs_of(job):
                            remove_debris(target)
                    yield job.index, {**answer["result"], "trial": asdict(job.trial)}
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)

    def close(self) -> None:
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()
        self._started = False


def _outputs_of(job: Job) -> list[str]:
    """The files an episode writes: its trace picture, its step log and the views beside it."""
    from robot.episode.step_log import views_path

    logs = [job.step_log, str(views_path(job.step_log))] if job.step_log else []
    return [p for p in [job.trial.trace_png, *logs] if p]


def _absolute(trial: Trial) -> Trial:
    """The trial with every path it reads or writes absolute (workers may run in another folder)."""
    fields = _path_fields(trial, (*INPUT_FIELDS, "trace_png"))
    return replace(trial, **{name: str(Path(value).resolve()) for name, value in fields.items()})
