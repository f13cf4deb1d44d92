"""Navigation through the serial backend: the Limo emulator in its own process on a
pseudo-terminal, the camera replayed from a video file, the real CLI; Ctrl-C must leave the base
commanded to zero velocity."""

from __future__ import annotations

import queue
import re
import signal
import subprocess
import sys
import threading
import time

import cv2
import numpy as np
import pytest

pytestmark = pytest.mark.slow      # the CLI over an emulated serial base, in real time

TINY_CONFIG = "descriptor:\n  backend: tiny\n"


def _places(n: int = 40) -> list[np.ndarray]:
    """A drive past distinct synthetic places: a long random mural seen through a sliding window."""
    rng = np.random.default_rng(7)
    mural = cv2.resize(rng.integers(0, 255, (6, 60, 3), dtype=np.uint8), (2400, 240),
                       interpolation=cv2.INTER_CUBIC)
    return [np.ascontiguousarray(mural[:, 20 * i: 20 * i + 320]) for i in range(n)]


@pytest.fixture(scope="module")
def serial_setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("serial")
    (root / "tiny.yaml").write_text(TINY_CONFIG)
    images = root / "imgs"
    images.mkdir()
    frames = _places()
    for i, img in enumerate(frames):
        cv2.imwrite(str(images / f"{i:04d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    video = root / "camera.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (320, 240))
    for img in frames[:5] * 40:           # the camera keeps seeing the start of the route
        writer.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    writer.release()
    proc = subprocess.run([sys.executable, "-m", "robot.run", "--mode", "map", "--images", str(images),
                           "--config", str(root / "tiny.yaml"), "--out", str(root / "run"), "--quiet"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return root


def _start_emulator():
    """The emulator process, its pty path and a queue of its status lines (stderr, every 0.1 s)."""
    emu = subprocess.Popen([sys.executable, "-m", "limo.emulator", "--status-every", "0.1"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    port = emu.stdout.readline().strip()
    assert port.startswith("/dev/"), port
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in emu.stderr], daemon=True).start()
    return emu, port, lines


def _commands(lines: "queue.Queue[str]", timeout_s: float) -> list[tuple[float, float]]:
    """Commanded (v, w) of the status lines arriving within ``timeout_s``."""
    out, deadline = [], time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            m = re.search(r"cmd v=([-+0-9.]+) w=([-+0-9.]+)", lines.get(timeout=0.2))
        except queue.Empty:
            continue
        if m:
            out.append((float(m.group(1)), float(m.group(2))))
    return out


def _wait_until_moving(nav: subprocess.Popen, lines: "queue.Queue[str]") -> None:
    """Until the navigation commands motion over the link (90 s at most; it must not exit)."""
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:
        if any(abs(v) > 0.01 or abs(w) > 0.01 for v, w in _commands(lines, 0.5)):
            return
        assert nav.poll() is None, nav.communicate()[1]
    raise AssertionError("the navigation never commanded motion over the serial link")


def _assert_left_at_zero(lines: "queue.Queue[str]") -> None:
    """The emulator's commanded velocity is zero right after the CLI exits (before its own
    watchdog would zero it)."""
    while not lines.empty():                                  # status from before the exit
        lines.get_nowait()
    after = _commands(lines, 0.4)
    assert after and all(v == 0.0 and w == 0.0 for v, w in after), after


@pytest.mark.parametrize("signum, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129)],
                         ids=["ctrl-c", "sigterm", "sighup"])
def test_a_signal_during_serial_navigation_leaves_the_base_at_zero(serial_setup, signum, status):
    """Ctrl-C, SIGTERM (systemd, docker, kill) and SIGHUP (a closed terminal) all end through the
    same cleanup: the last command on the wire is zero, before the firmware's own timeout."""
    root = serial_setup
    emu, port, lines = _start_emulator()
    try:
        nav = subprocess.Popen([sys.executable, "-m", "robot.run", "--mode", "navigate", "--hal", "serial",
                                "--port", port, "--camera", str(root / "camera.mp4"), "--map",
                                str(root / "run" / "map"), "--goal", "15", "--config", str(root / "tiny.yaml"),
                                "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _wait_until_moving(nav, lines)
        nav.send_signal(signum)
        _, err = nav.communicate(timeout=30)
        assert nav.returncode == status, err
        assert "stopped" in err and "Traceback" not in err
        _assert_left_at_zero(lines)
    finally:
        emu.send_signal(signal.SIGINT)
        emu.communicate(timeout=10)


def test_serial_navigation_needs_a_port_that_exists_and_a_goal(serial_setup):
    root = serial_setup
    base = [sys.executable, "-m", "robot.run", "--mode", "navigate", "--hal", "serial", "--map",
            str(root / "run" / "map"), "--config", str(root / "tiny.yaml")]
    no_port = subprocess.run(base + ["--goal", "3"], capture_output=True, text=True, timeout=60)
    # without --port the config's serial.port is used: /dev/ttyTHS1, which this machine lacks
    assert no_port.returncode == 2 and "/dev/ttyTHS1" in no_port.stderr and "does not exist" in no_port.stderr
    no_goal = subprocess.run(base + ["--port", "loop://"], capture_output=True, text=True, timeout=60)
    assert no_goal.returncode == 2 and "--goal" in no_goal.stderr
    bad_node = subprocess.run(base + ["--port", "loop://", "--goal", "999"], capture_output=True, text=True,
                              timeout=60)
    assert bad_node.returncode == 2 and "999" in bad_node.stderr and "Traceback" not in bad_node.stderr


def test_serial_navigation_never_loads_the_simulator(serial_setup):
    """--hal serial on the robot's own computer: the whole command up to opening the port (map,
    descriptor, goal) without pybullet."""
    root = serial_setup
    code = ("import runpy, sys\n"
            f"sys.argv = ['robot.run', '--mode', 'navigate', '--hal', 'serial', '--map', {str(root / 'run' / 'map')!r},"
            f" '--goal', '3', '--config', {str(root / 'tiny.yaml')!r}, '--port', '/dev/ttyNOPE']\n"
            "try:\n    runpy.run_module('robot.run', run_name='__main__')\n"
            "except SystemExit as exc:\n    print('exit', exc.code)\n"
            "print('pybullet' in sys.modules)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.stdout.split() == ["exit", "2", "False"], (proc.stdout, proc.stderr)
    assert "/dev/ttyNOPE" in proc.stderr


def test_a_serial_run_recorded_for_the_viewer_keeps_its_recording_after_ctrl_c(serial_setup, tmp_path):
    """--rerun-save on the real-base path: Ctrl-C stops the base as without it, and the recording
    of the steps made is at its name (moved into place on the way out), readable by Rerun."""
    rerun_chunk = pytest.importorskip("rerun.chunk")
    root = serial_setup
    rrd = tmp_path / "serial.rrd"
    emu, port, lines = _start_emulator()
    try:
        nav = subprocess.Popen([sys.executable, "-m", "robot.run", "--mode", "navigate", "--hal", "serial",
                                "--port", port, "--camera", str(root / "camera.mp4"), "--map",
                                str(root / "run" / "map"), "--goal", "15", "--config", str(root / "tiny.yaml"),
                                "--quiet", "--rerun-save", str(rrd)], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
        _wait_until_moving(nav, lines)
        nav.send_signal(signal.SIGINT)
        _, err = nav.communicate(timeout=30)
        assert nav.returncode == 130, err
        _assert_left_at_zero(lines)
    finally:
        emu.send_signal(signal.SIGINT)
        emu.communicate(timeout=10)
    store = rerun_chunk.RrdReader(rrd).store()
    ticks = sum(c.num_rows for c in store.stream().filter(content="/camera/image").to_chunks())
    assert ticks > 0 and "/map/true_pose" not in store.schema().entity_paths()   # a real base has no truth
    assert not list(tmp_path.glob(".*tmp*"))
