"""Where the paper harness's episodes run: in this process, in local worker processes, or as Ray
tasks (:mod:`robot.bench.cluster`).

Every runner takes the same jobs and yields each result as its episode finishes, in whatever
order. Results do not depend on the runner: an episode runs with one thread and its seeds are in
its trial (:func:`robot.bench.trials.worker_init`, :func:`robot.bench.trials.run_trial`).
"""

from __future__ import annotations

from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from multiprocessing import get_context
from typing import Iterator, Optional, Protocol, Sequence

from robot.bench.trials import Trial, run_trial, worker_init


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
    processes on this machine."""

    def __init__(self, workers: int, config_path: Optional[str]):
        self.workers = int(workers)
        self.config_path = config_path
        self.label = f"{self.workers} worker(s)"

    def results(self, jobs: Sequence[Job]) -> Iterator[tuple[int, dict]]:
        if self.workers <= 1 or len(jobs) <= 1:
            worker_init()
            for job in jobs:
                yield job.index, run_trial(job.trial, self.config_path, step_log=job.step_log)
            return
        # spawn: a fresh interpreter per worker (no forked PyBullet or torch state)
        with ProcessPoolExecutor(max_workers=min(self.workers, len(jobs)), mp_context=get_context("spawn"),
                                 initializer=worker_init) as pool:
            futures = {pool.submit(run_trial, job.trial, self.config_path, step_log=job.step_log): job.index
                       for job in jobs}
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    yield futures[future], future.result()

    def close(self) -> None:
        pass
