"""The Rerun viewer (robot.viewer): recordings written with the real SDK and read back with its
own reader (``rerun.chunk.RrdReader``), the flags' errors, and that recording never changes a run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from maps.config import MappingConfig
from maps.pipeline import build_map
from robot.episode.loop import run_episode
from robot.viewer import scene
from robot.viewer.mapping import log_map_build
from robot.viewer.navigation import NavigationLogger, similarity_colours
from robot.viewer.scene import node_positions
from robot.viewer.stream import Recording, ViewerTarget
from tests.conftest import run_cli
from tests.map_synthetic import landmark_route
from tests.memory_base import MemoryBase
from tests.test_episode_loop import CONFIG, N_NODES, chain  # noqa: F401  (the fixture)

rerun = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _rows(path: Path) -> dict[str, int]:
    """Entity path -> rows logged on the timelines (static rows not counted)."""
    store = RrdReader(path).store()
    out: dict[str, int] = {}
    for chunk in store.stream().to_chunks():
        if not chunk.is_static:
            out[chunk.entity_path] = out.get(chunk.entity_path, 0) + chunk.num_rows
    return out


def _entities(path: Path) -> set[str]:
    return set(RrdReader(path).store().schema().entity_paths())


def _texts(path: Path, entity: str, timeline: str) -> list[str]:
    """The text lines logged to ``entity``, in ``timeline`` order."""
    lines = []
    for chunk in RrdReader(path).store().stream().filter(content=entity).to_chunks():
        batch = chunk.to_record_batch()
        times = batch.column(timeline).to_pylist() if timeline in batch.column_names else [-1] * batch.num_rows
        for name in batch.column_names:
            if name.endswith(":text"):
                lines += [(t, text[0]) for t, text in zip(times, batch.column(name).to_pylist()) if text]
    return [text for _, text in sorted(lines, key=lambda pair: pair[0])]


def test_an_episode_is_recorded_step_by_step_and_reads_back(chain, tmp_path):  # noqa: F811
    topomap, descriptor = chain
    path = tmp_path / "episode.rrd"
    base = MemoryBase()
    base.connect()
    with Recording(ViewerTarget(save_path=path), "chain") as recording:
        viewer = NavigationLogger(recording.rr, recording.stream, topomap)
        viewer.setup(N_NODES - 1, np.zeros((4, 6, 3), np.uint8), "node id")
        outcome = run_episode(base, topomap, descriptor, N_NODES - 1, CONFIG, 400, observer=viewer.observer,
                              thirds_contrast=False)
    base.close()
    assert path.is_file() and not list(tmp_path.glob(".*tmp*")), "the file is moved into place when it closes"
    entities = _entities(path)
    for entity in ("/camera/image", "/camera/thirds", "/goal/image", "/map/arcs", "/map/nodes", "/map/goal",
                   "/map/current", "/map/target", "/map/plan", "/navigator/decision", "/navigator/events",
                   "/scores/current", "/scores/target", "/command/v_mps", "/command/w_radps", "/timing/describe_ms"):
        assert entity in entities, f"{entity} missing from {sorted(entities)}"
    rows = _rows(path)
    assert rows["/camera/image"] == outcome.steps == rows["/navigator/decision"] == rows["/command/v_mps"]
    assert len(viewer.step_ms) == outcome.steps
    events = _texts(path, "/navigator/events", scene.TICK)
    assert events[-1].startswith(f"step {outcome.steps - 1}: arrived"), events[-3:]


def test_the_map_build_is_logged_decision_by_decision(tmp_path):
    route = landmark_route()
    build = build_map(route.descriptors, MappingConfig(), true_poses=route.poses, stamps_s=route.stamps_s)
    assert build.log.loop_closure_events(), "the synthetic square should close its loop"
    images = [np.full((8, 12, 3), k % 255, np.uint8) for k in range(len(route.poses))]
    path = tmp_path / "map.rrd"
    with Recording(ViewerTarget(save_path=path), "square") as recording:
        logged = log_map_build(recording.rr, recording.stream, route.stamps_s, images, route.descriptors, build,
                               route.poses)
    assert logged == len(images)
    rows = _rows(path)
    assert rows["/camera/image"] == len(images) == rows["/map/robot"]
    assert rows["/map/nodes"] == len(build.raw_map)          # one update per node added
    assert rows["/map/loops"] == sum(e.new_arc for e in build.log.loop_closure_events())
    events = _texts(path, "/mapping/events", scene.FRAME)
    assert len(events) == len(build.log.events) + 1
    assert sum(e.startswith("loop closure") for e in events) == len(build.log.loop_closure_events())
    assert sum(e.startswith(f"map done: {len(build.topomap)} nodes") for e in events) == 1


def test_nodes_without_true_poses_get_a_seeded_layout(chain):  # noqa: F811
    from maps.graph import TopoMap

    topomap, _ = chain
    positions, true = node_positions(topomap)
    assert true and positions[:, 0].tolist() == list(range(N_NODES)) and not positions[:, 1].any()
    bare = TopoMap(topomap.dim)
    for k in range(N_NODES):
        bare.add_node(topomap.descriptors[k], keyframe_index=k, stamp_s=float(k))
    for k in range(N_NODES - 1):
        bare.add_arc(k, k + 1, 1.0, "sequential")
    a, true_a = node_positions(bare)
    b, _ = node_positions(bare)
    assert not true_a and np.array_equal(a, b) and len({tuple(p) for p in a.round(3)}) == N_NODES


def test_similarity_colours_run_from_the_least_to_the_most_alike():
    colours = similarity_colours(np.array([0.2, 0.9, 0.5]))
    assert colours.dtype == np.uint8 and colours.shape == (3, 3)
    assert colours[1, 0] > colours[2, 0] > colours[0, 0]
    assert (similarity_colours(np.array([0.5, 0.5])) == similarity_colours(np.array([0.1, 0.1]))).all()


def _blocked_rerun(tmp_path: Path) -> dict:
    """An environment in which ``import rerun`` fails, as on an install without the extra."""
    blocker = tmp_path / "blocker" / "rerun"
    blocker.mkdir(parents=True)
    (blocker / "__init__.py").write_text("raise ImportError('rerun-sdk is not installed')\n")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path / "blocker"), str(ROOT)])}


@pytest.mark.parametrize("command", [
    ("robot.run", "--mode", "navigate", "--route", "short", "--rerun"),
    ("robot.bench", "replay", "EPISODE", "--rerun-save", "x.rrd"),
])
def test_without_the_sdk_the_flags_say_how_to_install_it(tmp_path, command):
    (tmp_path / "map").mkdir()
    episode = tmp_path / "episode.json"
    episode.write_text("{}")        # the flags are checked before the episode file is read
    args = [a.replace("EPISODE", str(episode)) for a in command]
    if command[0] == "robot.run":
        args += ["--map", str(tmp_path / "map")]
    proc = subprocess.run([sys.executable, "-m", *args], cwd=tmp_path, env=_blocked_rerun(tmp_path),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "pip install -e '.[viz]'" in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr
    assert not (tmp_path / "x.rrd").exists()


@pytest.mark.parametrize("flag, value, says", [("--rerun-save", "out.txt", "ends in .rrd"),
                                               ("--rerun-save", "file/x.rrd", "is a file, not a folder"),
                                               ("--rerun", "laptop:9876", "expected a viewer URL")])
def test_a_recording_target_that_cannot_work_is_refused_before_any_work(tmp_path, flag, value, says):
    (tmp_path / "map").mkdir()
    (tmp_path / "file").write_text("")
    target = str(tmp_path / value) if flag == "--rerun-save" else value
    proc = run_cli("robot.run", "--mode", "navigate", "--map", str(tmp_path / "map"), "--route", "short",
                   flag, target, timeout=120)
    assert proc.returncode == 2 and says in proc.stderr and flag in proc.stderr, proc.stderr


@pytest.mark.slow
def test_a_tiny_world_episode_with_a_recording_makes_the_same_decisions(tiny_mapping_run, tmp_path):
    """The same seeded episode with and without --rerun-save: the same result, and the file
    holds one camera frame and one decision per control step."""
    results = []
    for name, extra in (("plain", []), ("recorded", ["--rerun-save", str(tmp_path / "nav.rrd")])):
        result = tmp_path / f"{name}.json"
        proc = run_cli("robot.run", "--mode", "navigate", "--world", str(ROOT / "tests/data/tiny_world.yaml"),
                       "--map", str(tiny_mapping_run / "map"), "--route", "short", "--appearance-seed", "3",
                       "--out", str(tmp_path / name), "--result", str(result), "--quiet", *extra)
        assert proc.returncode == 0, proc.stderr
        data = json.loads(result.read_text())
        results.append({k: v for k, v in data.items() if k not in ("wall_time_s", "ms_per_step", "setup")})
    assert results[0] == results[1]
    rows = _rows(tmp_path / "nav.rrd")
    steps = results[0]["steps"]
    assert rows["/camera/image"] == rows["/navigator/decision"] == rows["/map/true_pose"] == steps
    assert {"/map/true_pose", "/map/start_pose", "/map/goal_pose", "/goal/image", "/scores/goal_image",
            "/map/belief"} <= _entities(tmp_path / "nav.rrd")
    chunk = next(iter(RrdReader(tmp_path / "nav.rrd").store().stream().filter(content="/camera/image").to_chunks()))
    assert {scene.TICK, scene.SIM_TIME} <= set(chunk.timeline_names)
