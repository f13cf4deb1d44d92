"""`python -m robot.run --mode map` end to end on a small world, through the real CLI."""

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from maps.store import load_map
from robot.mapping.recording import read_recording

TINY = Path(__file__).parent / "data" / "tiny_world.yaml"


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "robot.run", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


pytestmark = pytest.mark.slow      # drives PyBullet over a world and starts the CLI


@pytest.fixture(scope="module")
def tiny_run(tiny_mapping_run):
    """The session's mapping run of the tiny world (conftest) and what the CLI printed."""
    return tiny_mapping_run, (tiny_mapping_run / "stdout.txt").read_text()


def test_mapping_run_records_frames_summary_and_picture(tiny_run):
    out, stdout = tiny_run
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
    assert "recorded" in stdout


def test_mapping_run_builds_a_map_along_the_drive(tiny_run):
    out, stdout = tiny_run
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames_read"] == summary["frames"]
    loaded = load_map(out / "map")
    topomap = loaded.topomap
    # 12 m at 0.3-1 m per node, every node at its true pose near the driven square
    assert 10 <= len(topomap) <= 45
    assert summary["nodes"] == len(topomap)
    for node in topomap.nodes():
        p = node.true_pose
        assert 0.5 < p.x_m < 5.5 and 0.5 < p.y_m < 3.5
    assert loaded.identity.backend == "effnet-vlad"
    # every keyframe's column profile (steering by bearing): 320 px at stride 32, unit columns
    assert loaded.columns.shape == (len(topomap), 10, 192)
    assert np.allclose(np.linalg.norm(loaded.columns, axis=-1), 1.0, atol=1e-2)
    # the drive's odometry heading at every node (navigation's turn hints): it turned as the truth did
    first = topomap.nodes()[0]
    for source in ("odometry", "gyro"):     # and the gyro's, integrated over every recorded frame
        headings = topomap.headings(source)
        for node in topomap.nodes():
            turned_map = headings[node.node_id] - headings[first.node_id]
            turned_true = node.true_pose.yaw_rad - first.true_pose.yaw_rad
            assert abs(math.remainder(turned_map - turned_true, math.tau)) < 0.15, (source, node.node_id)
    assert cv2.imread(str(out / "map" / "map.png")) is not None
    assert cv2.imread(str(out / "map" / "similarity.png")) is not None
    assert "nodes" in stdout and "loop closures" in stdout


def test_show_mode_redraws_the_pictures(tiny_run, tmp_path):
    out, _ = tiny_run
    copy = shutil.copytree(out / "map", tmp_path / "map")        # the session's map stays untouched
    (copy / "map.png").unlink()
    proc = _run("--mode", "show", "--map", str(copy))
    assert proc.returncode == 0, proc.stderr
    assert cv2.imread(str(copy / "map.png")) is not None


def test_map_from_a_video_without_a_robot(tiny_run, tmp_path):
    """The recorded drive written as an MP4 (as from a phone), mapped with --video --every."""
    out, _ = tiny_run
    frames = read_recording(out)
    video = tmp_path / "walk.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 5.0, (320, 240))
    assert writer.isOpened()
    for f in frames:
        writer.write(cv2.cvtColor(f.load_rgb(), cv2.COLOR_RGB2BGR))
    writer.release()
    proc = _run("--mode", "map", "--video", str(video), "--every", "2", "--out", str(tmp_path / "vmap"), "--quiet")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "vmap" / "summary.json").read_text())
    assert summary["frames_read"] == (len(frames) + 1) // 2
    loaded = load_map(tmp_path / "vmap" / "map")
    assert 5 <= len(loaded.topomap) <= summary["frames_read"] // 2
    assert all(node.true_pose is None for node in loaded.topomap.nodes())   # a video knows no poses
    assert loaded.topomap.odom_headings is None and loaded.topomap.headings("gyro") is None   # nor odometry, gyro
    assert cv2.imread(str(tmp_path / "vmap" / "map" / "map.png")) is not None


def test_map_from_an_image_folder_and_bad_sources(tiny_run, tmp_path):
    out, _ = tiny_run
    folder = tmp_path / "imgs"
    folder.mkdir()
    for f in read_recording(out)[:60]:
        cv2.imwrite(str(folder / f"{f.index:05d}.jpg"), cv2.cvtColor(f.load_rgb(), cv2.COLOR_RGB2BGR))
    proc = _run("--mode", "map", "--images", str(folder), "--out", str(tmp_path / "imap2"), "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "imap2" / "summary.json").read_text())["frames_read"] == 60
    missing = _run("--mode", "map", "--video", str(tmp_path / "nope.mp4"), "--out", str(tmp_path / "x"), "--quiet")
    assert missing.returncode == 2 and "nope.mp4" in missing.stderr and "Traceback" not in missing.stderr
    (tmp_path / "bad.mp4").write_bytes(b"not a video at all")
    bad = _run("--mode", "map", "--video", str(tmp_path / "bad.mp4"), "--out", str(tmp_path / "y"), "--quiet")
    assert bad.returncode == 2 and "bad.mp4" in bad.stderr


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
    # interrupt the drive itself: once frames are being recorded (a fixed sleep would hit the
    # interpreter's start-up on a busy machine)
    deadline = time.monotonic() + 120
    while not list(tmp_path.glob(".tiny.saving-*/frames/000005.jpg")) and time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert not out.exists()
    assert not any(p.name.startswith(".tiny") for p in tmp_path.iterdir())


def test_a_drive_starting_just_past_a_corner_closes_its_loop(tmp_path):
    """The walkthrough begins 0.3 m past a turn and ends 0.6 m past its start: the frames past the
    start are all the revisit there is, and the loop must still close onto the start."""
    import yaml
    spec = yaml.safe_load(TINY.read_text())
    spec["name"] = "tiny-corner"
    spec["routes"]["walkthrough"] = [[1.3, 1], [5, 1], [5, 3], [1, 3], [1, 1], [1.9, 1]]
    world = tmp_path / "tiny_corner.yaml"
    world.write_text(yaml.safe_dump(spec))
    out = tmp_path / "run"
    proc = _run("--mode", "map", "--world", str(world), "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    loaded = load_map(out / "map")
    closures = loaded.log.loop_closure_events()
    assert len(closures) == 1, [(e.seq, e.prev_node, e.node_id) for e in closures]
    closure = closures[0]
    frames = read_recording(out)
    seen_at = frames[closure.seq].true_pose
    matched = loaded.topomap.node(closure.node_id).true_pose
    assert seen_at.distance_to(matched) < 0.5, (seen_at, matched)
    assert abs(math.remainder(seen_at.yaw_rad - matched.yaw_rad, 2 * math.pi)) < math.radians(30)


@pytest.mark.parametrize("world", ["warehouse", "garage"])
def test_a_walk_begun_past_a_corner_closes_its_loop_onto_its_start(tmp_path, world):
    """The warehouse's and the garage's walkthroughs start 0.3 m past a corner and end 0.6 m past
    their start; the only revisit is those last frames, which no node decision offers as a
    candidate."""
    out = tmp_path / world
    proc = _run("--mode", "map", "--world", world, "--out", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    loaded = load_map(out / "map")
    closures = loaded.log.loop_closure_events()
    assert len(closures) == 1, [(e.seq, e.prev_node, e.node_id) for e in closures]
    start = loaded.topomap.node(0).true_pose
    matched = loaded.topomap.node(closures[0].node_id).true_pose
    assert start.distance_to(matched) < 1.5, matched
    assert loaded.topomap.arc(closures[0].prev_node, closures[0].node_id).kind == "loop_closure"
