"""Where the paper harness's episodes run: in this process, in local worker processes, or as Ray
tasks (:mod:`robot.bench.cluster`).

Every runner takes the same jobs and yields each result as its episode finishes, in whatever
order. Results do not depend on the runner: an episode runs with one thread and its seeds are in
its trial (:func:`robot.bench.trials.worker_init`, :func:`robot.bench.trials.run_trial`).
"""

from __future__ import annotations

import os
import signal
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing import get_context
from typing import Callable, Iterator, Optional, Protocol, Sequence

from tqdm import tqdm

from robot.bench.trials import Trial, run_trial, worker_init

#: Seconds a stopped worker gets to run its episode's cleanup (close the simulator, remove a
#: half-written step log) before it is killed.
STOP_GRACE_S = 10.0
#: the signals that stop a worker: Ctrl-C reaches every process of the terminal's group, the
#: harness sends SIGTERM when it stops, a closed terminal SIGHUP
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
#: the exit status of a worker that a stop signal ended (:func:`_worker_stop`, :func:`_job`)
_STOPPED = tuple(128 + s for s in _STOP_SIGNALS)
_in_job = False   # in a worker process: whether an episode is running (its cleanup must run)


@dataclass(frozen=True)
class Job:
    """One episode to run: its place in the harness's plan, the trial, where its step log goes."""

    index: int
    trial: Trial
    step_log: Optional[str] = None


class TrialRunner(Protocol):
    """What the harness needs of a runner."""

    #: how the episodes ran, for the harness's last line ("2 worker(s)", "Ray, 8 CPUs")
    label: str

    def results(self, jobs: Sequence[Job]) -> Iterator[tuple[int, dict]]:
        """``(job.index, result)`` for every job, each as soon as its episode has finished."""

    def close(self) -> None:
        """Release workers or a cluster connection (idempotent)."""


class LocalRunner:
    """``--workers N``: episodes in this process (N = 1, or a single job) or in N spawned
    processes on this machine. ``run``: what runs a job (``run_trial``'s signature; a stand-in
    in tests).

    Stopping (Ctrl-C, SIGTERM, SIGHUP, or any error while results are read) cancels the queued
    episodes and ends the workers once their running episode has cleaned up (at most
    :data:`STOP_GRACE_S`, then they are killed): a process pool left to itself would run every
    queued episode before the harness could exit, hours of work whose results nobody keeps.
    """

    def __init__(self, workers: int, config_path: Optional[str], run: Callable[..., dict] = run_trial):
        self.workers = int(workers)
        self.config_path = config_path
        self.run = run
        self.label = f"{self.workers} worker(s)"

    def results(self, jobs: Sequence[Job]) -> Iterator[tuple[int, dict]]:
        if self.workers <= 1 or len(jobs) <= 1:
            worker_init()
            for job in jobs:
                yield job.index, self.run(job.trial, self.config_path, step_log=job.step_log)
            return
        # spawn: a fresh interpreter per worker (no forked PyBullet or torch state)
        pool = ProcessPoolExecutor(max_workers=min(self.workers, len(jobs)), mp_context=get_context("spawn"),
                                   initializer=_worker_start)
        futures = {pool.submit(_job, self.run, job.trial, self.config_path, step_log=job.step_log): job.index
                   for job in jobs}
        # the executor has no public way to end its workers before Python 3.14 (terminate_workers);
        # a spawning pool has started them all by the time every job is submitted
        workers = list(getattr(pool, "_processes", {}).values())
        try:
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    try:
                        result = future.result()
                    except BrokenProcessPool:
                        if any(p.exitcode in _STOPPED for p in workers):   # a stop reached the workers first
                            raise KeyboardInterrupt from None
                        raise
                    yield futures[future], result
        except BaseException:        # KeyboardInterrupt, GeneratorExit (the reader stopped), an episode's error
            _stop(pool, workers)
            raise
        pool.shutdown(wait=True)

    def close(self) -> None:
        pass


def _worker_start() -> None:
    """A worker process's initializer: one thread (:func:`worker_init`), the stop signals
    handled by :func:`_worker_stop`, and a thread lock for progress bars."""
    worker_init()
    # tqdm's default lock is a multiprocessing semaphore, which a worker ended by os._exit (a stop)
    # leaves to the resource tracker ("leaked semaphore objects"); no other process shares it here
    tqdm.set_lock(threading.RLock())
    for s in _STOP_SIGNALS:
        signal.signal(s, _worker_stop)


def _worker_stop(signum, frame) -> None:
    """A stop signal in a worker: an idle worker exits at once; a running episode gets
    ``KeyboardInterrupt``, so that its cleanup runs (:func:`_job` then ends the process)."""
    for s in _STOP_SIGNALS:                   # the cleanup must not be cut short
        signal.signal(s, signal.SIG_IGN)
    if not _in_job:
        os._exit(128 + signum)
    raise KeyboardInterrupt


def _job(run: Callable[..., dict], *args, **kwargs) -> dict:
    """One episode in a worker. Interrupted, the worker ends after the episode's cleanup instead of
    taking the next queued episode."""
    global _in_job
    _in_job = True
    try:
        return run(*args, **kwargs)
    except KeyboardInterrupt:
        os._exit(128 + signal.SIGINT)
    finally:
        _in_job = False


def _stop(pool: ProcessPoolExecutor, workers) -> None:
    """Cancel the queued episodes and end the workers (see :class:`LocalRunner`); a second Ctrl-C
    meanwhile is ignored, so that no worker is left running."""
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:            # not the main thread: signals go elsewhere
        previous = None
    try:
        _end_workers(pool, workers)
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _end_workers(pool: ProcessPoolExecutor, workers) -> None:
    # shutdown(wait=False) forgets the pool's manager thread (a second shutdown then joins nothing);
    # left running, it races the interpreter's exit hook for its wake-up pipe ("Bad file descriptor")
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)   # the queued episodes: cancelled by the pool's own thread
    for p in workers:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + STOP_GRACE_S
    for p in workers:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join()
    if manager is not None:
        manager.join(STOP_GRACE_S)      # it ends once it sees the workers gone
