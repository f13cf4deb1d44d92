"""`python -m robot.run --mode navigate` end to end in the simulator, through the real CLI.

One mapping run of the tiny test world (the session's, conftest), then closed-loop episodes with the
default descriptor: the route `short` under another appearance seed than the map's, a kidnapped
start at a far node of the map, and bad inputs that must stop before the robot moves.
"""

import json
import math
import subprocess
import sys
from pathlib import Path

import networkx as nx
import pytest

from maps.store import load_map
from sim.worlds import load_world

TINY = Path(__file__).parent / "data" / "tiny_world.yaml"
# one torch thread: the machine is shared, and describe is then ~65 ms instead of >1 s
ENV_THREADS = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def _run(*args, timeout=300):
    import os
    env = {**os.environ, **ENV_THREADS}
    return subprocess.run([sys.executable, "-m", "robot.run", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


pytestmark = pytest.mark.slow      # closed-loop episodes in PyBullet through the CLI


@pytest.fixture(scope="module")
def tiny_map(tiny_mapping_run):
    """The session's map of the tiny world (conftest: drive, record, map through the CLI)."""
    return tiny_mapping_run / "map"


def _navigate(map_dir, tmp_path, *extra):
    result = tmp_path / "result.json"
    proc = _run("--mode", "navigate", "--world", str(TINY), "--map", str(map_dir), "--quiet",
                "--result", str(result), "--trace", str(tmp_path / "trace.png"), *extra)
    return proc, result


def _goal_xy():
    x, y, _ = load_world(TINY).routes.evaluation["short"].goal
    return float(x), float(y)


def test_route_short_under_another_appearance_reaches_the_goal(tiny_map, tmp_path):
    proc, result = _navigate(tiny_map, tmp_path, "--route", "short", "--appearance-seed", "3")
    data = json.loads(result.read_text())
    assert proc.returncode == 0, (proc.stderr, data["reason"])
    assert data["success"] and data["arrived"] and data["end"] == "arrived"
    assert data["final_distance_m"] <= 1.0
    assert data["shortest_length_m"] == pytest.approx(4.5)
    assert data["path_length_m"] > 2.0                     # it drove there, it was not placed there
    assert 0.0 < data["spl"] <= 1.0
    assert data["steps"] > 10 and data["sim_time_s"] > 1.0
    # the plan runs from where it localised to the goal node, and the goal node was visited last
    assert data["planned_nodes"][-1] == data["goal_node"] == data["visited_nodes"][-1]
    assert data["start_node"] == data["visited_nodes"][0]
    assert data["ms_per_step"]["describe_ms"] > 0
    assert data["setup"]["appearance_seed"] == 3
    assert (tmp_path / "trace.png").stat().st_size > 1000


def test_kidnapped_start_far_from_the_route_start_reaches_the_goal(tiny_map, tmp_path):
    """Placed at a map node far from the route start, the robot localises globally and plans
    from there; the node is one from which the route's goal node can be reached."""
    loaded = load_map(tiny_map)
    topomap = loaded.topomap
    gx, gy = _goal_xy()
    goal = min(topomap.nodes(), key=lambda n: math.hypot(n.true_pose.x_m - gx, n.true_pose.y_m - gy))
    start_xy = load_world(TINY).routes.evaluation["short"].start[:2]
    upstream = [topomap.node(n) for n in nx.ancestors(topomap.graph, goal.node_id)]
    far = [n for n in upstream if math.hypot(n.true_pose.x_m - start_xy[0], n.true_pose.y_m - start_xy[1]) > 2.5
           and math.hypot(n.true_pose.x_m - gx, n.true_pose.y_m - gy) > 0.7]
    assert far, "the tiny map has no node far from the route start upstream of the goal"
    kidnap = far[0]
    proc, result = _navigate(tiny_map, tmp_path, "--route", "short", "--start", f"node:{kidnap.node_id}")
    data = json.loads(result.read_text())
    assert proc.returncode == 0, (proc.stderr, data["reason"])
    assert data["success"], data["reason"]
    assert data["setup"]["start"] == f"node {kidnap.node_id} (kidnapped)"
    # it placed itself near where it was put, not at the route start
    first = topomap.node(data["start_node"]).true_pose
    assert math.hypot(first.x_m - kidnap.true_pose.x_m, first.y_m - kidnap.true_pose.y_m) < 1.0
    assert data["shortest_length_m"] is None and data["spl"] is None


def test_unknown_goal_node_exits_2_naming_it(tiny_map, tmp_path):
    proc, result = _navigate(tiny_map, tmp_path, "--start", "short", "--goal", "9999")
    assert proc.returncode == 2
    assert "9999" in proc.stderr and "goal node" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not result.exists()


def test_missing_goal_image_exits_2_naming_the_file(tiny_map, tmp_path):
    missing = tmp_path / "no_such_goal.png"
    proc, result = _navigate(tiny_map, tmp_path, "--start", "short", "--goal", str(missing))
    assert proc.returncode == 2
    assert str(missing) in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not result.exists()


def test_route_short_through_the_serial_link_reaches_the_goal(tiny_map, tmp_path):
    """The same episode with every command crossing the serial backend as bytes: the PyBullet
    Limo behind the base emulator on a pseudo-terminal, in real time (not lock-step)."""
    proc, result = _navigate(tiny_map, tmp_path, "--route", "short", "--appearance-seed", "3",
                             "--hal", "serial-twin")
    data = json.loads(result.read_text())
    assert proc.returncode == 0, (proc.stderr, data["reason"])
    assert data["success"] and data["final_distance_m"] <= 1.0
    assert data["path_length_m"] > 2.0
