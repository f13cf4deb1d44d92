"""The belief filter of :mod:`controllers.belief` set up for a map and fed by a base's odometry.

:func:`map_belief` fits the likelihood on the map's own keyframes and takes the arcs' lengths
when every arc has one (a map from a drive), node units otherwise (from a video). On a map in
node units the loop has no scale to turn odometry metres into arcs, so there the belief moves
by its views and its mixing alone (the filter's own node-unit step is for image sequences:
``python -m robot.bench vpr --sequence``).
:class:`ForwardTravel` turns successive odometry poses into the distance driven forward along
the heading (a reverse or a turn in place moves the belief nowhere).
"""

from __future__ import annotations

import math
from typing import Optional

from controllers.belief import LikelihoodError, NodeBelief, SimilarityModel
from controllers.config import BeliefConfig
from core.hal import Odometry
from maps.graph import TopoMap


def map_belief(topomap: TopoMap, config: BeliefConfig) -> tuple[Optional[NodeBelief], str]:
    """The filter over ``topomap``, uniform, and a line saying how it was set up; ``None`` (and
    why) when the map's keyframes do not support a likelihood (too few nodes, no route)."""
    node_ids = [int(n) for n in topomap.node_ids]
    try:
        model = SimilarityModel.from_references(topomap.descriptors, topomap.graph, node_ids)
    except LikelihoodError as exc:
        return None, f"no belief: {exc}"
    arcs = topomap.arcs()
    lengths = {(a.src, a.dst): a.length_m for a in arcs}
    metric = bool(arcs) and all(v is not None and v > 0 for v in lengths.values())
    belief = NodeBelief(topomap.graph, node_ids, model, config=config, arc_lengths_m=lengths if metric else None)
    unit = f"{belief.n_cells} cells of {config.cell_m:g} m" if metric else f"{belief.n_cells} cells in node units"
    return belief, (f"belief over {len(node_ids)} nodes, {unit}; likelihood slope {model.slope:.2f} per contrast "
                    f"unit (same-place mean {model.mean_same:.2f}, far {model.mean_other:.2f}, spread {model.std:.2f})")


class ForwardTravel:
    """Distance driven forward between successive odometry readings (metres, never negative)."""

    def __init__(self) -> None:
        self._last: Optional[Odometry] = None

    def update(self, odometry: Optional[Odometry]) -> float:
        if odometry is None:
            return 0.0
        last, self._last = self._last, odometry
        if last is None:
            return 0.0
        dx, dy = odometry.x_m - last.x_m, odometry.y_m - last.y_m
        yaw = 0.5 * (last.yaw_rad + odometry.yaw_rad) if abs(odometry.yaw_rad - last.yaw_rad) < math.pi else last.yaw_rad
        return max(0.0, dx * math.cos(yaw) + dy * math.sin(yaw))
