"""The belief over the map inside the episode loop (robot.episode.belief, robot.episode.loop): set
up from the map's keyframes, moved by the base's odometry, logged every step."""

import math
from dataclasses import replace
from typing import Sequence

import numpy as np
import pytest

from controllers.config import BearingConfig, NavigationConfig, Thresholds
from core.hal import Odometry, Pose2D
from maps.graph import TopoMap
from robot.episode.belief import OdometryMotion, map_belief
from robot.episode.loop import EpisodeEnd, run_episode
from robot.episode.step_log import step_log_entry
from tests.memory_base import MemoryBase, _decode

N_NODES = 12
WIDTH_M = 0.7          # how far a view's likeness spreads along the chain: neighbours look alike
# the chain's maps have no column profiles: the thirds steer (bearing off)
CONFIG = NavigationConfig(thresholds=Thresholds(t_milestone=0.9, t_change_node=0.8, t_limited_control=0.6,
                                                t_lost=0.3), bearing=BearingConfig(enabled=False))


class SmoothChain:
    """Views of a corridor along +x with nodes a metre apart: a view is a bump over 4 cells per
    metre centred where the robot stands, so nodes a metre apart are about 0.6 alike, far ones 0."""

    def __init__(self, n_nodes: int):
        self.n = n_nodes
        self.centres = np.arange(0.0, n_nodes - 1 + 1e-9, 0.25)

    def view(self, x_m: float) -> np.ndarray:
        v = np.exp(-0.5 * ((self.centres - x_m) / WIDTH_M) ** 2)
        return (v / np.linalg.norm(v)).astype(np.float32)

    def node_descriptors(self) -> np.ndarray:
        return np.stack([self.view(float(k)) for k in range(self.n)])

    def describe(self, images: Sequence[np.ndarray]) -> np.ndarray:
        return np.stack([self.view(_decode(img)) for img in images])

    def describe_thirds(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = []
        for img in images:
            x = _decode(img)
            out.append(np.stack([self.view(x), self.view(x - 0.3), self.view(x + 0.5), self.view(x - 0.3)]))
        return np.stack(out)


def _map(descriptor: SmoothChain, metric: bool) -> TopoMap:
    topomap = TopoMap(len(descriptor.centres))
    for k, d in enumerate(descriptor.node_descriptors()):
        topomap.add_node(d, keyframe_index=10 * k, stamp_s=float(k), true_pose=Pose2D(float(k), 0.0, 0.0))
    for k in range(descriptor.n - 1):
        topomap.add_arc(k, k + 1, 1.0, "sequential", length_m=1.0 if metric else None)
    return topomap


def _drive(topomap: TopoMap, descriptor, goal: int, config: NavigationConfig, max_steps: int,
           start: Pose2D = Pose2D(0.0, 0.0, 0.0)):
    """One episode on a memory base: the outcome and every step's record with the true pose."""
    records = []
    base = MemoryBase(start=start)
    base.connect()
    try:
        outcome = run_episode(base, topomap, descriptor, goal, config, max_steps,
                              observer=lambda r: records.append((r, base.pose)), thirds_contrast=False)
    finally:
        base.close()
    return outcome, records


@pytest.mark.parametrize("metric", [True, False])
def test_the_loop_tracks_the_belief_and_logs_it(metric):
    descriptor = SmoothChain(N_NODES)
    topomap = _map(descriptor, metric)
    outcome, records = _drive(topomap, descriptor, N_NODES - 1, CONFIG, 600)
    assert outcome.end is EpisodeEnd.ARRIVED, outcome.reason
    assert ("cells of 0.25 m" if metric else "node units") in outcome.belief_setup
    assert all(r.belief is not None for r, _ in records)
    # after the first look the mode stays within a node of where the robot really is; on a map in
    # node units, where odometry cannot move it, within two (it follows the views alone)
    errors = [abs(r.belief.mode - pose.x_m) for r, pose in records[5:]]
    assert max(errors) <= (1.0 if metric else 2.0), max(errors)
    assert records[-1][0].belief.confidence > 0.6
    entry = step_log_entry(records[-1][0], records[-1][1], topomap.node_ids)
    assert entry["belief_top"][0][0] == records[-1][0].belief.mode and 0 < entry["belief_confidence"] <= 1
    assert entry["belief_entropy_bits"] >= 0
    assert entry["odometry"] is None                 # it arrived by its views, not driving on blind


@pytest.mark.parametrize("metric", [True, False])
def test_the_belief_places_the_robot_and_it_drives_to_the_goal(metric):
    descriptor = SmoothChain(N_NODES)
    topomap = _map(descriptor, metric)
    config = replace(CONFIG, localiser=replace(CONFIG.localiser, from_belief="initial"))
    outcome, records = _drive(topomap, descriptor, N_NODES - 1, config, 600, start=Pose2D(2.1, 0.0, 0.0))
    assert outcome.end is EpisodeEnd.ARRIVED, outcome.reason
    placed = next(r for r, _ in records if r.step.state.value == "navigating")
    assert placed.step.reason.startswith("belief: node ") and "of the mass" in placed.step.reason


def test_without_a_belief_the_robot_places_itself_by_the_thresholded_match():
    """A map whose keyframes support no likelihood: the loop says so and localises as the paper does."""
    descriptor = SmoothChain(N_NODES)
    topomap = TopoMap(len(descriptor.centres))
    for k in range(N_NODES):                     # every node sees one cell alone: neighbours unrelated
        topomap.add_node(np.eye(len(descriptor.centres), dtype=np.float32)[4 * k], keyframe_index=10 * k,
                         stamp_s=float(k), true_pose=Pose2D(float(k), 0.0, 0.0))
    for k in range(N_NODES - 1):
        topomap.add_arc(k, k + 1, 1.0, "sequential", length_m=1.0)
    config = replace(CONFIG, localiser=replace(CONFIG.localiser, from_belief="initial"))
    outcome, _ = _drive(topomap, descriptor, N_NODES - 1, config, 30)
    assert outcome.belief_setup.startswith("no belief:")
    assert outcome.belief_setup.endswith("the robot places itself by the thresholded match instead "
                                         "(localiser.from_belief off)")


def test_a_map_whose_neighbours_look_unrelated_gets_no_belief():
    topomap = TopoMap(9)
    for k in range(8):
        topomap.add_node(np.eye(9, dtype=np.float32)[k], keyframe_index=k, stamp_s=float(k))
    for k in range(7):
        topomap.add_arc(k, k + 1, 1.0, "sequential")
    belief, why = map_belief(topomap, CONFIG.belief)
    assert belief is None and why.startswith("no belief:")


def test_odometry_motion_is_along_the_heading_and_turning():
    motion = OdometryMotion()
    assert motion.update(None) == (0.0, 0.0)
    assert motion.update(Odometry(0.0, 0.0, 0.0, 0, 0, 0, 0)) == (0.0, 0.0)          # the first reading
    assert motion.update(Odometry(0.3, 0.0, 0.0, 0, 0, 0, 0)) == pytest.approx((0.3, 0.0))
    assert motion.update(Odometry(0.1, 0.0, 0.0, 0, 0, 0, 0)) == pytest.approx((-0.2, 0.0))   # reversing
    assert motion.update(Odometry(0.1, 0.0, math.pi / 2, 0, 0, 0, 0)) == pytest.approx((0.0, math.pi / 2))
    assert motion.update(Odometry(0.1, 0.5, math.pi / 2, 0, 0, 0, 0)) == pytest.approx((0.5, 0.0))
    # across the +-pi seam the turn is the short way round
    motion.update(Odometry(0.1, 0.5, math.pi - 0.05, 0, 0, 0, 0))
    assert motion.update(Odometry(0.1, 0.5, -math.pi + 0.05, 0, 0, 0, 0))[1] == pytest.approx(0.1)


def test_the_step_log_keeps_the_views_beside_it(tmp_path):
    """What the robot saw at each step (the similarity row, the odometry) goes beside the step
    log, so the belief can be run again offline (python -m robot.bench belief)."""
    from robot.episode.step_log import StepLog, ViewsError, read_views, views_path

    descriptor = SmoothChain(N_NODES)
    topomap = _map(descriptor, True)
    _, records = _drive(topomap, descriptor, 4, CONFIG, 80)
    log = StepLog(tmp_path / "ep.steps.jsonl", topomap.node_ids)
    for record, pose in records:
        log.write(record, pose)
    log.close()
    views = read_views(views_path(log.path))
    assert views_path(log.path).name == "ep.views.npz"
    assert views.similarities.shape == (len(records), N_NODES)
    np.testing.assert_allclose(views.similarities[-1], records[-1][0].similarities, atol=1e-3)   # float16
    last = records[-1][0].frame.odometry
    np.testing.assert_allclose(views.odometry[-1], (last.x_m, last.y_m, last.yaw_rad))
    (tmp_path / "bad.views.npz").write_bytes(b"not a zip")
    with pytest.raises(ViewsError, match="bad.views.npz: cannot read the views"):
        read_views(tmp_path / "bad.views.npz")
