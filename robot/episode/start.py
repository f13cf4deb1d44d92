"""Where a simulated episode starts: a route's start, an explicit ``x,y,yaw_deg`` pose, or a map
node's true pose (a *kidnapped* start, far from where the route begins)."""

from __future__ import annotations

import math
from typing import Optional, Union

from core.hal import Pose2D
from maps.store import LoadedMap
from sim.geometry import clearance_m
from sim.world_spec import EvaluationRouteSpec, WorldSpec


class StartError(ValueError):
    """A start that cannot be used (unknown route, malformed pose, node without a true pose)."""


StartSpec = Union[str, Pose2D, int, None]


def parse_start(text: str) -> Union[str, Pose2D, int]:
    """A command-line start: ``x,y,yaw_deg`` (metres, degrees), ``node:ID`` (a map node's true
    pose: a kidnapped start) or a route name (that route's start)."""
    text = str(text).strip()
    if text.startswith("node:"):
        ident = text[5:].strip()
        if not ident.lstrip("-").isdigit():
            raise StartError(f"--start {text!r}: expected node:ID with an integer ID")
        return int(ident)
    if "," in text:
        parts = text.split(",")
        try:
            values = [float(p) for p in parts]
        except ValueError:
            values = []
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise StartError(f"--start {text!r}: expected x,y,yaw_deg (three numbers, metres and degrees)")
        return Pose2D(values[0], values[1], math.radians(values[2]))
    if not text:
        raise StartError("--start is empty: give a route name, x,y,yaw_deg or node:ID")
    return text


def route_of(world: WorldSpec, name: str, what: str) -> EvaluationRouteSpec:
    """The evaluation route ``name`` of ``world``; ``what`` names the option in the error."""
    routes = world.routes.evaluation
    if name not in routes:
        raise StartError(f"{what} {name!r}: world {world.name!r} has no such route "
                         f"(routes: {', '.join(sorted(routes)) or 'none'})")
    return routes[name]


def route_pose(xy_yaw_deg) -> Pose2D:
    """A world-file pose (x_m, y_m, yaw_deg) as a Pose2D (radians)."""
    x, y, yaw_deg = xy_yaw_deg
    return Pose2D(float(x), float(y), math.radians(float(yaw_deg)))


#: a start pose must leave the Limo's body clear of walls and props (its half diagonal is 0.19 m)
START_CLEARANCE_M = 0.2


def check_free(world: WorldSpec, pose: Pose2D) -> None:
    """Raise :class:`StartError` when ``pose`` lies off the world's floor or too close to a wall
    or prop for the robot to stand there."""
    (x0, y0), (sx, sy) = world.floor.origin_m, world.floor.size_m
    where = f"--start {pose.x_m:g},{pose.y_m:g}"
    if not (x0 <= pose.x_m <= x0 + sx and y0 <= pose.y_m <= y0 + sy):
        raise StartError(f"{where}: off the floor of world {world.name!r} (x {x0:g}..{x0 + sx:g} m, "
                         f"y {y0:g}..{y0 + sy:g} m)")
    clearance, owners = clearance_m(world, [(pose.x_m, pose.y_m)])
    if clearance[0] < START_CLEARANCE_M:
        raise StartError(f"{where}: {clearance[0]:.2f} m from {owners[0]}; the robot needs "
                         f"{START_CLEARANCE_M} m of free floor around it")


def resolve_start(world: WorldSpec, loaded_map: LoadedMap, start: StartSpec,
                  route: Optional[str] = None) -> tuple[Pose2D, str]:
    """The start pose and a label for it; ``start`` None means the route's start."""
    if start is None:
        if route is None:
            raise StartError("no start: give --start (route name, x,y,yaw_deg or node:ID) or --route")
        return route_pose(route_of(world, route, "--route").start), f"start of route {route}"
    if isinstance(start, Pose2D):
        check_free(world, start)
        return start, f"pose ({start.x_m:.2f}, {start.y_m:.2f}, {math.degrees(start.yaw_rad):.0f} deg)"
    if isinstance(start, int) and not isinstance(start, bool):
        if start not in loaded_map.topomap:
            raise StartError(f"--start node:{start}: the map {loaded_map.path} has no node {start}")
        pose = loaded_map.topomap.node(start).true_pose
        if pose is None:
            raise StartError(f"--start node:{start}: the map {loaded_map.path} has no true poses "
                             "(not a simulator map); give x,y,yaw_deg instead")
        return pose, f"node {start} (kidnapped)"
    if isinstance(start, str):
        return route_pose(route_of(world, start, "--start").start), f"start of route {start}"
    raise StartError(f"start {start!r}: expected a route name, a Pose2D or a node id")
