"""The shortest collision-free path length between two points of a world (for SPL).

SPL (Anderson et al. 2018) divides by the *shortest* path from the start to the goal, not by the
length of the route as it was taught. This module computes it on an occupancy grid of the
world: every cell whose centre is closer than ``clearance_m`` to a wall or prop surface
(``sim.geometry.footprints``) is blocked, and Dijkstra runs over the free cells with 16
neighbours (steps of 1 and 2 cells straight, sqrt(2) diagonal and sqrt(5) knight moves), which
stays within about 3 % of the Euclidean length in open space (8 neighbours: up to 8 %).

A *route's* shortest length keeps the path within ``corridor_half_width_m`` of the route's
polyline (start, waypoints, goal): the length the taught route allows, corners cut. A map is
taught along one drive and navigates along it (the office route goes 40 m around the floor to a
goal 11 m north of its start through an aisle the walkthrough drove the other way), so SPL
against the whole floor's shortest path would measure the route choice, not the driving.

The clearance is the Limo's circumscribed radius (0.322 x 0.22 m body: 0.195 m), rounded up:
the centre of a robot that touches nothing stays this far from every surface.
"""

from __future__ import annotations

import heapq
import math
from typing import Sequence

import numpy as np

from sim.geometry import footprints
from sim.world_spec import WorldSpec

#: The Limo's circumscribed radius, rounded up (m).
LIMO_CLEARANCE_M = 0.2
#: Grid resolution (m per cell).
DEFAULT_RESOLUTION_M = 0.05

_STEPS = [(dx, dy) for dx in (-2, -1, 0, 1, 2) for dy in (-2, -1, 0, 1, 2)
          if (dx, dy) != (0, 0) and math.gcd(abs(dx), abs(dy)) == 1]


class NoPathError(ValueError):
    """Start or goal is blocked, or no free path joins them; the message names the points."""


#: How far (m) a route's shortest path may stray from the route's polyline: half a 2.4 m corridor.
ROUTE_CORRIDOR_HALF_WIDTH_M = 1.2


def free_space(spec: WorldSpec, clearance_m: float = LIMO_CLEARANCE_M,
               resolution_m: float = DEFAULT_RESOLUTION_M,
               corridor: Sequence[Sequence[float]] | None = None,
               corridor_half_width_m: float = ROUTE_CORRIDOR_HALF_WIDTH_M) -> tuple[np.ndarray, tuple[float, float]]:
    """Boolean grid (rows = y, columns = x) of cells a robot centre may occupy, and the world
    position of cell (0, 0)'s centre. Cells outside the floor are blocked; with ``corridor`` (a
    polyline of (x, y) points) so are cells farther than ``corridor_half_width_m`` from it."""
    (w, h), (x0, y0) = spec.floor.size_m, spec.floor.origin_m   # origin: the south-west corner
    nx, ny = int(math.ceil(w / resolution_m)), int(math.ceil(h / resolution_m))
    xs = x0 + (np.arange(nx) + 0.5) * resolution_m
    ys = y0 + (np.arange(ny) + 0.5) * resolution_m
    gx, gy = np.meshgrid(xs, ys)
    points = np.stack([gx.ravel(), gy.ravel()], axis=1)
    distance = np.full(len(points), np.inf)
    for fp in footprints(spec):
        distance = np.minimum(distance, fp.distance_m(points))
    free = distance >= clearance_m
    if corridor is not None:
        free &= _distance_to_polyline(points, np.asarray(corridor, dtype=float)) <= corridor_half_width_m
    return free.reshape(ny, nx), (float(xs[0]), float(ys[0]))


def _distance_to_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    if len(line) == 1:
        return np.hypot(*(points - line[0]).T)
    best = np.full(len(points), np.inf)
    for a, b in zip(line[:-1], line[1:]):
        ab = b - a
        t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.hypot(*(points - (a + t[:, None] * ab)).T))
    return best


def _visible(a: np.ndarray, b: np.ndarray, free: np.ndarray, origin, resolution_m: float) -> bool:
    """Whether the straight segment a-b stays on free cells (sampled every quarter cell)."""
    n = max(2, int(math.ceil(float(np.hypot(*(b - a))) / (resolution_m / 4))))
    t = np.linspace(0.0, 1.0, n)[:, None]
    pts = a + t * (b - a)
    cols = np.rint((pts[:, 0] - origin[0]) / resolution_m).astype(int)
    rows = np.rint((pts[:, 1] - origin[1]) / resolution_m).astype(int)
    inside = (rows >= 0) & (rows < free.shape[0]) & (cols >= 0) & (cols < free.shape[1])
    return bool(inside.all() and free[rows, cols].all())


def _pull_string(points: np.ndarray, free: np.ndarray, origin, resolution_m: float) -> np.ndarray:
    """Shorten the grid path: from each kept point go on to the last point of the run of later
    points in straight view (removes the grid's zig-zag and the snapping of start and goal to cell centres). The
    start and goal themselves may lie in the clearance band (they were snapped), so the
    segments touching them are checked from their snapped neighbours."""
    kept = [0]
    i = 0
    last = len(points) - 1
    while i < last:
        a = points[i] if i > 0 else points[1]
        j = i + 1
        while j < last:
            b = points[j + 1] if j + 1 < last else points[last - 1]
            if not _visible(a, b, free, origin, resolution_m):
                break
            j += 1
        kept.append(j)
        i = j
    return points[kept]


def route_shortest_length_m(spec: WorldSpec, route: str, start_xy: Sequence[float] | None = None,
                            **kwargs) -> float:
    """The shortest length (m) of evaluation route ``route`` of ``spec`` from ``start_xy`` (default
    the route's start) to its goal, within the route's corridor (see the module docstring)."""
    r = spec.routes.evaluation[route]
    start = tuple(r.start[:2]) if start_xy is None else tuple(start_xy)
    line = [start, *[tuple(w) for w in r.waypoints], tuple(r.goal[:2])]
    grid = free_space(spec, kwargs.get("clearance_m", LIMO_CLEARANCE_M),
                      kwargs.get("resolution_m", DEFAULT_RESOLUTION_M), corridor=line)
    return shortest_path(spec, start, r.goal[:2], grid=grid, **kwargs)[0]


def shortest_path_length_m(spec: WorldSpec, start_xy: Sequence[float], goal_xy: Sequence[float], **kwargs) -> float:
    """Length (m) of :func:`shortest_path`."""
    return shortest_path(spec, start_xy, goal_xy, **kwargs)[0]


def shortest_path(spec: WorldSpec, start_xy: Sequence[float], goal_xy: Sequence[float], *,
                  clearance_m: float = LIMO_CLEARANCE_M,
                  resolution_m: float = DEFAULT_RESOLUTION_M,
                  grid: tuple[np.ndarray, tuple[float, float]] | None = None) -> tuple[float, np.ndarray]:
    """Length (m) and points ((K, 2) world x, y) of the shortest path from ``start_xy`` to ``goal_xy`` that keeps the robot's
    centre ``clearance_m`` from every surface. ``grid``: a precomputed :func:`free_space` (same
    resolution) to reuse over many queries. Start and goal snap to the nearest free cell within
    ``clearance_m`` (a start pose may graze the clearance band); the snapping distance is added.
    Raises :class:`NoPathError`."""
    free, (cx0, cy0) = grid if grid is not None else free_space(spec, clearance_m, resolution_m)
    ny, nx = free.shape

    def cell(xy, what):
        col = int(round((float(xy[0]) - cx0) / resolution_m))
        row = int(round((float(xy[1]) - cy0) / resolution_m))
        reach = int(math.ceil(clearance_m / resolution_m))
        best = None
        for r in range(max(0, row - reach), min(ny, row + reach + 1)):
            for c in range(max(0, col - reach), min(nx, col + reach + 1)):
                if free[r, c]:
                    d = math.hypot(cx0 + c * resolution_m - xy[0], cy0 + r * resolution_m - xy[1])
                    if best is None or d < best[0]:
                        best = (d, r, c)
        if best is None or best[0] > clearance_m:
            raise NoPathError(f"{what} ({xy[0]:.2f}, {xy[1]:.2f}) is closer than {clearance_m} m to a "
                              "wall or obstacle (or outside the floor)")
        return best

    d_start, r0, c0 = cell(start_xy, "start")
    d_goal, r1, c1 = cell(goal_xy, "goal")
    dist = np.full(free.shape, np.inf)
    dist[r0, c0] = 0.0
    parent = np.full(free.shape, -1, dtype=np.int64)
    queue = [(0.0, r0, c0)]
    steps = [(dy, dx, math.hypot(dx, dy)) for dx, dy in _STEPS]
    while queue:
        d, r, c = heapq.heappop(queue)
        if (r, c) == (r1, c1):
            cells = [r * nx + c]
            while parent.flat[cells[-1]] >= 0:
                cells.append(int(parent.flat[cells[-1]]))
            rows, cols = np.divmod(np.asarray(cells[::-1]), nx)
            points = np.stack([cx0 + cols * resolution_m, cy0 + rows * resolution_m], axis=1)
            points = np.vstack([np.asarray(start_xy, float)[None, :2], points, np.asarray(goal_xy, float)[None, :2]])
            points = _pull_string(points, free, (cx0, cy0), resolution_m)
            return float(np.hypot(*np.diff(points, axis=0).T).sum()), points
        if d > dist[r, c]:
            continue
        for dy, dx, cost in steps:
            rr, cc = r + dy, c + dx
            if not (0 <= rr < ny and 0 <= cc < nx) or not free[rr, cc]:
                continue
            if abs(dx) == 2 or abs(dy) == 2:   # a knight move must not jump a blocked cell
                if not (free[r + (dy // 2 if abs(dy) == 2 else 0), c + (dx // 2 if abs(dx) == 2 else 0)]
                        and free[r + (dy if abs(dy) == 1 else 0), c + (dx if abs(dx) == 1 else 0)]):
                    continue
            nd = d + cost
            if nd < dist[rr, cc]:
                dist[rr, cc] = nd
                parent[rr, cc] = r * nx + c
                heapq.heappush(queue, (nd, rr, cc))
    raise NoPathError(f"no free path from ({start_xy[0]:.2f}, {start_xy[1]:.2f}) to "
                      f"({goal_xy[0]:.2f}, {goal_xy[1]:.2f}) with {clearance_m} m clearance")
