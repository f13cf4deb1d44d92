"""Goal images placed on the map (robot.episode.goal.resolve_goal): by the map's likelihood
(ours), or above t_milestone (the paper's rule, and where the keyframes support no likelihood)."""

from dataclasses import replace

import numpy as np
import pytest

from controllers.localisation import GoalNotLocalisedError
from core.hal import Pose2D
from maps.graph import TopoMap
from robot.episode.goal import resolve_goal
from tests.memory_base import ChainDescriptor, encode_position
from tests.test_episode_loop import CONFIG, N_NODES

TH = CONFIG.thresholds        # t_milestone 0.9, t_change_node 0.8, t_lost 0.3
PAPER = replace(CONFIG, localiser=replace(CONFIG.localiser, goal_by_likelihood=False))
DIM, LENGTH = 96, 30


class VectorDescriptor:
    """The "image" is the descriptor itself (normalised): the tests choose what the camera sees."""

    def describe(self, images):
        rows = np.stack([np.asarray(image, dtype=np.float32).ravel() for image in images])
        return rows / np.linalg.norm(rows, axis=1, keepdims=True)


def _place(x_m: float, basis: np.ndarray) -> np.ndarray:
    """A view at ``x_m`` metres along a corridor: a blend of the random patterns painted one
    metre apart, weighted by distance, so neighbouring places look alike and far ones do not."""
    weights = np.exp(-0.5 * ((np.arange(len(basis)) - x_m) / 0.8) ** 2)
    v = weights @ basis
    return v / np.linalg.norm(v)


def _corridor(twins_of: tuple[int, ...] = ()) -> tuple[TopoMap, np.ndarray]:
    """Nodes 0..29 one metre apart, each keyframe the view at its place; then one node per
    ``twins_of`` entry that looks exactly like that node (a stretch alike far along the route)."""
    basis = np.random.default_rng(3).standard_normal((LENGTH, DIM))
    views = [_place(float(k), basis) for k in range(LENGTH)] + [_place(float(k), basis) for k in twins_of]
    topomap = TopoMap(DIM)
    for k, d in enumerate(views):
        topomap.add_node(d.astype(np.float32), keyframe_index=k, stamp_s=float(k), true_pose=Pose2D(float(k), 0.0, 0.0))
    for k in range(len(views) - 1):
        topomap.add_arc(k, k + 1, 1.0, "sequential")
    return topomap, basis


def _between(basis: np.ndarray, x_m: float, scale: float) -> np.ndarray:
    """The view at ``x_m`` under other light: its pattern scaled down under the same noise, so it
    scores about ``scale`` against its own place."""
    noise = np.random.default_rng(11).standard_normal(DIM)
    noise /= np.linalg.norm(noise)
    return scale * _place(x_m, basis) + np.sqrt(1.0 - scale ** 2) * noise


def test_a_goal_picture_below_t_milestone_is_placed_when_nothing_elsewhere_comes_close():
    topomap, basis = _corridor()
    view = _between(basis, 12.4, 0.6)
    best = topomap.similarities(VectorDescriptor().describe([view])[0])
    assert TH.t_lost < best.max() <= TH.t_milestone and int(np.argmax(best)) == 12
    with pytest.raises(GoalNotLocalisedError, match="t_milestone"):
        resolve_goal(view, topomap, VectorDescriptor(), PAPER)          # the paper's rule refuses it
    goal = resolve_goal(view, topomap, VectorDescriptor(), CONFIG)
    assert goal.node == 12 and goal.descriptor is not None
    assert goal.localisation.confidence >= CONFIG.belief.confidence


def test_a_goal_picture_whose_stretch_of_route_recurs_elsewhere_is_refused():
    topomap, basis = _corridor(twins_of=(11, 12, 13))        # nodes 30-32 look like 11-13
    with pytest.raises(GoalNotLocalisedError, match="posterior mass 0.[3-5]"):
        resolve_goal(_between(basis, 12.0, 0.6), topomap, VectorDescriptor(), CONFIG)


def test_a_confident_goal_picture_below_t_lost_is_refused():
    topomap, basis = _corridor()
    view = _between(basis, 12.0, 0.2)                        # alike nothing: below the floor t_lost
    with pytest.raises(GoalNotLocalisedError, match=r"<= floor 0.300\), posterior mass 0.9\d near it >="):
        resolve_goal(view, topomap, VectorDescriptor(), CONFIG)


def test_keyframes_that_support_no_likelihood_fall_back_to_t_milestone():
    descriptor = ChainDescriptor(N_NODES)                    # one-hot keyframes: no node resembles another
    topomap = TopoMap(N_NODES + 1)
    for k, d in enumerate(descriptor.node_descriptors()):
        topomap.add_node(d, keyframe_index=k, stamp_s=float(k), true_pose=Pose2D(float(k), 0.0, 0.0))
    for k in range(N_NODES - 1):
        topomap.add_arc(k, k + 1, 1.0, "sequential")
    with pytest.raises(GoalNotLocalisedError, match="t_milestone"):
        resolve_goal(encode_position(1.35), topomap, descriptor, CONFIG)
    assert resolve_goal(encode_position(1.0), topomap, descriptor, CONFIG).node == 1
