"""`python -m robot.run --mode map` end to end on a small world, through the real CLI."""

import json
import subprocess
import sys
from pathlib import Path

import cv2

from robot.recording import read_recording

TINY = Path(__file__).parent / "data" / "tiny_world.yaml"


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "robot.run", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


def test_mapping_run_records_frames_summary_and_picture(tmp_path):
    out = tmp_path / "tiny"
    proc = _run("--mode", "map", "--world", str(TINY), "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["world"] == "tiny"
    # the loop is 12 m; the teleoperator drives all of it and stops near the start
    assert 11.0 < summary["metres_driven"] < 13.5
    assert summary["frames"] > 100 and summary["duration_s"] > 20
    frames = read_recording(out)
    assert len(frames) == summary["frames"]
    assert frames[-1].true_pose.distance_to(frames[0].true_pose) < 0.5
    assert frames[5].load_rgb().shape == (240, 320, 3)
    picture = cv2.imread(str(out / "world.png"))
    assert picture is not None and picture.shape[0] > 100
    assert "recorded" in proc.stdout


def test_bad_world_file_names_file_and_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(TINY.read_text().replace("size_m: [6.0, 4.0]", "size_m: [6.0, wide]"))
    out = tmp_path / "never"
    proc = _run("--mode", "map", "--world", str(bad), "--out", str(out), "--quiet")
    assert proc.returncode == 2
    assert "bad.yaml" in proc.stderr and "floor.size_m" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not out.exists()


def test_unknown_world_lists_the_available_ones(tmp_path):
    proc = _run("--mode", "map", "--world", "moonbase", "--out", str(tmp_path / "x"), "--quiet")
    assert proc.returncode == 2
    assert "hospital" in proc.stderr and "office" in proc.stderr


def test_ctrl_c_stops_cleanly_and_leaves_no_partial_recording(tmp_path):
    import signal
    import time

    out = tmp_path / "tiny"
    proc = subprocess.Popen([sys.executable, "-m", "robot.run", "--mode", "map", "--world", str(TINY),
                             "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(4.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert not out.exists()
    assert not any(p.name.startswith(".tiny") for p in tmp_path.iterdir())
