"""Goal images placed on the map (robot.episode.goal.resolve_goal): above t_milestone, or above
t_change_node when no node far from the best one comes close."""

import pytest

from controllers.localisation import GoalNotLocalisedError
from core.hal import Pose2D
from maps.graph import TopoMap
from robot.episode.goal import resolve_goal
from tests.memory_base import ChainDescriptor, encode_position
from tests.test_episode_loop import CONFIG, N_NODES

TH = CONFIG.thresholds        # t_milestone 0.9, t_change_node 0.8


def _chain(twin_of: int | None = None) -> tuple[TopoMap, ChainDescriptor]:
    """The episode tests' chain 0 -> ... -> 5; with ``twin_of``, a node 6 after node 5 that looks
    exactly like node ``twin_of`` (a look-alike far along the route)."""
    descriptor = ChainDescriptor(N_NODES)
    nodes = list(descriptor.node_descriptors())
    if twin_of is not None:
        nodes.append(nodes[twin_of])
    topomap = TopoMap(N_NODES + 1)
    for k, d in enumerate(nodes):
        topomap.add_node(d, keyframe_index=k, stamp_s=float(k), true_pose=Pose2D(float(k), 0.0, 0.0))
    for k in range(len(nodes) - 1):
        topomap.add_arc(k, k + 1, 1.0, "sequential")
    return topomap, descriptor


def _score(descriptor, x_m: float, node: int) -> float:
    return float(descriptor.describe([encode_position(x_m)])[0] @ descriptor.node_descriptors()[node])


def test_a_goal_picture_between_keyframes_is_placed_when_nothing_far_comes_close():
    topomap, descriptor = _chain()
    between = encode_position(1.35)                   # 0.35 m past node 1: below t_milestone, above t_change_node
    assert TH.t_change_node < _score(descriptor, 1.35, 1) <= TH.t_milestone
    with pytest.raises(GoalNotLocalisedError, match="t_milestone"):
        resolve_goal(between, topomap, descriptor, TH)           # margin 0: the paper's rule
    goal = resolve_goal(between, topomap, descriptor, TH, margin=0.04)
    assert goal.node == 1 and goal.descriptor is not None


def test_a_goal_picture_below_t_milestone_with_a_look_alike_far_away_is_refused():
    topomap, descriptor = _chain(twin_of=1)           # node 6, five arcs from node 1, looks the same
    with pytest.raises(GoalNotLocalisedError, match="t_change_node"):
        resolve_goal(encode_position(1.35), topomap, descriptor, TH, margin=0.04)
    # above t_milestone the best node is the goal as before (the rivals are reported, not refused)
    goal = resolve_goal(encode_position(1.0), topomap, descriptor, TH, margin=0.04)
    assert goal.node in (1, 6) and goal.rivals


def test_a_goal_picture_below_t_change_node_is_refused_whatever_the_margin():
    topomap, descriptor = _chain()
    assert _score(descriptor, 1.5, 1) < TH.t_change_node
    with pytest.raises(GoalNotLocalisedError):
        resolve_goal(encode_position(1.5), topomap, descriptor, TH, margin=0.04)
