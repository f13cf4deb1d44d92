"""A small deterministic stand-in for descriptors, for testing the navigation logic.

Map nodes are planar poses. The similarity of the robot's view to a node falls off with the
distance to the node and with the heading difference, like a VLAD cosine would: about 0.9 at
the node's own pose, about 0.37 one metre further, 0.2 for unrelated places. A third of the
image (Left / Middle / Right, centred 22 degrees left, straight, 22 degrees right) scores
high when the direction the node's view looks at lies in that third. Seeded Gaussian noise is
added to every score. The robot is a unicycle integrated at a fixed time step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import networkx as nx
import numpy as np

from core.angles import wrap_angle
from core.hal import Pose2D, VelocityCommand

THIRD_OFFSETS_RAD = (0.38, 0.0, -0.38)   # left, middle, right: 65 deg HFOV split in three


@dataclass
class SyntheticPlaces:
    """Similarities of views at given poses to the nodes of a map of poses."""

    node_poses: Dict[int, Pose2D]
    seed: int = 0
    noise_std: float = 0.03
    s_near: float = 0.9
    s_far: float = 0.2
    sigma_d_m: float = 0.6
    sigma_yaw_rad: float = 0.5
    lookahead_m: float = 1.0
    rng: np.random.Generator = field(init=False)

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self.node_ids: Tuple[int, ...] = tuple(sorted(self.node_poses))
        self._xy = np.array([[self.node_poses[n].x_m, self.node_poses[n].y_m] for n in self.node_ids])
        self._yaw = np.array([self.node_poses[n].yaw_rad for n in self.node_ids])

    def clean_similarities(self, pose: Pose2D) -> np.ndarray:
        d2 = np.sum((self._xy - [pose.x_m, pose.y_m]) ** 2, axis=1)
        dyaw = np.arctan2(np.sin(self._yaw - pose.yaw_rad), np.cos(self._yaw - pose.yaw_rad))
        near = np.exp(-d2 / (2 * self.sigma_d_m ** 2)) * np.exp(-dyaw ** 2 / (2 * self.sigma_yaw_rad ** 2))
        return self.s_far + (self.s_near - self.s_far) * near

    def similarities(self, pose: Pose2D) -> np.ndarray:
        clean = self.clean_similarities(pose)
        return np.clip(clean + self.rng.normal(0.0, self.noise_std, clean.shape), -1.0, 1.0)

    def thirds(self, pose: Pose2D, node: int) -> Tuple[float, float, float]:
        target = self.node_poses[node]
        # the node's view looks along its heading: aim at a point ahead of the node
        cx = target.x_m + self.lookahead_m * math.cos(target.yaw_rad)
        cy = target.y_m + self.lookahead_m * math.sin(target.yaw_rad)
        bearing_error = wrap_angle(math.atan2(cy - pose.y_m, cx - pose.x_m) - pose.yaw_rad)
        visible = math.exp(-pose.distance_to(target) ** 2 / (2 * 2.0 ** 2))
        scores = [0.15 + 0.6 * visible * math.exp(-(bearing_error - o) ** 2 / (2 * 0.3 ** 2))
                  for o in THIRD_OFFSETS_RAD]
        noisy = np.asarray(scores) + self.rng.normal(0.0, self.noise_std, 3)
        return tuple(float(v) for v in noisy)


def drive(pose: Pose2D, cmd: VelocityCommand, dt_s: float) -> Pose2D:
    """Unicycle: turn half a step, move, turn half a step."""
    yaw_mid = pose.yaw_rad + 0.5 * cmd.w_radps * dt_s
    return Pose2D(pose.x_m + cmd.v_mps * dt_s * math.cos(yaw_mid),
                  pose.y_m + cmd.v_mps * dt_s * math.sin(yaw_mid),
                  pose.yaw_rad + cmd.w_radps * dt_s)


def square_loop(side_m: int = 4) -> Tuple[nx.DiGraph, Dict[int, Pose2D]]:
    """A directed counter-clockwise loop around a square, as a mapping run would leave it.

    Along each side a node every metre; at each corner one node still facing along the side
    and one turned by 45 degrees (nodes added as the view turns); the last node links back to
    node 0 (loop closure). Arcs carry weight 1.
    """
    poses: List[Pose2D] = []
    corners = [(0.0, 0.0), (side_m, 0.0), (side_m, side_m), (0.0, side_m)]
    for k, (x0, y0) in enumerate(corners):
        yaw = k * math.pi / 2
        dx, dy = math.cos(yaw), math.sin(yaw)
        for step in range(side_m + 1):
            poses.append(Pose2D(round(x0 + step * dx, 9), round(y0 + step * dy, 9), yaw))
        poses.append(Pose2D(round(x0 + side_m * dx, 9), round(y0 + side_m * dy, 9), yaw + math.pi / 4))
    graph = nx.DiGraph()
    graph.add_nodes_from(range(len(poses)))
    for n in range(len(poses)):
        graph.add_edge(n, (n + 1) % len(poses), weight=1.0)
    return graph, dict(enumerate(poses))


def chain(n_nodes: int, spacing_m: float = 1.0) -> Tuple[nx.DiGraph, Dict[int, Pose2D]]:
    """A straight directed chain 0 -> 1 -> ... along +x."""
    graph = nx.DiGraph()
    graph.add_nodes_from(range(n_nodes))
    graph.add_edges_from((n, n + 1, {"weight": 1.0}) for n in range(n_nodes - 1))
    return graph, {n: Pose2D(n * spacing_m, 0.0, 0.0) for n in range(n_nodes)}


def offset(pose: Pose2D, forward_m: float = 0.0, left_m: float = 0.0, yaw_rad: float = 0.0) -> Pose2D:
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    return Pose2D(pose.x_m + forward_m * c - left_m * s, pose.y_m + forward_m * s + left_m * c,
                  pose.yaw_rad + yaw_rad)


def nearest_node(places: SyntheticPlaces, pose: Pose2D) -> Optional[int]:
    return places.node_ids[int(np.argmax(places.clean_similarities(pose)))]
