"""Dijkstra over the directed, weighted arcs of a hand-made topological map."""

import math

import networkx as nx
import pytest

from controllers.planner import GlobalPlanner, PlanningError, UnknownNodeError, UnreachableGoalError


def diamond() -> GlobalPlanner:
    #   0 -> 1 -> 3 costs 1 + 1; 0 -> 2 -> 3 costs 5 + 0.5; 3 -> 4; 4 -> 0 closes a loop;
    #   5 is an island reachable from 4 only, with no way back.
    return GlobalPlanner.from_arcs(range(6), [(0, 1, 1.0), (1, 3, 1.0), (0, 2, 5.0), (2, 3, 0.5),
                                              (3, 4, 2.0), (4, 0, 1.0), (4, 5, 1.0)])


def test_cheapest_route_by_weight_not_by_hops():
    planner = GlobalPlanner.from_arcs(range(4), [(0, 3, 10.0), (0, 1, 1.0), (1, 2, 1.0), (2, 3, 1.0)])
    plan = planner.plan(0, 3)
    assert plan.nodes == (0, 1, 2, 3)
    assert plan.cost == pytest.approx(3.0)
    assert plan.start == 0 and plan.goal == 3


def test_plan_follows_arc_direction_through_the_loop():
    plan = diamond().plan(3, 1)          # no arc 3 -> 1: around the loop 3 -> 4 -> 0 -> 1
    assert plan.nodes == (3, 4, 0, 1)
    assert plan.cost == pytest.approx(4.0)


def test_replan_from_any_node_of_a_loop():
    n = 7
    planner = GlobalPlanner.from_arcs(range(n), [(k, (k + 1) % n, 1.0) for k in range(n)])
    goal = 2
    for start in range(n):
        plan = planner.plan(start, goal)
        hops = (goal - start) % n
        assert plan.nodes == tuple((start + k) % n for k in range(hops + 1))
        assert plan.cost == pytest.approx(hops)


def test_start_equal_to_goal_is_a_one_node_plan():
    plan = diamond().plan(2, 2)
    assert plan.nodes == (2,) and plan.cost == 0.0


def test_unreachable_goal_names_both_nodes():
    with pytest.raises(UnreachableGoalError) as info:
        diamond().plan(5, 0)
    message = str(info.value)
    assert "goal node 0" in message and "start node 5" in message
    assert info.value.start == 5 and info.value.goal == 0


def test_unknown_nodes_are_named():
    with pytest.raises(UnknownNodeError, match="goal node 42"):
        diamond().plan(0, 42)
    with pytest.raises(UnknownNodeError, match="start node -1"):
        diamond().plan(-1, 0)
    with pytest.raises(UnknownNodeError, match="node 9"):
        GlobalPlanner.from_arcs([0, 1], [(0, 9, 1.0)])


@pytest.mark.parametrize("weight", [-1.0, math.nan, math.inf, "far"])
def test_bad_weights_name_the_arc(weight):
    graph = nx.DiGraph()
    graph.add_edge(0, 1, weight=1.0)
    graph.add_edge(1, 2, weight=weight)
    with pytest.raises(PlanningError, match="arc 1 -> 2"):
        GlobalPlanner(graph)


def test_missing_weight_counts_one_and_zero_weight_is_allowed():
    graph = nx.DiGraph()
    graph.add_edge("a", "b")
    graph.add_edge("b", "c")
    graph.add_edge("a", "x", weight=0.0)
    graph.add_edge("x", "c", weight=1.5)
    plan = GlobalPlanner(graph).plan("a", "c")
    assert plan.nodes == ("a", "x", "c") and plan.cost == pytest.approx(1.5)


def test_empty_or_wrong_graph_is_rejected():
    with pytest.raises(PlanningError, match="no nodes"):
        GlobalPlanner(nx.DiGraph())
    with pytest.raises(PlanningError, match="DiGraph"):
        GlobalPlanner(nx.Graph([(0, 1)]))
