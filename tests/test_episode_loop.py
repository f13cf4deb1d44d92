"""The episode loop (robot.episode.loop.run_episode) on a base in memory: every way out of the loop
leaves the base commanded to zero, and each end is reported as what it is."""

import math
from dataclasses import replace

import numpy as np
import pytest

from controllers.config import BearingConfig, NavigationConfig, Thresholds
from core.hal import HalError, Pose2D
from core.hal_check import check_base
from maps.graph import MapError, TopoMap
from robot.episode.loop import EpisodeEnd, run_episode
from tests.memory_base import ChainDescriptor, MemoryBase, encode_position

N_NODES = 6
# the chain's maps have no column profiles: the thirds steer (bearing off)
CONFIG = NavigationConfig(thresholds=Thresholds(t_milestone=0.9, t_change_node=0.8, t_limited_control=0.6,
                                                t_lost=0.3), bearing=BearingConfig(enabled=False))


@pytest.fixture
def chain():
    descriptor = ChainDescriptor(N_NODES)
    topomap = TopoMap(N_NODES + 1)
    for k, d in enumerate(descriptor.node_descriptors()):
        topomap.add_node(d, keyframe_index=10 * k, stamp_s=float(k), true_pose=Pose2D(float(k), 0.0, 0.0))
    for k in range(N_NODES - 1):
        topomap.add_arc(k, k + 1, 1.0, "sequential")
    return topomap, descriptor


def _run(base, chain, max_steps=400, observer=None):
    """run_episode on a connected base; ``base.left_at`` is the command it left applied, read
    before the base is closed (closing stops it as well)."""
    topomap, descriptor = chain
    base.connect()
    try:
        return run_episode(base, topomap, descriptor, N_NODES - 1, CONFIG, max_steps, observer=observer,
                           thirds_contrast=False)
    finally:
        base.left_at = base.last_command
        base.close()


def test_the_memory_base_conforms_to_the_hal():
    check_base(lambda: MemoryBase())


def test_the_loop_drives_along_the_chain_and_arrives(chain):
    base = MemoryBase()
    outcome = _run(base, chain)
    assert outcome.end is EpisodeEnd.ARRIVED, outcome.reason
    assert outcome.start_node == 0 and outcome.visited_nodes[-1] == N_NODES - 1
    assert outcome.planned_nodes == tuple(range(N_NODES))
    assert N_NODES - 1.5 < base.pose.x_m < N_NODES - 0.2       # the goal-settle ticks carry it a bit past
    assert base.left_at.is_zero and len(outcome.timings) == outcome.steps


def test_a_base_fault_ends_the_episode_and_stops_the_base(chain):
    base = MemoryBase(fault_at=30)
    outcome = _run(base, chain)
    assert outcome.end is EpisodeEnd.BASE_FAULT
    assert "motor driver over temperature" in outcome.reason
    assert outcome.steps == 30                       # the faulty frame is not acted on
    assert any(not c.is_zero for c in base.applied[:-1]) and base.left_at.is_zero


def test_an_observer_aborts_the_episode_and_the_base_stops(chain):
    seen = []

    def observer(record):
        seen.append(record.index)
        return "the robot toppled" if record.index == 20 else None

    base = MemoryBase()
    outcome = _run(base, chain, observer=observer)
    assert outcome.end is EpisodeEnd.ABORTED and outcome.reason == "the robot toppled"
    assert seen == list(range(21)) and outcome.steps == 21
    assert base.left_at.is_zero


def test_the_step_budget_ends_the_episode(chain):
    base = MemoryBase()
    outcome = _run(base, chain, max_steps=12)
    assert outcome.end is EpisodeEnd.STEP_BUDGET and outcome.steps == 12
    assert "12 steps" in outcome.reason and base.left_at.is_zero


@pytest.mark.parametrize("exception", [RuntimeError, KeyboardInterrupt])
def test_an_exception_in_the_loop_stops_the_base_before_it_propagates(chain, exception):
    base = MemoryBase(raise_in_tick_at=25, exception=exception)
    with pytest.raises(exception, match="inside tick"):
        _run(base, chain)
    assert any(not c.is_zero for c in base.applied) and base.left_at.is_zero and not base.connected


def test_a_frame_without_an_image_is_an_error_after_the_base_stopped(chain):
    base = MemoryBase(no_image_at=15)
    with pytest.raises(HalError, match="without a camera image"):
        _run(base, chain)
    assert any(not c.is_zero for c in base.applied) and base.left_at.is_zero


def test_bad_step_budgets_are_refused_before_the_base_moves(chain):
    for bad in (0, -5, 2.5, True):
        base = MemoryBase()
        with pytest.raises(ValueError, match="max_steps"):
            _run(base, chain, max_steps=bad)
        assert not any(not c.is_zero for c in base.applied)


def test_an_image_goal_stops_where_the_view_matches_the_goal_image(chain):
    """The goal picture was taken 0.4 m before the goal node's: the final approach stops at the
    picture's place, where the goal node's score alone carries the robot to the node and past."""
    topomap, descriptor = chain
    goal_x = N_NODES - 1.4
    goal = descriptor.describe([encode_position(goal_x)])[0]
    ends = {}
    for name, goal_descriptor in (("node", None), ("image", goal)):
        base = MemoryBase()
        base.connect()
        scores = []
        try:
            outcome = run_episode(base, topomap, descriptor, N_NODES - 1, CONFIG, 400, thirds_contrast=False,
                                  goal_descriptor=goal_descriptor,
                                  observer=lambda r: scores.append(r.goal_score) and None)
        finally:
            base.close()
        assert outcome.end is EpisodeEnd.ARRIVED, outcome.reason
        ends[name] = base.pose.x_m
        assert (name == "image") == all(s is not None for s in scores)
    assert abs(ends["image"] - goal_x) < 0.35 < abs(ends["node"] - goal_x)


def test_a_goal_descriptor_of_another_length_is_refused(chain):
    topomap, descriptor = chain
    base = MemoryBase()
    base.connect()
    with pytest.raises(ValueError, match="goal_descriptor must have the map's descriptor length"):
        run_episode(base, topomap, descriptor, N_NODES - 1, CONFIG, 10, goal_descriptor=[1.0, 0.0])
    base.close()



class _TurnedChainDescriptor(ChainDescriptor):
    """The chain's descriptors, and column profiles of a panorama seen at the base's heading
    (the picture encodes only the position, so the heading is read from the base: a stand-in
    for a camera that turns with the robot)."""

    def __init__(self, n_nodes: int, base: MemoryBase):
        super().__init__(n_nodes)
        self.base = base
        rng = np.random.default_rng(0)
        self.panorama = rng.normal(size=(60, 8))
        self.panorama /= np.linalg.norm(self.panorama, axis=1, keepdims=True)

    def columns_at(self, yaw_rad: float) -> np.ndarray:
        # 10 columns over 65 deg, centred on the heading; turning left moves the content right
        first = 25 - int(round(math.degrees(yaw_rad) / 6.5))
        return self.panorama[first:first + 10].astype(np.float32)

    def describe_with_columns(self, images):
        return self.describe_thirds(images), np.stack([self.columns_at(self.base.pose.yaw_rad) for _ in images])


def test_with_bearing_the_loop_steers_a_robot_facing_off_the_chain_back_along_it(chain):
    topomap, _ = chain
    base = MemoryBase(start=Pose2D(0.0, 0.0, math.radians(20.0)))
    descriptor = _TurnedChainDescriptor(N_NODES, base)
    columns = np.stack([descriptor.columns_at(0.0)] * N_NODES)        # every node mapped facing +x
    config = replace(CONFIG, bearing=BearingConfig(enabled=True))
    reasons = []
    base.connect()
    try:
        outcome = run_episode(base, topomap, descriptor, N_NODES - 1, config, 400, thirds_contrast=False,
                              node_columns=columns, observer=lambda r: reasons.append(r.step.reason) and None)
    finally:
        base.close()
    assert outcome.end is EpisodeEnd.ARRIVED, outcome.reason
    steered = [r for r in reasons if "of the view's width" in r]
    assert steered and steered[0].endswith("right")        # facing 20 deg left: it bears right
    assert abs(math.degrees(base.pose.yaw_rad)) < 8.0        # the voter alone would keep the 20 deg
    # a map without column profiles is refused before the robot moves, naming the setting
    base = MemoryBase()
    base.connect()
    with pytest.raises(MapError, match="navigation.bearing.enabled: the map has no column profiles"):
        run_episode(base, topomap, descriptor, N_NODES - 1, config, 10)
    assert base.last_command.is_zero
    base.close()
