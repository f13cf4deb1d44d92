"""The harness's local worker processes (robot.bench.runners.LocalRunner), with a stand-in episode."""

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from concurrent.futures.process import _ExecutorManagerThread
from pathlib import Path

import pytest

from robot.bench.runners import Job, LocalRunner

pytestmark = pytest.mark.slow      # spawns worker processes


def episode(trial, config_path, step_log=None):
    """A stand-in for ``run_trial``: ``trial`` is ``(folder, index, seconds)``; marks where it got."""
    folder, index, seconds = trial
    Path(folder, f"{index}.started").write_text(str(os.getpid()))
    try:
        time.sleep(seconds)
    finally:
        Path(folder, f"{index}.cleaned").touch()    # the cleanup an interrupted episode must run
    Path(folder, f"{index}.done").touch()
    return {"index": index, "pid": os.getpid()}


def _marks(folder: Path, kind: str) -> set:
    return {int(p.stem) for p in folder.glob(f"*.{kind}")}


def test_every_job_runs_once_on_two_workers(tmp_path):
    jobs = [Job(i, (str(tmp_path), i, 0.05)) for i in range(6)]
    got = dict(LocalRunner(2, None, run=episode).results(jobs))
    assert sorted(got) == list(range(6)) and all(r["index"] == i for i, r in got.items())
    assert len({r["pid"] for r in got.values()}) == 2


@pytest.mark.parametrize("how", ["while the harness writes", "while it waits", "to the whole group"])
def test_an_interrupt_ends_the_workers_instead_of_running_the_queue(tmp_path, how):
    """Stopped after its first episode, the pool runs none of the queued ones, and the episodes
    that were running clean up; before, the harness's exit waited for every queued episode."""
    jobs = [Job(i, (str(tmp_path), i, 1.5)) for i in range(10)]
    finished = []
    with pytest.raises(KeyboardInterrupt):
        for index, result in LocalRunner(2, None, run=episode).results(jobs):
            finished.append(index)
            if how == "while the harness writes":
                raise KeyboardInterrupt
            if len(finished) > 1:
                continue
            running = _marks(tmp_path, "started") - _marks(tmp_path, "done")
            if how == "to the whole group":          # what a terminal's Ctrl-C does
                for i in running:
                    os.kill(int(Path(tmp_path, f"{i}.started").read_text()), signal.SIGINT)
                os.kill(os.getpid(), signal.SIGINT)
            timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))   # arrives in the pool's wait
            timer.start()
    started, done, cleaned = (_marks(tmp_path, k) for k in ("started", "done", "cleaned"))
    assert finished and len(started) <= 4 and len(done) < len(jobs), (finished, started, done)
    assert started == cleaned                        # every episode begun ran its cleanup
    for pid in {int(Path(tmp_path, f"{i}.started").read_text()) for i in started}:
        with pytest.raises(ProcessLookupError):      # no worker left behind
            os.kill(pid, 0)
    # nor the pool's manager thread, which would race the interpreter's exit for its wake-up pipe
    assert not [t for t in threading.enumerate() if isinstance(t, _ExecutorManagerThread)]


def test_a_stopped_run_prints_nothing_of_the_pools_insides(tmp_path):
    """Stopped while its workers run episodes with a progress bar, the harness's process ends
    without the interpreter's or the resource tracker's complaints: no "Exception ignored" from
    the pool's wake-up pipe, no "leaked semaphore objects" from the workers' progress bars."""
    (tmp_path / "stand_in.py").write_text(textwrap.dedent("""
        import time
        from tqdm import tqdm

        def episode(seconds, config_path, step_log=None):
            for _ in tqdm(range(1), disable=True):
                time.sleep(seconds)
            return {}
    """))
    (tmp_path / "stop.py").write_text(textwrap.dedent("""
        import os, signal, threading
        from stand_in import episode
        from robot.bench.runners import Job, LocalRunner

        if __name__ == "__main__":
            jobs = [Job(i, 0.2 if i == 0 else 5.0) for i in range(6)]
            try:
                for index, _ in LocalRunner(2, None, run=episode).results(jobs):
                    threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGINT)).start()
            except KeyboardInterrupt:
                print("stopped")
    """))
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(root)])}
    done = subprocess.run([sys.executable, str(tmp_path / "stop.py")], cwd=root, env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "stopped", done.stderr
    assert "leaked" not in done.stderr and "Exception ignored" not in done.stderr, done.stderr
