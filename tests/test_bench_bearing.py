"""``python -m robot.bench bearing``: the probe poses, the node choice, and the table on the tiny
world's map (real PyBullet views, the real descriptor)."""

from __future__ import annotations

import json
import math

import pytest

from robot.bench.bearing import BearingBenchError, default_nodes, parse_ids, probe_poses
from tests.conftest import TINY_WORLD, run_cli


def test_probe_poses_lie_before_the_node_beside_and_turned_off_its_heading():
    beside, turned = probe_poses(2.0, 1.0, math.pi / 2, before_m=0.6, lateral_m=0.5, turn_deg=10.0)
    # facing +y, 0.6 m before the node is y = 0.4; left of +y is -x
    assert beside[1] == pytest.approx((2.0, 0.4, math.pi / 2))
    assert beside[0] == pytest.approx((2.5, 0.4, math.pi / 2))      # right of the line
    assert beside[2] == pytest.approx((1.5, 0.4, math.pi / 2))      # left of it
    assert turned[0][2] == pytest.approx(math.pi / 2 - math.radians(10.0))
    assert turned[2][2] == pytest.approx(math.pi / 2 + math.radians(10.0))
    assert turned[1] == beside[1]


def test_default_nodes_spread_along_the_map_and_skip_its_ends():
    assert default_nodes(range(50)) == [10, 20, 29, 39]
    assert default_nodes([3, 5]) == [3, 5]


def test_node_lists_are_checked():
    assert parse_ids("--nodes", "4, 7") == [4, 7]
    for bad in ("a,b", "", "-1"):
        with pytest.raises(BearingBenchError, match="--nodes"):
            parse_ids("--nodes", bad)


@pytest.mark.slow      # the tiny world's mapping run and PyBullet views
def test_a_turn_shows_as_a_shift_towards_the_line(tiny_mapping_run, tmp_path):
    out = tmp_path / "bearing.json"
    proc = run_cli("robot.bench", "bearing", str(tiny_mapping_run / "map"), "--world", str(TINY_WORLD),
                   "--appearances", "1", "--turn", "15", "--json", str(out), "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "columns per 10 deg turned" in proc.stdout
    rows = json.loads(out.read_text())["rows"]
    assert rows
    # turned right (-15 deg) asks to turn left (positive), turned left asks right, on most places
    agree = sum(r["turned"][0] > r["turned"][1] > r["turned"][2] for r in rows)
    assert agree >= len(rows) - 1, rows
