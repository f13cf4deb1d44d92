"""Plane geometry of a world: polylines, the footprints of walls and props, clearance."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

from sim.world_spec import PropSpec, Vec2, WallSpec, WorldSpec


def polyline_length_m(points: Sequence[Sequence[float]]) -> float:
    """Sum of the segment lengths of a polyline (metres)."""
    pts = np.asarray(points, dtype=float)
    if len(pts) < 2:
        return 0.0
    return float(np.hypot(*np.diff(pts, axis=0).T).sum())


def sample_polyline(points: Sequence[Sequence[float]], step_m: float = 0.05) -> np.ndarray:
    """Points every ``step_m`` along a polyline, both ends and every corner included: (N, 2)."""
    pts = np.asarray(points, dtype=float)
    out = [pts[:1]]
    for a, b in zip(pts[:-1], pts[1:]):
        n = max(1, int(math.ceil(math.hypot(*(b - a)) / step_m)))
        t = np.arange(1, n + 1)[:, None] / n
        out.append(a + t * (b - a))
    return np.concatenate(out)


@dataclass(frozen=True)
class Footprint:
    """The floor area an obstacle blocks: a rotated rectangle or a circle (metres, radians)."""

    owner: str            # "walls[3]", "props[2] bench_1"
    kind: Literal["rect", "circle"]
    center: Vec2
    half_extents: Vec2 = (0.0, 0.0)
    yaw_rad: float = 0.0
    radius_m: float = 0.0

    def distance_m(self, xy: np.ndarray) -> np.ndarray:
        """Signed distance from points (N, 2) to this footprint (negative inside)."""
        d = np.asarray(xy, dtype=float) - np.asarray(self.center)
        if self.kind == "circle":
            return np.hypot(d[:, 0], d[:, 1]) - self.radius_m
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        local = np.abs(np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1))
        q = local - np.asarray(self.half_extents)
        outside = np.hypot(np.maximum(q[:, 0], 0.0), np.maximum(q[:, 1], 0.0))
        inside = np.minimum(np.maximum(q[:, 0], q[:, 1]), 0.0)
        return outside + inside

    def corners(self) -> np.ndarray:
        """The 4 corners (rect) or 24 points on the circle, counter-clockwise: (K, 2)."""
        if self.kind == "circle":
            a = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
            return np.asarray(self.center) + self.radius_m * np.stack([np.cos(a), np.sin(a)], axis=1)
        hx, hy = self.half_extents
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return local @ np.array([[c, s], [-s, c]]) + np.asarray(self.center)


def wall_footprint(wall: WallSpec, owner: str = "wall") -> Footprint:
    """The wall box seen from above (its ends extend by half the thickness)."""
    (x0, y0), (x1, y1) = wall.start, wall.end
    return Footprint(owner, "rect", ((x0 + x1) / 2, (y0 + y1) / 2),
                     (wall.length_m / 2 + wall.thickness_m / 2, wall.thickness_m / 2),
                     math.atan2(y1 - y0, x1 - x0))


def prop_footprints(prop: PropSpec, owner: str = "prop") -> list[Footprint]:
    """What a prop blocks on the floor: its model footprint or one footprint per part."""
    x, y, yaw_deg = prop.pose
    yaw = math.radians(yaw_deg)
    c, s = math.cos(yaw), math.sin(yaw)
    if prop.model is not None:
        fx, fy = prop.footprint_m or (0.0, 0.0)
        return [Footprint(owner, "rect", (x, y), (fx / 2, fy / 2), yaw)]
    out = []
    for part in prop.parts:
        ox, oy, _ = part.offset_m
        center = (x + c * ox - s * oy, y + s * ox + c * oy)
        if part.shape == "box":
            out.append(Footprint(owner, "rect", center, (part.size_m[0] / 2, part.size_m[1] / 2), yaw))
        else:
            out.append(Footprint(owner, "circle", center, radius_m=part.size_m[0] / 2))
    return out


def footprints(spec: WorldSpec) -> list[Footprint]:
    """Every wall and prop footprint of a world."""
    out = [wall_footprint(w, f"walls[{i}]") for i, w in enumerate(spec.walls)]
    for i, prop in enumerate(spec.props):
        out.extend(prop_footprints(prop, f"props[{i}] {prop.name}"))
    return out


def clearance_m(spec: WorldSpec, points: Sequence[Sequence[float]]) -> tuple[np.ndarray, list[str]]:
    """Distance (m) from each point to the nearest wall or prop surface, and that obstacle's name."""
    xy = np.asarray(points, dtype=float).reshape(-1, 2)
    prints = footprints(spec)
    if not prints:
        return np.full(len(xy), np.inf), ["" for _ in range(len(xy))]
    dist = np.stack([fp.distance_m(xy) for fp in prints], axis=0)
    nearest = np.argmin(dist, axis=0)
    return dist[nearest, np.arange(len(xy))], [prints[k].owner for k in nearest]
