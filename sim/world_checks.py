"""What types alone cannot check in a world: wall segments are not degenerate, decals fit their
walls, props have a model or parts, the walkthrough comes back to its start, every evaluation
route's ``length_m`` agrees with its polyline and every route lies along the walkthrough, driven
the same way, with clearance for the Limo."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from core.angles import angle_between
from sim.geometry import clearance_m, polyline_length_m, sample_polyline
from sim.route_along import ALONG_TOLERANCE_M, HEADING_TOLERANCE_DEG, WALKTHROUGH_CLOSE_M, follow_walkthrough
from sim.world_spec import EvaluationRouteSpec, FloorSpec, LightSpec, PropSpec, Vec2, WallSpec, WorldError, WorldSpec

#: an evaluation route's length_m may differ this much (fraction) from its polyline
ROUTE_LENGTH_TOLERANCE = 0.10
#: any route point this close to a wall or prop is an error (the Limo's half diagonal is 0.19 m)
MIN_PATH_CLEARANCE_M = 0.25


def check_world(spec: WorldSpec, source: str = "<world>") -> None:
    """Raise :class:`WorldError` (naming ``source`` and the field) on the first problem."""
    for field_path, problem in _problems(spec):
        raise WorldError(source, field_path, problem)


def _problems(spec: WorldSpec):
    """Yield (field path, problem) pairs, most basic first."""
    if not spec.name.strip():
        yield "name", "must not be empty"
    yield from _floor_problems(spec.floor)
    for i, wall in enumerate(spec.walls):
        yield from _wall_problems(wall, f"walls[{i}]", spec.floor)
    names: set[str] = set()
    for i, prop in enumerate(spec.props):
        if prop.name in names:
            yield f"props[{i}].name", f"{prop.name!r} is used by an earlier prop; names must be unique"
        names.add(prop.name)
        yield from _prop_problems(prop, f"props[{i}]", spec.floor)
    yield from _light_problems(spec.light)
    yield from _route_problems(spec)


def _inside_floor(floor: FloorSpec, xy: Sequence[float], margin: float = 0.5) -> bool:
    (x0, y0), (sx, sy) = floor.origin_m, floor.size_m
    return x0 - margin <= xy[0] <= x0 + sx + margin and y0 - margin <= xy[1] <= y0 + sy + margin


def _floor_problems(floor: FloorSpec):
    if not all(s > 0 for s in floor.size_m):
        yield "floor.size_m", f"both sides must be > 0 m, got {list(floor.size_m)}"
    if floor.ceiling_height_m is not None and floor.ceiling_height_m <= 0.5:
        yield "floor.ceiling_height_m", f"must be > 0.5 m (above the camera), got {floor.ceiling_height_m}"


def _wall_problems(wall: WallSpec, where: str, floor: FloorSpec):
    if wall.length_m < 0.05:
        yield where, f"start {list(wall.start)} and end {list(wall.end)} are less than 5 cm apart"
        return
    if wall.height_m <= 0:
        yield f"{where}.height_m", f"must be > 0 m, got {wall.height_m}"
    if not 0 < wall.thickness_m <= 1.0:
        yield f"{where}.thickness_m", f"must be within (0, 1] m, got {wall.thickness_m}"
    for end in ("start", "end"):
        if not _inside_floor(floor, getattr(wall, end)):
            yield f"{where}.{end}", f"{list(getattr(wall, end))} lies outside the floor"
    half_t = wall.thickness_m / 2
    for j, decal in enumerate(wall.decals):
        at = f"{where}.decals[{j}]"
        w, h = decal.size_m
        if w <= 0 or h <= 0:
            yield f"{at}.size_m", f"both sides must be > 0 m, got {list(decal.size_m)}"
        elif decal.at_m - w / 2 < -half_t - 1e-6 or decal.at_m + w / 2 > wall.length_m + half_t + 1e-6:
            yield f"{at}.at_m", (f"a {w} m wide decal centred at {decal.at_m} m does not fit on a "
                                 f"{wall.length_m:.2f} m wall")
        elif decal.bottom_m < 0 or decal.bottom_m + h > wall.height_m + 1e-6:
            yield f"{at}.bottom_m", (f"a {h} m high decal from {decal.bottom_m} m does not fit on a "
                                     f"{wall.height_m} m high wall")


def _prop_problems(prop: PropSpec, where: str, floor: FloorSpec):
    if not prop.name.strip():
        yield f"{where}.name", "must not be empty"
    if (prop.model is None) == (not prop.parts):
        yield where, "give either model (a pybullet_data path) or parts (primitives), not both or neither"
        return
    if not _inside_floor(floor, prop.pose[:2]):
        yield f"{where}.pose", f"{list(prop.pose[:2])} lies outside the floor"
    if prop.model is not None:
        import pybullet_data  # data files only; no physics import here

        if not (Path(pybullet_data.getDataPath()) / prop.model).is_file():
            yield f"{where}.model", f"{prop.model!r} is not a file in pybullet_data"
        if prop.scale <= 0:
            yield f"{where}.scale", f"must be > 0, got {prop.scale}"
        if prop.footprint_m is None:
            yield f"{where}.footprint_m", "a model prop needs its footprint [x, y] in metres"
        elif not all(v > 0 for v in prop.footprint_m):
            yield f"{where}.footprint_m", f"both sides must be > 0 m, got {list(prop.footprint_m)}"
        return
    for k, part in enumerate(prop.parts):
        at = f"{where}.parts[{k}]"
        sx, sy, sz = part.size_m
        if not (sx > 0 and sy > 0 and sz > 0):
            yield f"{at}.size_m", f"all sizes must be > 0 m, got {list(part.size_m)}"
        elif part.shape == "cylinder" and abs(sx - sy) > 1e-9:
            yield f"{at}.size_m", f"a cylinder needs equal x and y (its diameter), got {list(part.size_m)}"
        elif part.shape == "sphere" and not (abs(sx - sy) < 1e-9 and abs(sx - sz) < 1e-9):
            yield f"{at}.size_m", f"a sphere needs three equal sizes (its diameter), got {list(part.size_m)}"
        if not all(0.0 <= c <= 1.0 for c in part.color):
            yield f"{at}.color", f"each channel must be within 0..1, got {list(part.color)}"
        if part.offset_m[2] < 0:
            yield f"{at}.offset_m", f"z (the part's bottom) must be >= 0, got {part.offset_m[2]}"


def _light_problems(light: LightSpec):
    if float(np.linalg.norm(light.direction)) < 1e-6:
        yield "light.direction", "must not be the zero vector"
    if not all(0.0 <= c <= 1.0 for c in light.color):
        yield "light.color", f"each channel must be within 0..1, got {list(light.color)}"
    for name in ("ambient", "diffuse", "specular"):
        if not 0.0 <= getattr(light, name) <= 1.0:
            yield f"light.{name}", f"must be within 0..1, got {getattr(light, name)}"


def _route_problems(spec: WorldSpec):
    walk = spec.routes.walkthrough
    if len(walk) < 3:
        yield "routes.walkthrough", f"needs at least 3 waypoints, got {len(walk)}"
        return
    gap = math.hypot(walk[-1][0] - walk[0][0], walk[-1][1] - walk[0][1])
    if gap > WALKTHROUGH_CLOSE_M:
        yield "routes.walkthrough", (f"ends {gap:.2f} m from its start {list(walk[0])}; it must come back "
                                     f"within {WALKTHROUGH_CLOSE_M} m so the mapping run can close the loop")
    yield from _clearance_problems(spec, walk, "routes.walkthrough")
    for name, route in spec.routes.evaluation.items():
        where = f"routes.evaluation.{name}"
        poly = polyline_length_m(route.path)
        if poly < 0.5:
            yield where, f"start and goal are only {poly:.2f} m apart"
            continue
        if abs(route.length_m - poly) > ROUTE_LENGTH_TOLERANCE * poly:
            yield f"{where}.length_m", (f"{route.length_m} m disagrees with the waypoint polyline "
                                        f"({poly:.2f} m) by more than {ROUTE_LENGTH_TOLERANCE:.0%}")
        yield from _clearance_problems(spec, route.path, where)
        yield from _direction_problems(route, where)
        yield from _along_problems(walk, route, where)


def _clearance_problems(spec: WorldSpec, path: Sequence[Vec2], where: str):
    samples = sample_polyline(path, 0.05)
    dist, owner = clearance_m(spec, samples)
    k = int(np.argmin(dist))
    if dist[k] < MIN_PATH_CLEARANCE_M:
        x, y = samples[k]
        yield where, (f"passes {dist[k]:.2f} m from {owner[k]} at ({x:.2f}, {y:.2f}); routes need at least "
                      f"{MIN_PATH_CLEARANCE_M} m clearance for the Limo")


def _direction_problems(route: EvaluationRouteSpec, where: str):
    path = route.path
    first = math.atan2(path[1][1] - path[0][1], path[1][0] - path[0][0])
    last = math.atan2(path[-1][1] - path[-2][1], path[-1][0] - path[-2][0])
    tol = math.radians(HEADING_TOLERANCE_DEG)
    if angle_between(math.radians(route.start[2]), first) > tol:
        yield f"{where}.start", (f"yaw {route.start[2]} deg does not face along the first leg "
                                 f"({math.degrees(first):.0f} deg)")
    if angle_between(math.radians(route.goal[2]), last) > tol:
        yield f"{where}.goal", (f"yaw {route.goal[2]} deg does not face along the last leg "
                                f"({math.degrees(last):.0f} deg)")


def _along_problems(walk: Sequence[Vec2], route: EvaluationRouteSpec, where: str):
    found = follow_walkthrough(walk, route.path, math.radians(route.start[2]))
    if found is None:
        yield where, (f"does not lie along the walkthrough in its direction of travel (every point within "
                      f"{ALONG_TOLERANCE_M} m, same heading); the map is a directed graph of what was driven")
        return
    if angle_between(math.radians(route.goal[2]), found.heading_goal_rad) > math.radians(HEADING_TOLERANCE_DEG):
        yield f"{where}.goal", (f"yaw {route.goal[2]} deg differs from the walkthrough heading there "
                                f"({math.degrees(found.heading_goal_rad):.0f} deg)")
