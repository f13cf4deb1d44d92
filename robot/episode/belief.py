"""The belief filter of :mod:`controllers.belief` set up for a map and fed by a base's odometry.

:func:`map_belief` fits the likelihood on the map's own keyframes and takes the arcs' lengths
when every arc has one (a map from a drive), node units otherwise (from a video). On a map in
node units the loop has no scale to turn odometry metres into arcs, so there the belief moves
by its views and its mixing alone, a node or two behind the robot where neighbouring keyframes
look alike (the filter's own node-unit step is for image sequences: ``python -m robot.bench vpr
--sequence``).
:class:`OdometryMotion` turns successive odometry poses into the filter's motion: the distance
along the robot's heading (negative when reversing) and the turn; :class:`BeliefTracker` feeds
the filter one control step at a time (odometry, then the view), for the episode loop and for
``python -m robot.bench belief`` alike. With ``heading_bins`` > 1 the
filter needs the mapping drive's node headings; a map without them gets one direction, and the
set-up line says so.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Optional

from controllers.belief import BeliefSnapshot, LikelihoodError, NodeBelief, SimilarityModel
from controllers.config import BeliefConfig
from core.hal import Odometry
from maps.graph import TopoMap


def map_belief(topomap: TopoMap, config: BeliefConfig) -> tuple[Optional[NodeBelief], str]:
    """The filter over ``topomap``, uniform, and a line saying how it was set up; ``None`` (and
    why) when the map's keyframes do not support a likelihood (too few nodes, no route)."""
    node_ids = [int(n) for n in topomap.node_ids]
    try:
        model = SimilarityModel.from_references(topomap.descriptors, topomap.graph, node_ids,
                                                smoothing_hops=config.smoothing_hops)
    except LikelihoodError as exc:
        return None, f"no belief: {exc}"
    lengths = topomap.arc_lengths_m
    metric = lengths is not None
    headings = topomap.odom_headings
    directions = ""
    if config.heading_bins > 1 and headings is None:
        config = replace(config, heading_bins=1)
        directions = " (no directions: the map has no node headings)"
    belief = NodeBelief(topomap.graph, node_ids, model, config=config, arc_lengths_m=lengths,
                        node_headings=headings)
    unit = f"{belief.n_cells} cells of {config.cell_m:g} m" if metric else f"{belief.n_cells} cells in node units"
    if belief.bins > 1:
        unit += f" x {belief.bins} directions"
    return belief, (f"belief over {len(node_ids)} nodes, {unit}{directions}; likelihood slope {model.slope:.2f} per "
                    f"contrast unit (same-place mean {model.mean_same:.2f}, far {model.mean_other:.2f}, spread "
                    f"{model.std:.2f})")


class OdometryMotion:
    """The motion between successive odometry readings: ``(along, turned_rad)``, the distance
    along the mean heading (metres, negative when reversing) and the heading change (radians)."""

    def __init__(self) -> None:
        self._last: Optional[Odometry] = None

    def update(self, odometry: Optional[Odometry]) -> tuple[float, float]:
        if odometry is None:
            return 0.0, 0.0
        last, self._last = self._last, odometry
        if last is None:
            return 0.0, 0.0
        turned = math.remainder(odometry.yaw_rad - last.yaw_rad, 2.0 * math.pi)
        yaw = last.yaw_rad + 0.5 * turned
        dx, dy = odometry.x_m - last.x_m, odometry.y_m - last.y_m
        return dx * math.cos(yaw) + dy * math.sin(yaw), turned


class BeliefTracker:
    """The filter fed step by step: the odometry's motion (its distance only on a metric map,
    which alone has a scale for it; the turn always), then the view's similarity row."""

    def __init__(self, belief: NodeBelief):
        self.belief = belief
        self._motion = OdometryMotion()

    def step(self, odometry: Optional[Odometry], similarities) -> BeliefSnapshot:
        along, turned = self._motion.update(odometry)
        self.belief.move(along if self.belief.metric else 0.0, turned)
        self.belief.observe(similarities)
        return self.belief.snapshot()
