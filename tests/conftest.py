"""Shared fixtures and safeguards for the whole test session.

Two lanes: ``python -m pytest -q`` runs the fast lane (the default, ``-m "not slow"`` in
pyproject.toml); ``python -m pytest -q -m slow`` runs what drives PyBullet over a world, runs the
CNN on many frames, starts subprocesses or runs in real time. ``.ci/run`` runs both.
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
TINY_WORLD = TESTS / "data" / "tiny_world.yaml"
#: the helper-thread variables that the harness's worker_init sets for its process
_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")


def _sigint_ignored_by_the_kernel() -> bool:
    """SIGINT set to SIG_IGN at the C level (by a native library: Python's ``getsignal`` still
    reports its own handler then); children inherit an ignored SIGINT and never see Ctrl-C."""
    if not sys.platform.startswith("linux"):
        return False

    class SigAction(ctypes.Structure):
        _fields_ = [("handler", ctypes.c_void_p), ("mask", ctypes.c_ulong * 16), ("flags", ctypes.c_int),
                    ("restorer", ctypes.c_void_p)]

    old = SigAction()
    if ctypes.CDLL(None, use_errno=True).sigaction(signal.SIGINT, None, ctypes.byref(old)) != 0:
        return False
    return old.handler == signal.SIG_IGN.value


@pytest.fixture(scope="session", autouse=True)
def _onnx_cache(tmp_path_factory):
    """Exported ONNX graphs go to a folder of this session (and of its subprocesses), not to the
    user's cache."""
    before = os.environ.get("LIMO_TOPONAV_CACHE")
    os.environ["LIMO_TOPONAV_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    yield
    if before is None:
        os.environ.pop("LIMO_TOPONAV_CACHE", None)
    else:
        os.environ["LIMO_TOPONAV_CACHE"] = before


@pytest.fixture(autouse=True)
def _process_state_stays_as_found(request):
    """Tests that run the harness in this process (its ``worker_init``) leave one torch thread
    and ``OPENBLAS_NUM_THREADS=1`` behind, which every later subprocess inherits; commands run
    in-process install their SIGTERM / SIGHUP handlers; SIGINT must stay deliverable (Python's
    handler, unblocked, not ignored by the kernel) for the Ctrl-C tests. Restore all of it after
    each test, and name a test that broke SIGINT."""
    env = {name: os.environ.get(name) for name in _THREAD_VARIABLES}
    torch = sys.modules.get("torch")
    threads = torch.get_num_threads() if torch is not None else None
    handlers = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP)}   # CLIs run in-process set them
    yield
    for signum, handler in handlers.items():
        signal.signal(signum, handler)
    for name, value in env.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
    torch = sys.modules.get("torch")
    if torch is not None and threads is not None and torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    handler = signal.getsignal(signal.SIGINT)
    blocked = signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    ignored = _sigint_ignored_by_the_kernel()
    if handler is not signal.default_int_handler or blocked or ignored:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])
        state = "blocked" if blocked else "ignored at the C level" if ignored else repr(handler)
        warnings.warn(f"{request.node.nodeid} left SIGINT {state}; restored")


def run_cli(module: str, *args: str, timeout: float = 300, **kwargs) -> subprocess.CompletedProcess:
    """``python -m module args...`` in a subprocess, output captured as text."""
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True,
                          timeout=timeout, **kwargs)


@pytest.fixture(scope="session")
def tiny_mapping_run(tmp_path_factory) -> Path:
    """The tiny test world driven, recorded and mapped once through the real CLI
    (``python -m robot.run --mode map``), shared by every test that needs a recording or a map of
    it: the folder holds the recording, ``summary.json``, ``world.png`` and ``map/``. Read only."""
    out = tmp_path_factory.mktemp("tiny-run") / "tiny"
    proc = run_cli("robot.run", "--mode", "map", "--world", str(TINY_WORLD), "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    (out / "stdout.txt").write_text(proc.stdout)
    return out
