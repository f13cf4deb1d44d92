"""Node switching with scripted and synthetic similarity sequences."""

import math
from dataclasses import replace

import numpy as np
import pytest

from controllers.config import (
    NavigationConfig,
    SimilarityFilterConfig,
    SupervisorConfig,
    ThresholdFractions,
    Thresholds,
)
from controllers.localisation import InitialLocaliser, LocaliserStatus
from controllers.planner import GlobalPlanner
from controllers.similarity_filter import SimilarityFilter
from controllers.supervisor import NodeSwitchSupervisor, SupervisorState
from tests.synthetic_places import SyntheticPlaces, chain, offset

# The paper's rule alone: on three-node maps "the best node of the map" is always some node,
# so the appearance-adaptive confirmation is tested on its own below.
PAPER = SupervisorConfig(confirm_best_of_map=False, goal_settle_ticks=0)
CONFIG = NavigationConfig(supervisor=PAPER)
TH = CONFIG.thresholds
# a filter that passes every frame through unchanged: the control case for the filter tests
PASS_THROUGH = NavigationConfig(filter=SimilarityFilterConfig(process_std=10.0, measurement_std=1e-6),
                                supervisor=PAPER)


def row(n_nodes, base=0.2, **scores):
    """A similarity row: ``base`` everywhere, ``n3=0.7`` sets node 3."""
    values = np.full(n_nodes, base)
    for key, value in scores.items():
        values[int(key[1:])] = value
    return values


def feed(supervisor, rows):
    return [supervisor.tick(r) for r in rows]


def test_switches_and_confirms_in_the_papers_order():
    sup = NodeSwitchSupervisor([0, 1, 2], range(3), PASS_THROUGH)
    d = sup.tick(row(3, n0=0.85, n1=0.40))
    assert d.state is SupervisorState.LEAVING and d.current_node == 0 and d.target_node == 1
    # the next node passes t_milestone but the view still looks more like node 0: not yet
    d = sup.tick(row(3, n0=0.80, n1=0.70))
    assert d.state is SupervisorState.LEAVING and d.confirmed_node is None
    # node 0 drops below t_change_node: switch to node 1 (approaching it)
    d = sup.tick(row(3, n0=TH.t_change_node - 0.01, n1=0.62))
    assert d.state is SupervisorState.APPROACHING and "left node 0" in d.reason
    assert d.current_node == 0 and d.target_node == 1
    # node 1 exceeds t_milestone: reached, now leaving it towards node 2
    d = sup.tick(row(3, n0=0.45, n1=TH.t_milestone + 0.01))
    assert d.confirmed_node == 1 and d.target_changed
    assert d.state is SupervisorState.LEAVING and d.current_node == 1 and d.target_node == 2
    d = sup.tick(row(3, n1=0.50, n2=0.60))
    assert d.state is SupervisorState.APPROACHING
    d = sup.tick(row(3, n1=0.45, n2=0.75))
    assert d.state is SupervisorState.GOAL_REACHED and d.confirmed_node == 2
    assert d.target_node is None and d.path_index == 2
    # final: the goal stays reached whatever follows
    assert sup.tick(row(3, n2=0.1)).state is SupervisorState.GOAL_REACHED


def test_driving_along_a_chain_confirms_every_node_near_it():
    graph, poses = chain(6)
    places = SyntheticPlaces(poses, seed=11, noise_std=0.03)
    sup = NodeSwitchSupervisor(range(6), places.node_ids, CONFIG)
    confirmed = []
    for k in range(400):
        pose = offset(poses[0], forward_m=0.02 * k)
        d = sup.tick(places.similarities(pose))
        if d.confirmed_node is not None:
            confirmed.append(d.confirmed_node)
            assert pose.distance_to(poses[d.confirmed_node]) < 0.5
        if d.state is SupervisorState.GOAL_REACHED:
            break
    assert confirmed == [1, 2, 3, 4, 5]
    assert d.state is SupervisorState.GOAL_REACHED


def test_window_ignores_look_alikes_outside_it():
    path = list(range(10))
    config = NavigationConfig(supervisor=SupervisorConfig(window_behind=1, window_ahead=3))
    sup = NodeSwitchSupervisor(path, range(12), config)     # nodes 10, 11 are off the path
    # node 6 (on the path, beyond the window) and node 11 (off the path) look like the view
    for _ in range(30):
        d = sup.tick(row(12, n0=0.5, n1=0.5, n6=0.95, n11=0.97))
    assert d.path_index == 0 and d.confirmed_node is None
    assert d.window_nodes == (0, 1, 2, 3)
    assert 6 not in d.window_nodes and 11 not in d.window_nodes
    # the same look-alike inside the window is taken: node 3 was passed unnoticed
    d = feed(sup, [row(12, n0=0.5, n1=0.5, n3=0.95)] * 10)
    reached = [x for x in d if x.confirmed_node is not None]
    assert reached[0].confirmed_node == 3 and "skipped 1, 2" in reached[0].reason
    assert reached[0].window_nodes == (2, 3, 4, 5, 6)


def test_single_frame_spike_does_not_confirm_a_node():
    def run(config):
        sup = NodeSwitchSupervisor([0, 1, 2], range(3), config)
        feed(sup, [row(3, n0=0.5, n1=0.5)] * 20)              # left node 0, approaching 1
        assert sup.state is SupervisorState.APPROACHING
        spike = sup.tick(row(3, n0=0.5, n1=0.97))
        after = feed(sup, [row(3, n0=0.5, n1=0.5)] * 5)
        return spike, after
    spike, after = run(CONFIG)
    assert spike.confirmed_node is None and spike.path_index == 0
    assert all(d.path_index == 0 for d in after)
    assert spike.target_score < TH.t_milestone
    # the control: without filtering the same spike would have confirmed node 1
    spike_raw, _ = run(PASS_THROUGH)
    assert spike_raw.confirmed_node == 1


def test_single_frame_dip_does_not_switch_away_from_the_current_node():
    def run(config):
        sup = NodeSwitchSupervisor([0, 1, 2], range(3), config)
        feed(sup, [row(3, n0=0.85, n1=0.4)] * 20)
        return sup.tick(row(3, n0=0.15, n1=0.4))
    dip = run(CONFIG)
    assert dip.state is SupervisorState.LEAVING and dip.current_score > TH.t_change_node
    assert run(PASS_THROUGH).state is SupervisorState.APPROACHING


def test_standing_still_at_the_goal_detects_arrival_despite_noise():
    # ViNT's failure: standing at the goal, the closest node flickers and arrival never fires.
    rng = np.random.default_rng(5)
    n = 4
    sup = NodeSwitchSupervisor([0, 1, 2, 3], range(n), CONFIG)
    feed(sup, [row(n, n0=0.85, n1=0.35)] * 3)
    feed(sup, [row(n, n0=0.40, n1=0.80)] * 5)                 # reached node 2's predecessor
    assert sup.index == 1
    feed(sup, [row(n, n1=0.45, n2=0.85)] * 6)
    assert sup.index == 2
    # now standing at node 3 (the goal): its noisy score straddles t_milestone, node 2
    # (the look-alike neighbour) is close behind
    goal = np.clip(0.72 + rng.normal(0, 0.08, 60), -1, 1)
    neighbour = np.clip(0.64 + rng.normal(0, 0.08, 60), -1, 1)
    raw_best = [3 if g > m else 2 for g, m in zip(goal, neighbour)]
    assert sum(a != b for a, b in zip(raw_best, raw_best[1:])) >= 10   # the raw arg-max flickers
    assert (goal <= TH.t_milestone).sum() >= 10                        # and often misses
    states = [sup.tick(row(n, n2=m, n3=g)).state for g, m in zip(goal, neighbour)]
    first = states.index(SupervisorState.GOAL_REACHED)
    assert first < 30
    assert all(s is SupervisorState.GOAL_REACHED for s in states[first:])


def test_lost_then_relocalised_and_replanned():
    n = 8
    planner = GlobalPlanner.from_arcs(range(n), [(k, k + 1, 1.0) for k in range(n - 1)])
    config = NavigationConfig(supervisor=SupervisorConfig(lost_patience_ticks=10, goal_settle_ticks=0))
    shared = SimilarityFilter(n, config.filter)
    sup = NodeSwitchSupervisor(planner.plan(0, 7).nodes, range(n), config, shared)
    feed(sup, [row(n, n0=0.85, n1=0.4)] * 5)
    # kidnapped: the view matches node 5, far outside the window around node 0
    kidnapped = row(n, base=0.25, n5=0.85)
    decisions = feed(sup, [kidnapped] * 40)
    lost_at = next(i for i, d in enumerate(decisions) if d.state is SupervisorState.LOST)
    # the filter needs a few ticks to fall below t_lost, then the patience runs
    assert config.supervisor.lost_patience_ticks <= lost_at < config.supervisor.lost_patience_ticks + 15
    assert all(d.state is not SupervisorState.LOST for d in decisions[:lost_at])
    assert decisions[lost_at].relocalise and "lost" in decisions[lost_at].reason
    assert decisions[-1].state is SupervisorState.LOST                 # final until replaced
    # global re-localisation finds node 5, re-plan from it, and carry on with the same filter
    loc = InitialLocaliser(range(n), TH.t_milestone, config.localiser)
    step = next(s for s in (loc.tick(kidnapped) for _ in range(10)) if loc.done)
    assert step.status is LocaliserStatus.LOCALISED and step.node == 5
    sup = NodeSwitchSupervisor(planner.plan(step.node, 7).nodes, range(n), config, shared)
    assert sup.path == (5, 6, 7)
    d = feed(sup, [row(n, n5=0.5, n6=0.8)] * 10 + [row(n, n6=0.5, n7=0.8)] * 10)
    assert [x.confirmed_node for x in d if x.confirmed_node is not None] == [6, 7]
    assert d[-1].state is SupervisorState.GOAL_REACHED


def test_not_lost_between_nodes_while_something_nearby_is_in_view():
    config = NavigationConfig(supervisor=SupervisorConfig(lost_patience_ticks=5, confirm_best_of_map=False))
    sup = NodeSwitchSupervisor([0, 1, 2], range(3), config)
    between = row(3, n0=TH.t_lost + 0.05, n1=TH.t_lost + 0.1)    # under both t_change and t_milestone
    decisions = feed(sup, [between] * 100)
    assert all(d.state is SupervisorState.APPROACHING for d in decisions)


def test_lost_when_no_node_is_confirmed_for_too_long():
    config = NavigationConfig(supervisor=SupervisorConfig(progress_patience_ticks=50, confirm_best_of_map=False))
    sup = NodeSwitchSupervisor([0, 1, 2], range(3), config)
    decisions = feed(sup, [row(3, n0=0.5, n1=0.55)] * 60)
    states = [d.state for d in decisions]
    assert states.index(SupervisorState.LOST) == 49
    assert "no node confirmed for 50 ticks" in decisions[49].reason


def test_one_node_path_is_the_goal_and_bad_paths_are_rejected():
    sup = NodeSwitchSupervisor([4], range(6), CONFIG)
    assert sup.tick(row(6, n4=0.8)).state is SupervisorState.GOAL_REACHED
    with pytest.raises(ValueError, match="node 9"):
        NodeSwitchSupervisor([1, 9], range(6), CONFIG)
    with pytest.raises(ValueError, match="at least one node"):
        NodeSwitchSupervisor([], range(6), CONFIG)
    with pytest.raises(ValueError, match="one score per map node"):
        NodeSwitchSupervisor([0, 1], range(6), CONFIG).tick(np.zeros(5))


def test_thresholds_from_the_map_drive_the_same_logic():
    th = Thresholds.from_map(0.30, 0.70, ThresholdFractions(milestone=0.6, change_node=0.45, lost=0.15))
    config = NavigationConfig(thresholds=th)
    sup = NodeSwitchSupervisor([0, 1], range(2), config)
    # 0.58 would never confirm under the default t_milestone (0.66); here it is above 0.54
    assert th.t_milestone == pytest.approx(0.54)
    d = feed(sup, [row(2, n0=0.4, n1=0.58)] * 15)
    assert d[-1].state is SupervisorState.GOAL_REACHED
    assert d[-1].current_node == 1 and math.isclose(d[-1].current_score, 0.58, abs_tol=1e-9)


def test_best_of_the_map_confirms_a_node_that_never_passes_t_milestone():
    """Under other lighting every cosine drops: the robot at node 1 scores it only 0.5, below
    t_milestone, yet node 1 is clearly the best of a 10-node map once node 0 is left."""
    assert TH.t_lost < 0.55 < TH.t_milestone and 0.45 < TH.t_change_node
    def drive(config):
        sup = NodeSwitchSupervisor([0, 1, 2], range(10), config)
        d = feed(sup, [row(10, n0=0.80, n1=0.30, n5=0.35)] * 20)[-1]        # at node 0
        assert d.state is SupervisorState.LEAVING
        return sup, feed(sup, [row(10, n0=0.45, n1=0.55, n5=0.35)] * 30)    # at node 1
    _, decisions = drive(NavigationConfig())
    confirmed = [d for d in decisions if d.confirmed_node is not None]
    assert [d.confirmed_node for d in confirmed] == [1] and "best of the map" in confirmed[0].reason
    # the paper's rule alone never confirms it
    _, decisions = drive(CONFIG)
    assert all(d.confirmed_node is None for d in decisions)


def test_best_of_the_map_needs_the_current_node_left_and_a_score_above_t_lost():
    sup = NodeSwitchSupervisor([0, 1, 2], range(10), NavigationConfig())
    # node 1 beats node 0 but node 0 is still above t_change_node: still LEAVING, no confirmation
    still = feed(sup, [row(10, n0=TH.t_change_node + 0.02, n1=TH.t_change_node + 0.03)] * 30)
    assert all(d.confirmed_node is None for d in still)
    # everything low (a view of nothing): node 1 is the best of the map but below t_lost
    sup = NodeSwitchSupervisor([0, 1, 2], range(10), NavigationConfig())
    low = feed(sup, [row(10, base=0.05, n0=TH.t_lost - 0.1, n1=TH.t_lost - 0.05)] * 30)
    assert all(d.confirmed_node is None for d in low)


def test_goal_is_declared_once_its_score_stops_improving_not_at_the_first_pass():
    """A view before the goal node already passes t_milestone: the robot drives on while the
    goal's score rises and arrives when it settles (or falls past the peak)."""
    config = NavigationConfig(filter=PASS_THROUGH.filter, supervisor=SupervisorConfig(goal_settle_ticks=5))
    sup = NodeSwitchSupervisor([0, 1], range(4), config)
    feed(sup, [row(4, n0=0.85, n1=0.3)] * 3 + [row(4, n0=0.5, n1=0.5)] * 3)      # left node 0
    rising = [row(4, n0=0.4, n1=TH.t_milestone + 0.02 * k) for k in range(1, 8)]
    decisions = feed(sup, rising)
    assert all(d.state is not SupervisorState.GOAL_REACHED for d in decisions)
    assert decisions[-1].target_node == 1 and "goal in sight" in decisions[-1].reason
    flat = feed(sup, [rising[-1]] * 5)
    assert [d.state for d in flat].count(SupervisorState.GOAL_REACHED) == 1
    assert flat[-1].state is SupervisorState.GOAL_REACHED and "settled" in flat[-1].reason
    # passing the node: a clear fall below the peak arrives at once
    sup = NodeSwitchSupervisor([0, 1], range(4), config)
    feed(sup, [row(4, n0=0.85, n1=0.3)] * 3 + [row(4, n0=0.5, n1=0.5)] * 3 + rising)
    d = sup.tick(row(4, n0=0.4, n1=TH.t_milestone + 0.02))
    assert d.state is SupervisorState.GOAL_REACHED


# -- the final approach to a goal image ---------------------------------------------------

IMAGE = NavigationConfig(filter=PASS_THROUGH.filter,
                         supervisor=SupervisorConfig(goal_settle_ticks=5, confirm_best_of_map=False))


def _at_the_node_before_the_goal(config=IMAGE):
    """A supervisor on the path 0 -> 1 -> 2 that has confirmed node 1 and left it: node 2 (the
    goal node) is the target."""
    sup = NodeSwitchSupervisor([0, 1, 2], range(5), config)
    feed(sup, [row(5, n0=0.85, n1=0.3)] * 3 + [row(5, n0=0.5, n1=0.5)] * 2)
    d = sup.tick(row(5, n0=0.4, n1=TH.t_milestone + 0.05))
    assert d.confirmed_node == 1 and d.target_node == 2
    d = feed(sup, [row(5, n1=TH.t_change_node - 0.05, n2=0.45)] * 2)[-1]
    assert d.state is SupervisorState.APPROACHING and d.target_node == 2
    return sup


def test_a_goal_image_peak_before_the_goal_node_is_confirmed_does_not_arrive():
    """Before the goal node is confirmed, a passing high of the goal image (a corridor a metre
    short of the goal, identical doors) neither arrives nor counts as the peak afterwards."""
    sup = _at_the_node_before_the_goal()
    node_two = TH.t_lost + 0.05                       # the view resembles the goal node, not enough to confirm it
    early = [sup.tick(row(5, n1=0.4, n2=node_two), goal_score=s) for s in (0.6, 0.75, 0.9, 0.75, 0.6, 0.5, 0.5)]
    assert all(d.state is not SupervisorState.GOAL_REACHED for d in early)
    d = sup.tick(row(5, n1=0.4, n2=TH.t_milestone + 0.05), goal_score=0.6)    # the goal node confirmed
    assert d.state is not SupervisorState.GOAL_REACHED and "goal in sight" in d.reason
    rising = [sup.tick(row(5, n1=0.4, n2=TH.t_milestone + 0.05), goal_score=0.6 + 0.05 * k) for k in range(1, 4)]
    assert all(d.state is not SupervisorState.GOAL_REACHED for d in rising)
    falling = [sup.tick(row(5, n1=0.4, n2=TH.t_milestone + 0.05), goal_score=0.4) for _ in range(4)]
    arrived = next(d for d in falling if d.state is SupervisorState.GOAL_REACHED)
    assert "the goal image" in arrived.reason
    peak = float(arrived.reason.split("the goal image")[1].split("peak ")[1].split(" ")[0])
    assert peak == pytest.approx(0.75), "the peak counts from the confirmation on, not the early 0.9"


def test_past_the_goal_nodes_picture_the_robot_drives_on_while_the_goal_image_improves():
    """The goal node is confirmed and its score stops improving, but the goal image still
    scores higher each tick: the goal lies ahead of the node's picture."""
    sup = _at_the_node_before_the_goal()
    d = sup.tick(row(5, n1=0.4, n2=TH.t_milestone + 0.05), goal_score=TH.t_milestone + 0.02)
    assert d.state is not SupervisorState.GOAL_REACHED and "goal in sight" in d.reason
    flat_node = [sup.tick(row(5, n1=0.4, n2=TH.t_milestone + 0.05), goal_score=TH.t_milestone + 0.02 + 0.02 * k)
                 for k in range(1, 10)]
    assert all(d.state is not SupervisorState.GOAL_REACHED for d in flat_node)   # the node rule alone: 5 ticks
    d = sup.tick(row(5, n1=0.4, n2=TH.t_milestone + 0.05), goal_score=TH.t_milestone + 0.16)
    assert d.state is SupervisorState.GOAL_REACHED and "the goal image" in d.reason


def test_a_goal_image_that_stops_improving_short_of_the_goal_node_waits_for_the_node():
    """Confirmed as the best of the map a metre short (below t_milestone), the goal node's score
    still rises while the goal image's falls for a few ticks (the robot weaves): no arrival until
    the node settles too, and then at once (the image said so already)."""
    sup = NodeSwitchSupervisor([0, 1, 2], range(5), replace(IMAGE, supervisor=replace(IMAGE.supervisor,
                                                                                     confirm_best_of_map=True)))
    feed(sup, [row(5, base=0.0, n0=0.85)] * 3 + [row(5, base=0.0, n0=0.3, n1=0.2)] * 2)   # left node 0
    assert sup.tick(row(5, base=0.0, n1=TH.t_milestone + 0.05)).confirmed_node == 1
    feed(sup, [row(5, base=0.0, n1=TH.t_change_node - 0.05, n2=0.1)] * 2)                # left node 1
    weak = TH.t_lost + 0.02                            # the best of the map, below t_milestone
    rising_node = [row(5, base=0.0, n1=0.0, n2=weak + 0.005 * k) for k in range(1, 9)]
    images = [0.8, 0.8] + [0.7] * 6                     # past t_milestone, then a clear fall
    ds = [sup.tick(r, goal_score=g) for r, g in zip(rising_node, images)]
    assert all(d.state is not SupervisorState.GOAL_REACHED for d in ds)
    assert "the goal image settled" in ds[-1].reason
    flat = [sup.tick(rising_node[-1], goal_score=0.7) for _ in range(5)]
    states = [d.state for d in flat]
    assert states.count(SupervisorState.GOAL_REACHED) == 1 and states[-1] is SupervisorState.GOAL_REACHED
    assert "settled at filtered" in flat[-1].reason and "the goal image" in flat[-1].reason


def test_a_goal_image_that_never_matches_well_leaves_arrival_to_the_goal_node():
    """Under other light than the goal picture's, its score may never pass t_milestone: the goal
    node's own score settles arrival as without a goal image."""
    sup = _at_the_node_before_the_goal()
    low = TH.t_milestone - 0.1
    ds = [sup.tick(row(5, n1=0.4, n2=TH.t_milestone + 0.05), goal_score=low) for _ in range(8)]
    states = [d.state for d in ds]
    assert SupervisorState.GOAL_REACHED in states
    assert "settled" in ds[states.index(SupervisorState.GOAL_REACHED)].reason


def test_the_belief_confirms_a_goal_node_whose_view_never_passes():
    """Under the day's light the goal node's view scores below every confirmation rule; the
    belief, holding its mass there, confirms it, and the settle decides arrival as after any
    confirmation (before: the robot drove past the goal and was lost a node later)."""
    weak = row(5, n1=0.4, n2=TH.t_lost + 0.02, n4=TH.t_lost + 0.1)   # another place scores higher
    sup = _at_the_node_before_the_goal()
    assert all(sup.tick(weak, goal_mass=0.59).confirmed_node is None for _ in range(3))
    d = sup.tick(weak, goal_mass=CONFIG.belief.confidence)
    assert d.state is not SupervisorState.GOAL_REACHED
    assert "goal in sight: reached node 2: the belief holds 0.60 of its mass there" in d.reason
    ds = [sup.tick(weak, goal_mass=0.9) for _ in range(IMAGE.supervisor.goal_settle_ticks)]
    assert ds[-1].state is SupervisorState.GOAL_REACHED and "settled" in ds[-1].reason
    off = _at_the_node_before_the_goal(replace(IMAGE, supervisor=replace(IMAGE.supervisor, goal_by_belief=False)))
    assert all(off.tick(weak, goal_mass=1.0).state is SupervisorState.APPROACHING for _ in range(10))


def test_on_a_long_goal_arc_the_belief_confirms_the_goal_only_near_its_end_by_odometry():
    """A node's mass gathers the cells up to half an arc before it: on a 3 m goal arc the belief
    held 0.6 at the goal 0.2 m past its predecessor and the robot stopped 2.5 m short. With
    ``goal_odometry_short_m`` the odometry must first have driven the arc less that much since
    the predecessor's confirmation; without the distance, or with None, the belief alone decides."""
    arcs = {(0, 1): 1.0, (1, 2): 3.0}
    config = replace(IMAGE, supervisor=replace(IMAGE.supervisor, goal_odometry_short_m=0.5))
    weak = row(5, n1=0.4, n2=TH.t_lost - 0.1, n4=TH.t_lost + 0.1)   # another place scores higher

    def approach(config, arcs=arcs, travelled=True):
        sup = NodeSwitchSupervisor([0, 1, 2], range(5), config, arc_lengths_m=arcs)
        feed(sup, [row(5, n0=0.85, n1=0.3)] * 3 + [row(5, n0=0.5, n1=0.5)] * 2)
        assert sup.tick(row(5, n0=0.4, n1=TH.t_milestone + 0.05), travelled_m=10.0).confirmed_node == 1
        for _ in range(2):
            sup.tick(row(5, n1=TH.t_change_node - 0.05, n2=0.3), travelled_m=10.1)
        # 0.1 m per tick from 0.25 m past node 1; the belief holds 0.9 at the goal throughout
        return [sup.tick(weak, goal_mass=0.9, travelled_m=10.25 + 0.1 * k if travelled else None)
                for k in range(30)]

    ds = approach(config)
    first = next(k for k, d in enumerate(ds) if "goal in sight" in d.reason)
    assert first == 23                                  # 2.55 m driven of the 3 m arc
    assert "the belief holds 0.90 of its mass there" in ds[first].reason
    assert "goal in sight" in approach(IMAGE)[0].reason  # the setting off: at once, as before
    assert "goal in sight" in approach(config, travelled=False)[0].reason
    assert "goal in sight" in approach(config, arcs=None)[0].reason
    with pytest.raises(ValueError, match="goal_odometry_short_m"):
        replace(IMAGE.supervisor, goal_odometry_short_m=-1.0)


def test_on_a_long_goal_arc_a_goal_confirmed_as_the_best_of_the_map_waits_for_the_odometry():
    """On a 3 m goal arc the goal node's score is the best of the map 1.4 m short and then stays
    flat: the settle stopped there. With ``goal_odometry_short_m`` it waits until the odometry
    has driven the arc less that much since the goal's predecessor; a goal image past
    ``t_milestone`` still decides alone."""
    arcs = {(0, 1): 1.0, (1, 2): 3.0}

    def approach(short, goal_score=None):
        config = replace(IMAGE, supervisor=replace(IMAGE.supervisor, confirm_best_of_map=True,
                                                    goal_odometry_short_m=short))
        sup = NodeSwitchSupervisor([0, 1, 2], range(5), config, arc_lengths_m=arcs)
        feed(sup, [row(5, n0=0.85, n1=0.3)] * 3 + [row(5, n0=0.5, n1=0.5)] * 2)
        sup.tick(row(5, n0=0.4, n1=TH.t_milestone + 0.05), travelled_m=0.0)   # at node 1 from 0 m
        for _ in range(2):
            sup.tick(row(5, n1=TH.t_change_node - 0.05, n2=0.3), travelled_m=0.1)
        assert sup.target_node == 2
        weak = row(5, n1=0.3, n2=TH.t_lost + 0.05)      # the best of the map, below t_milestone
        d = sup.tick(weak, travelled_m=1.6, goal_score=goal_score)
        assert "goal in sight" in d.reason
        states = [sup.tick(weak, travelled_m=1.65 + 0.05 * k, goal_score=goal_score).state for k in range(40)]
        return states.index(SupervisorState.GOAL_REACHED) if SupervisorState.GOAL_REACHED in states else None

    settle = IMAGE.supervisor.goal_settle_ticks
    assert approach(None) == settle - 1                # settles 1.4 m short, as before
    assert approach(0.5) == 17                         # 1.65 + 0.85 = 2.5 m driven of the 3 m arc
    assert approach(2.0) == settle - 1                 # 1.0 m of the arc suffices: no wait
    assert approach(0.5, goal_score=TH.t_milestone + 0.1) <= settle   # the goal image decides


def test_the_belief_confirms_the_goal_only_once_the_node_before_it_is_left():
    sup = NodeSwitchSupervisor([0, 1, 2], range(5), IMAGE)
    feed(sup, [row(5, n0=0.85, n1=0.3)] * 3 + [row(5, n0=0.5, n1=0.5)] * 2)
    d = sup.tick(row(5, n0=0.4, n1=TH.t_milestone + 0.05), goal_mass=0.9)
    assert d.confirmed_node == 1 and d.state is SupervisorState.LEAVING
    d = sup.tick(row(5, n1=TH.t_milestone + 0.05, n2=0.3), goal_mass=0.9)   # still at node 1's view
    assert d.state is SupervisorState.LEAVING and d.confirmed_node is None
    with pytest.raises(ValueError, match="goal_mass must be finite"):
        feed(sup, [row(5, n1=TH.t_change_node - 0.05, n2=0.3)] * 2)
        sup.tick(row(5, n2=0.3), goal_mass=math.nan)


def test_the_belief_confirms_the_goal_only_as_the_target():
    """With the goal two nodes ahead inside the window, the belief's mass there confirms nothing
    (a garage run skipped two nodes that way and stopped 1.5 m short); once the node before the
    goal is reached, it does."""
    sup = NodeSwitchSupervisor([0, 1, 2, 3], range(6), IMAGE)
    feed(sup, [row(6, n0=0.85, n1=0.3)] * 3 + [row(6, n0=0.5, n1=0.4)] * 2)
    weak = row(6, n0=0.4, n1=0.4, n3=TH.t_lost + 0.02, n5=TH.t_lost + 0.1)
    assert 3 in sup.window() and sup.target_node == 1
    ds = [sup.tick(weak, goal_mass=0.9) for _ in range(3)]
    assert all(d.confirmed_node is None and "goal in sight" not in d.reason for d in ds)
    feed(sup, [row(6, n1=TH.t_milestone + 0.05)] + [row(6, n1=TH.t_change_node - 0.05, n2=0.3)] * 2)
    feed(sup, [row(6, n2=TH.t_milestone + 0.05)] + [row(6, n2=TH.t_change_node - 0.05, n3=0.3)] * 2)
    assert sup.target_node == 3
    assert "the belief holds 0.90 of its mass there" in sup.tick(weak, goal_mass=0.9).reason


def _settled_short(mode, driven_m, wait=True):
    """A goal node confirmed as the best of the map whose score then stays flat while the robot
    drives ``driven_m`` (in 20 ticks) with the belief's mode at ``mode``: the decisions."""
    config = replace(IMAGE, supervisor=replace(IMAGE.supervisor, confirm_best_of_map=True,
                                                goal_waits_for_belief=wait))
    sup = NodeSwitchSupervisor([0, 1, 2], range(5), config, arc_lengths_m=ARCS_1M)
    feed(sup, [row(5, n0=0.85, n1=0.3)] * 3 + [row(5, n0=0.5, n1=0.5)] * 2)
    sup.tick(row(5, n0=0.4, n1=TH.t_milestone + 0.05), travelled_m=0.0)
    feed(sup, [row(5, n1=TH.t_change_node - 0.05, n2=0.3)] * 2)
    weak = row(5, n1=0.3, n2=TH.t_lost + 0.05)          # the best of the map, below t_milestone
    d = sup.tick(weak, travelled_m=0.5, belief_mode=1)
    assert "goal in sight" in d.reason
    return [sup.tick(weak, travelled_m=0.5 + driven_m * (k + 1) / 20, belief_mode=mode) for k in range(20)]


def test_a_settled_goal_node_waits_while_the_belief_places_the_robot_before_it():
    """Confirmed as the best of the map a metre short, the goal node's score stays flat; the
    belief, still at the node before the goal, holds the arrival for up to the goal's arc."""
    settle = IMAGE.supervisor.goal_settle_ticks
    at_goal = _settled_short(mode=2, driven_m=0.5)
    assert at_goal[settle - 1].state is SupervisorState.GOAL_REACHED   # the mode agrees: as before
    short = _settled_short(mode=1, driven_m=2.0)                        # 0.1 m per tick
    states = [d.state for d in short]
    assert states.index(SupervisorState.GOAL_REACHED) == 9             # after the goal's 1 m arc
    assert "the belief still places the robot at node 1, before the goal" in short[settle].reason
    beyond = _settled_short(mode=3, driven_m=0.5)                       # past the goal, off the path
    assert beyond[settle - 1].state is SupervisorState.GOAL_REACHED
    off = _settled_short(mode=1, driven_m=2.0, wait=False)
    assert off[settle - 1].state is SupervisorState.GOAL_REACHED


def test_a_settled_goal_node_waits_while_the_goal_image_still_rises_below_t_milestone():
    """Confirmed a metre short, the goal node's score falls at once, while the goal image's,
    still below t_milestone, rises as the robot closes in: no arrival until it stops rising."""
    sup = _at_the_node_before_the_goal()
    settle = IMAGE.supervisor.goal_settle_ticks
    low = TH.t_milestone - 0.3
    d = sup.tick(row(5, n1=0.4, n2=TH.t_milestone + 0.05), goal_score=low)              # confirmed
    assert "goal in sight" in d.reason
    falling_node = row(5, n1=0.4, n2=TH.t_milestone)                                     # settles at once
    rising = [sup.tick(falling_node, goal_score=low + 0.01 * k) for k in range(1, 3 * settle)]
    assert all(d.state is not SupervisorState.GOAL_REACHED for d in rising)
    assert "settled at filtered" in rising[-1].reason and "still rising" in rising[-1].reason
    flat = [sup.tick(falling_node, goal_score=low + 0.01 * (3 * settle - 1)) for _ in range(settle)]
    assert [d.state for d in flat].count(SupervisorState.GOAL_REACHED) == 1
    assert flat[-1].state is SupervisorState.GOAL_REACHED and "the goal image" not in flat[-1].reason


def test_goal_image_arrival_off_ignores_the_goal_image():
    config = replace(IMAGE, supervisor=replace(IMAGE.supervisor, goal_image_arrival=False))
    with_image, without = _at_the_node_before_the_goal(config), _at_the_node_before_the_goal(config)
    scores = [0.6, 0.7, 0.8, 0.7, 0.6] + [0.5] * 6
    rows = [row(5, n1=0.4, n2=TH.t_milestone + 0.01 * k) for k in range(len(scores))]
    a = [with_image.tick(r, goal_score=s) for r, s in zip(rows, scores)]
    b = [without.tick(r) for r in rows]
    assert [(d.state, d.reason) for d in a] == [(d.state, d.reason) for d in b]
    assert all(d.goal_image_score is None for d in a)


def test_a_goal_score_that_is_not_finite_is_refused():
    sup = _at_the_node_before_the_goal()
    with pytest.raises(ValueError, match="goal_score must be finite"):
        sup.tick(row(5, n2=0.5), goal_score=float("nan"))


# -- driving on by odometry (supervisor.odometry_max_m) ------------------------------------------

ODOMETRY = NavigationConfig(supervisor=SupervisorConfig(confirm_best_of_map=False, goal_settle_ticks=0,
                                                        odometry_max_m=3.0))
ARCS_1M = {(k, k + 1): 1.0 for k in range(9)}


def _blind(n: int, far: int) -> np.ndarray:
    """A view of a stretch a moved prop changed: nothing near the plan matches, a far node a little."""
    return row(n, base=0.2, **{f"n{far}": 0.3})


def _drive(sup, rows, start_m=0.0, step_m=0.025):
    """Tick ``rows`` while the odometry drives ``step_m`` per tick (0.25 m/s at 10 Hz)."""
    return [sup.tick(r, travelled_m=start_m + step_m * k) for k, r in enumerate(rows)]


def test_where_the_views_match_nothing_the_robot_drives_on_by_odometry_then_is_lost():
    n = 10
    sup = NodeSwitchSupervisor(range(n), range(n), ODOMETRY, arc_lengths_m=ARCS_1M)
    decisions = _drive(sup, [_blind(n, far=9)] * 200)
    passed = [(k, d.confirmed_node) for k, d in enumerate(decisions) if d.confirmed_node is not None]
    # nodes 1, 2, 3 reached by odometry, each once the arc's metre is driven from the one before
    assert [node for _, node in passed] == [1, 2, 3]
    assert all(decisions[k].by_odometry and "by odometry" in decisions[k].reason for k, _ in passed)
    assert [round(0.025 * k, 2) for k, _ in passed] == [1.0, 2.0, 3.0]
    # driving on while the patience has run out, not before; then lost past 3 m since node 0
    first_on = next(k for k, d in enumerate(decisions) if d.driving_on)
    assert first_on + 1 >= ODOMETRY.supervisor.lost_patience_ticks      # ticks counted from 1
    lost = next(k for k, d in enumerate(decisions) if d.state is SupervisorState.LOST)
    assert 0.025 * lost > 3.0 and all(d.driving_on for d in decisions[first_on:lost])
    assert "since the last node seen" in decisions[lost].reason and not decisions[lost].driving_on


def test_a_node_seen_again_ends_the_drive_on_and_renews_its_budget():
    n = 10
    sup = NodeSwitchSupervisor(range(n), range(n), ODOMETRY, arc_lengths_m=ARCS_1M)
    rows = [_blind(n, far=9)] * 50 + [row(n, n2=0.9)] * 40 + [_blind(n, far=9)] * 200
    decisions = _drive(sup, rows)
    seen = [d for d in decisions if d.confirmed_node is not None and not d.by_odometry]
    assert [d.confirmed_node for d in seen] == [2]
    reached = [d.confirmed_node for d in decisions if d.by_odometry]
    assert reached[0] == 1 and 3 in reached and 4 in reached       # 3 m more after node 2 was seen
    assert any(d.state is SupervisorState.LOST for d in decisions)


def test_a_robot_already_past_the_budget_is_lost_not_moved_on_by_odometry():
    """The window kept a weak match (not lost) for 4 m without confirming a node, then matched
    nothing: no node is confirmed by odometry, however near the map puts the next one."""
    n = 10
    sup = NodeSwitchSupervisor(range(n), range(n), ODOMETRY, arc_lengths_m=ARCS_1M)
    weak = row(n, base=0.2, n0=0.45)       # above t_lost, below t_change_node: not lost, no progress
    decisions = _drive(sup, [weak] * 160 + [_blind(n, far=9)] * 40)
    assert not any(d.confirmed_node is not None for d in decisions)
    lost = next(k for k, d in enumerate(decisions) if d.state is SupervisorState.LOST)
    assert lost >= 160 and "drove 4." in decisions[lost].reason and "since the last node seen" in decisions[lost].reason


def test_the_goal_is_never_reached_by_odometry():
    sup = NodeSwitchSupervisor([0, 1, 2], range(4), ODOMETRY, arc_lengths_m=ARCS_1M)
    decisions = _drive(sup, [_blind(4, far=3)] * 150)
    assert [d.confirmed_node for d in decisions if d.confirmed_node is not None] == [1]
    assert decisions[-1].state is SupervisorState.LOST
    assert all(d.state is not SupervisorState.GOAL_REACHED for d in decisions)


@pytest.mark.parametrize("case", ["off", "no distance", "no arc lengths", "published"])
def test_without_the_setting_the_distance_or_arc_lengths_the_robot_is_lost_as_before(case):
    n = 10
    config = {"off": NavigationConfig(supervisor=replace(ODOMETRY.supervisor, odometry_max_m=0.0)),
              "published": ODOMETRY.as_published()}.get(case, ODOMETRY)
    sup = NodeSwitchSupervisor(range(n), range(n), config, arc_lengths_m=None if case == "no arc lengths" else ARCS_1M)
    rows = [_blind(n, far=9)] * 60
    decisions = feed(sup, rows) if case == "no distance" else _drive(sup, rows)
    assert not any(d.driving_on or d.confirmed_node is not None for d in decisions)
    lost = next(k for k, d in enumerate(decisions) if d.state is SupervisorState.LOST)
    assert lost < 40 and "since the last node seen" not in decisions[lost].reason


def test_a_distance_that_is_not_finite_and_a_bad_limit_are_refused():
    sup = NodeSwitchSupervisor([0, 1, 2], range(3), ODOMETRY, arc_lengths_m=ARCS_1M)
    with pytest.raises(ValueError, match="travelled_m"):
        sup.tick(row(3, n0=0.9), travelled_m=float("nan"))
    for bad in (-1.0, float("inf"), "3"):
        with pytest.raises(ValueError, match="odometry_max_m"):
            SupervisorConfig(odometry_max_m=bad)
