"""World YAML: schema errors name file and field; the shipped worlds' routes are sound."""

import copy
import math

import numpy as np
import pytest
import yaml

from core.angles import angle_between
from core.configfile import ConfigError
from core.hal import Pose2D
from sim.appearance import MAX_PROP_SHIFT_M, apply_appearance
from sim.geometry import clearance_m, polyline_length_m, sample_polyline
from sim.route_along import follow_walkthrough
from sim.teleop import WaypointTeleop
from sim.world_spec import WorldError
from sim.worlds import available_worlds, load_world

# A 6 x 4 m room with a rectangular loop and one route: the smallest valid world.
MINIMAL = {
    "name": "tiny",
    "floor": {"size_m": [6.0, 4.0]},
    "walls": [
        {"start": [0, 0], "end": [6, 0], "decals": [
            {"texture": {"kind": "poster", "seed": 1}, "at_m": 3.0, "side": "left", "size_m": [0.6, 0.9],
             "bottom_m": 0.5}]},
        {"start": [6, 0], "end": [6, 4]},
        {"start": [6, 4], "end": [0, 4]},
        {"start": [0, 4], "end": [0, 0]},
    ],
    "props": [{"name": "box", "pose": [3.0, 2.0, 0.0], "parts": [{"shape": "box", "size_m": [0.6, 0.6, 0.5]}]}],
    "routes": {
        "walkthrough": [[1, 1], [5, 1], [5, 3], [1, 3], [1, 1]],
        "evaluation": {"short": {"start": [1.5, 1.0, 0.0], "goal": [5.0, 2.0, 90.0], "waypoints": [[5.0, 1.0]],
                                 "length_m": 4.5, "difficulty": "easy", "description": "one turn"}},
    },
}

# what the issue asks of each shipped world: route name -> about how long
EXPECTED_ROUTES = {"hospital": {"easy": 10.0, "moderate": 20.0, "hard": 35.0}, "office": {"main": 40.0},
                   "warehouse": {"easy": 10.0, "moderate": 20.0, "hard": 33.0},
                   "garage": {"easy": 10.0, "moderate": 20.0, "hard": 33.0}}
CLEARANCE_M = 0.45


def _write(tmp_path, data, name="world.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def _error(tmp_path, mutate):
    data = copy.deepcopy(MINIMAL)
    mutate(data)
    path = _write(tmp_path, data)
    with pytest.raises(WorldError) as info:
        load_world(path)
    assert str(path) in str(info.value), "the message must name the file"
    return info.value


def test_minimal_world_loads(tmp_path):
    spec = load_world(_write(tmp_path, MINIMAL))
    assert spec.name == "tiny"
    assert spec.walls[0].decals[0].texture.kind == "poster"
    assert spec.routes.evaluation["short"].path == ((1.5, 1.0), (5.0, 1.0), (5.0, 2.0))


def test_wrong_type_names_the_field(tmp_path):
    def mutate(d):
        d["walls"][3]["height_m"] = "high"
    err = _error(tmp_path, mutate)
    assert err.field == "walls[3].height_m"
    assert "walls[3].height_m: expected a number" in str(err)


def test_missing_field_names_the_field(tmp_path):
    err = _error(tmp_path, lambda d: d.pop("routes"))
    assert err.field == "routes" and "required field is missing" in str(err)
    err = _error(tmp_path, lambda d: d["routes"]["evaluation"]["short"].pop("difficulty"))
    assert err.field == "routes.evaluation.short.difficulty"


def test_unknown_field_names_the_field(tmp_path):
    def mutate(d):
        d["walls"][0]["colour"] = [1, 0, 0]
    err = _error(tmp_path, mutate)
    assert err.field == "walls[0].colour" and "unknown field" in str(err)


def test_bad_texture_kind_names_the_field(tmp_path):
    def mutate(d):
        d["walls"][0]["decals"][0]["texture"]["kind"] = "graffiti"
    err = _error(tmp_path, mutate)
    assert err.field == "walls[0].decals[0].texture.kind"


def test_route_length_must_match_its_polyline(tmp_path):
    def mutate(d):
        d["routes"]["evaluation"]["short"]["length_m"] = 6.0
    err = _error(tmp_path, mutate)
    assert err.field == "routes.evaluation.short.length_m"
    assert "4.50 m" in str(err)


def test_walkthrough_must_come_back_to_its_start(tmp_path):
    def mutate(d):
        d["routes"]["walkthrough"] = [[1, 1], [5, 1], [5, 3], [1, 3]]
    err = _error(tmp_path, mutate)
    assert err.field == "routes.walkthrough" and "loop" in str(err)


def test_route_driven_against_the_walkthrough_is_rejected(tmp_path):
    def mutate(d):
        d["routes"]["evaluation"]["short"].update(start=[5.0, 2.0, -90.0], goal=[1.5, 1.0, 180.0])
    err = _error(tmp_path, mutate)
    assert err.field == "routes.evaluation.short" and "direction" in str(err)


def test_route_through_a_prop_is_rejected(tmp_path):
    def mutate(d):
        d["props"][0]["pose"] = [5.0, 2.0, 0.0]
    err = _error(tmp_path, mutate)
    assert err.field == "routes.walkthrough" and "props[0] box" in str(err)


def test_degenerate_wall_and_misfit_decal_are_rejected(tmp_path):
    def degenerate(d):
        d["walls"][1]["end"] = [6, 0.01]
    assert _error(tmp_path, degenerate).field == "walls[1]"

    def misfit(d):
        d["walls"][0]["decals"][0]["at_m"] = 5.9
    assert _error(tmp_path, misfit).field == "walls[0].decals[0].at_m"


def test_prop_needs_exactly_one_of_model_and_parts(tmp_path):
    def both(d):
        d["props"][0]["model"] = "table/table.urdf"
    assert _error(tmp_path, both).field == "props[0]"

    def missing_model(d):
        d["props"][0] = {"name": "t", "pose": [3, 2, 0], "model": "no/such.urdf", "footprint_m": [1, 1]}
    err = _error(tmp_path, missing_model)
    assert err.field == "props[0].model" and "pybullet_data" in str(err)


def test_unknown_world_name_lists_the_available_ones():
    with pytest.raises(WorldError) as info:
        load_world("atlantis")
    assert "atlantis" in str(info.value)
    for name in ("hospital", "office"):
        assert name in str(info.value)
    assert isinstance(info.value, ConfigError)


def test_follow_walkthrough_crosses_the_seam_and_respects_direction():
    loop = [(0, 0), (4, 0), (4, 3), (0, 3), (0, 0.5)]
    # from the last leg over the seam into the first one
    found = follow_walkthrough(loop, [(0, 2), (0, 0), (2, 0)], math.radians(-90))
    assert found is not None and found.s_goal_m > found.s_start_m
    assert abs(found.heading_goal_rad) < 1e-6
    assert follow_walkthrough(loop, [(2, 0), (0, 0)], math.radians(180)) is None


# ---------------------------------------------------------------- the shipped worlds


@pytest.fixture(scope="module", params=sorted(EXPECTED_ROUTES))
def world(request):
    return load_world(request.param)


def test_shipped_worlds_are_listed():
    assert set(EXPECTED_ROUTES) <= set(available_worlds())


def test_routes_have_the_asked_names_and_lengths(world):
    expected = EXPECTED_ROUTES[world.name]
    assert set(expected) <= set(world.routes.evaluation)
    for name, about_m in expected.items():
        route = world.routes.evaluation[name]
        poly = polyline_length_m(route.path)
        assert abs(route.length_m - poly) <= 0.1 * poly
        assert abs(poly - about_m) <= 0.15 * about_m, f"{name}: {poly:.1f} m, asked about {about_m} m"
    if world.name == "hospital":
        grades = {n: world.routes.evaluation[n].difficulty for n in expected}
        assert grades == {"easy": "easy", "moderate": "moderate", "hard": "hard"}


def test_walkthrough_is_a_loop_through_every_route_start_and_goal(world):
    walk = world.routes.walkthrough
    assert math.dist(walk[0], walk[-1]) <= 1.0
    for name, route in world.routes.evaluation.items():
        found = follow_walkthrough(walk, route.path, math.radians(route.start[2]))
        assert found is not None, name
        for yaw_deg, heading in ((route.start[2], found.heading_start_rad), (route.goal[2], found.heading_goal_rad)):
            diff = angle_between(math.radians(yaw_deg), heading)
            assert diff < math.radians(10), f"{name}: pose yaw {yaw_deg} vs walkthrough {math.degrees(heading):.0f}"


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_paths_keep_clear_of_walls_and_props(world, seed):
    shown = apply_appearance(world, seed)
    paths = {"walkthrough": world.routes.walkthrough}
    paths.update({name: r.path for name, r in world.routes.evaluation.items()})
    for name, path in paths.items():
        samples = sample_polyline(path, 0.05)
        dist, owner = clearance_m(shown, samples)
        k = int(np.argmin(dist))
        assert dist[k] >= CLEARANCE_M, f"{name} at {samples[k]} is {dist[k]:.2f} m from {owner[k]} (seed {seed})"


def test_appearance_seed_moves_only_movable_props_and_changes_light(world):
    assert apply_appearance(world, 0) is world
    a, b = apply_appearance(world, 7), apply_appearance(world, 7)
    assert a == b, "the same seed must give the same world"
    assert a.light != world.light
    assert a.walls == world.walls and a.routes == world.routes
    moved = [p.name for p, q in zip(world.props, a.props) if p.pose != q.pose]
    assert moved, "some movable prop must move"
    for p, q in zip(world.props, a.props):
        if not p.movable:
            assert p == q
        else:
            assert math.dist(p.pose[:2], q.pose[:2]) <= MAX_PROP_SHIFT_M + 1e-9
    assert apply_appearance(world, 8).light != a.light
    light = a.light
    assert 0.25 <= light.ambient <= 0.95 and 0.1 <= light.diffuse <= 0.8 and light.direction[2] > 0


def test_teleop_drives_the_walkthrough_clear_of_obstacles(world):
    """A unicycle driven by the project's teleoperator along the walkthrough finishes it and
    keeps the Limo (half diagonal 0.19 m) off every wall and prop, corners and swerves included."""
    walk = world.routes.walkthrough
    teleop = WaypointTeleop(walk)
    yaw = math.atan2(walk[1][1] - walk[0][1], walk[1][0] - walk[0][0])
    pose, dt, trace = Pose2D(walk[0][0], walk[0][1], yaw), 0.1, []
    for _ in range(int(3 * polyline_length_m(walk) / (0.4 * dt))):
        if teleop.done(pose):
            break
        cmd = teleop.command(pose)
        yaw = pose.yaw_rad + cmd.w_radps * dt
        pose = Pose2D(pose.x_m + cmd.v_mps * dt * math.cos(yaw), pose.y_m + cmd.v_mps * dt * math.sin(yaw), yaw)
        trace.append((pose.x_m, pose.y_m))
    assert teleop.done(pose), "the teleoperator did not finish the walkthrough"
    dist, owner = clearance_m(world, trace)
    k = int(np.argmin(dist))
    assert dist[k] >= 0.3, f"the drive passes {dist[k]:.2f} m from {owner[k]} at {trace[k]}"
