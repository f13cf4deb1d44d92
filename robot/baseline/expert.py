"""The ground-truth expert that labels LEFT / FORWARD / RIGHT for the learned baseline.

A sample pairs what the robot sees with a *target node* of the map a bit ahead of it along the
walkthrough (between ``target_min_m`` and ``target_max_m`` of arc length, measured with the
nodes' true poses, see :class:`NodeTargets`), as the navigator's next node on a plan would be.
The label is the expert's action towards that node: the heading error between the robot's yaw
and the bearing to the node's position; within ``forward_tolerance_deg`` it is FORWARD,
otherwise LEFT for a target on the left (positive, counter-clockwise error) and RIGHT for one
on the right. Standing (nearly) on the target, the bearing is meaningless, so closer than
``near_m`` the node's own heading (where the mapping camera looked) is used instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controllers.actions import Action
from core.angles import wrap_angle
from core.hal import Pose2D
from core.validate import check_at_least, check_count, check_range
from maps.graph import TopoMap
from robot.baseline.track import TrackError, WalkthroughTrack

#: the classifier's classes, in the order of its outputs
CLASSES = (Action.LEFT, Action.FORWARD, Action.RIGHT)


class ExpertError(ValueError):
    """The expert cannot be set up (a map without true poses, bad settings)."""


@dataclass(frozen=True)
class ExpertConfig:
    """How the expert picks targets and labels actions."""

    target_min_m: float = 0.3             # targets at least this far ahead along the walkthrough (m)
    target_max_m: float = 1.5             # ... and at most this far (m): the next node or the one after
    forward_tolerance_deg: float = 10.0   # |heading error| below this is FORWARD (a 0.2 m offset at 1 m is 11 deg)
    near_m: float = 0.25                  # closer than this to the target, steer to the node's heading
    max_targets: int = 3                  # at most this many targets per frame (nearest ahead first)

    def __post_init__(self) -> None:
        if not 0.0 <= self.target_min_m < self.target_max_m:
            raise ExpertError(f"need 0 <= target_min_m < target_max_m, got {self.target_min_m}, {self.target_max_m}")
        check_range("forward_tolerance_deg", self.forward_tolerance_deg, 0.0, 90.0, low_open=True, high_open=True,
                    what="a number of degrees", error=ExpertError)
        check_at_least("near_m", self.near_m, 0.0, error=ExpertError)
        check_count("max_targets", self.max_targets, 1, error=ExpertError)


def heading_error_rad(pose: Pose2D, target: Pose2D, near_m: float = ExpertConfig.near_m) -> float:
    """Signed angle (rad, counter-clockwise positive) the robot must turn to face ``target``:
    the bearing to the target's position, or the target's own yaw when closer than ``near_m``."""
    dx, dy = target.x_m - pose.x_m, target.y_m - pose.y_m
    if math.hypot(dx, dy) < near_m:
        return wrap_angle(target.yaw_rad - pose.yaw_rad)
    return wrap_angle(math.atan2(dy, dx) - pose.yaw_rad)


def expert_action(pose: Pose2D, target: Pose2D, config: ExpertConfig = ExpertConfig()) -> Action:
    """LEFT / FORWARD / RIGHT towards ``target`` from ``pose`` (see the module docstring)."""
    error = heading_error_rad(pose, target, config.near_m)
    if abs(error) < math.radians(config.forward_tolerance_deg):
        return Action.FORWARD
    return Action.LEFT if error > 0.0 else Action.RIGHT


class NodeTargets:
    """The map's nodes placed on the walkthrough track by their true poses."""

    def __init__(self, topomap: TopoMap, track: WalkthroughTrack, where: str = "the map"):
        nodes = topomap.nodes()
        if not nodes or not topomap.has_true_poses:
            raise ExpertError(f"{where}: the expert needs every node's true pose (a map built in the "
                              "simulator); this map has none")
        self.track = track
        self.node_ids = np.array([n.node_id for n in nodes], dtype=np.int64)
        self.poses = {int(n.node_id): n.true_pose for n in nodes}
        self.arc_m = np.array([track.project(n.true_pose.x_m, n.true_pose.y_m)[0] for n in nodes])

    def ahead(self, pose: Pose2D, config: ExpertConfig = ExpertConfig()) -> list[int]:
        """Node ids between ``target_min_m`` and ``target_max_m`` ahead of ``pose`` along the
        track, nearest first, at most ``max_targets``; when none lies in that band (a sparse
        stretch of the map), the nearest node beyond ``target_min_m`` alone."""
        s, _ = self.track.project(pose.x_m, pose.y_m)
        ahead = np.asarray(self.track.ahead_m(s, self.arc_m))
        order = np.argsort(ahead, kind="stable")
        band = [int(self.node_ids[k]) for k in order if config.target_min_m <= ahead[k] <= config.target_max_m]
        if band:
            return band[: config.max_targets]
        beyond = [k for k in order if ahead[k] >= config.target_min_m]
        return [int(self.node_ids[beyond[0]])] if beyond else []


def node_targets(topomap: TopoMap, walkthrough, where: str = "the map") -> NodeTargets:
    """:class:`NodeTargets` of ``topomap`` on the walkthrough polyline ``walkthrough``."""
    try:
        return NodeTargets(topomap, WalkthroughTrack(walkthrough), where)
    except TrackError as exc:
        raise ExpertError(f"{where}: {exc}") from None
