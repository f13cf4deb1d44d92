"""Where a route runs along the walkthrough, in the walkthrough's direction of travel (a map is a
directed graph of what was driven, so a route can only repeat it)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from core.angles import angle_between
from sim.geometry import sample_polyline
from sim.world_spec import Vec2

#: the walkthrough must end this close to its start, so the mapping run can close the loop
WALKTHROUGH_CLOSE_M = 1.0
#: a route point must be this close to the walkthrough to count as "along it"
ALONG_TOLERANCE_M = 0.30
#: start/goal yaw and the walkthrough heading there may differ this much
HEADING_TOLERANCE_DEG = 35.0


def _headings(samples: np.ndarray) -> np.ndarray:
    """Direction of travel at each sample (radians); the last copies the one before."""
    d = np.diff(samples, axis=0)
    h = np.arctan2(d[:, 1], d[:, 0])
    return np.concatenate([h, h[-1:]])


def _cyclic_samples(walkthrough: Sequence[Vec2], step_m: float) -> np.ndarray:
    """Samples of the walkthrough; a closed one continues into a second lap from where it ended.

    The mapping run closes the loop where it ends, so a route may run over the seam (from
    the last metres of the walkthrough into its first ones).
    """
    walk = sample_polyline(walkthrough, step_m)
    gap = float(np.hypot(*(walk[-1] - walk[0])))
    if gap > WALKTHROUGH_CLOSE_M:
        return walk
    head = int(math.ceil((gap + 1.0) / step_m)) + 1
    join = int(np.argmin(np.hypot(*(walk[:head] - walk[-1]).T)))
    return np.concatenate([walk, walk[join + 1:]])


@dataclass(frozen=True)
class AlongWalkthrough:
    """Where a route runs along the walkthrough: arc lengths (m) of its start and goal on the
    (possibly second-lap) walkthrough and the walkthrough's heading (rad) at both."""

    s_start_m: float
    s_goal_m: float
    heading_start_rad: float
    heading_goal_rad: float


def follow_walkthrough(walkthrough: Sequence[Vec2], path: Sequence[Vec2], start_yaw_rad: float,
                       step_m: float = 0.05, tol_m: float = ALONG_TOLERANCE_M) -> Optional[AlongWalkthrough]:
    """Where ``path`` runs along ``walkthrough`` in the walkthrough's direction, or ``None``.

    The first stretch that starts at the path's start with a heading within
    :data:`HEADING_TOLERANCE_DEG` of ``start_yaw_rad`` and then stays within ``tol_m`` of every
    path point in order, moving forward only (at most 1 m + 2 tol per 5 cm step). A closed
    walkthrough is followed over its seam into a second lap.
    """
    walk = _cyclic_samples(walkthrough, step_m)
    heads = _headings(walk)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(walk, axis=0).T))])
    route = sample_polyline(path, step_m)
    d0 = np.hypot(*(walk - route[0]).T)
    tol_h = math.radians(HEADING_TOLERANCE_DEG)
    ok0 = (d0 <= tol_m) & np.array([angle_between(h, start_yaw_rad) <= tol_h for h in heads])
    window = int(math.ceil((1.0 + 2 * tol_m) / step_m))
    tried_until = -1
    for i0 in np.flatnonzero(ok0):
        if i0 <= tried_until:
            continue  # one attempt per pass of the walkthrough through the start
        run_end = i0
        while run_end + 1 < len(walk) and ok0[run_end + 1]:
            run_end += 1
        tried_until = run_end
        start = i0 + int(np.argmin(d0[i0:run_end + 1]))
        j = start
        for point in route[1:]:
            hi = min(len(walk), j + window)
            dist = np.hypot(*(walk[j:hi] - point).T)
            if dist.size == 0 or dist.min() > tol_m:
                break
            j = j + int(np.argmin(dist))
        else:
            return AlongWalkthrough(float(arc[start]), float(arc[j]), float(heads[start]), float(heads[j]))
    return None
