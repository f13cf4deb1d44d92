"""Global planner: Dijkstra over the weighted directed arcs of the topological map."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Hashable, Iterable, Tuple

import networkx as nx

NodeId = Hashable


class PlanningError(ValueError):
    """The map graph or a planning request is invalid."""


class UnknownNodeError(PlanningError):
    """A node id that the map does not have."""


class UnreachableGoalError(PlanningError):
    """No chain of directed arcs leads from the start node to the goal node."""

    def __init__(self, start: NodeId, goal: NodeId, reachable: int):
        self.start = start
        self.goal = goal
        super().__init__(
            f"goal node {goal!r} is unreachable from start node {start!r}: no chain of directed "
            f"arcs leads there (only {reachable} node(s) are reachable from {start!r})")


@dataclass(frozen=True)
class Plan:
    """A navigation sequence L0..Ln: ``nodes[0]`` is the start, ``nodes[-1]`` the goal."""

    nodes: Tuple[NodeId, ...]
    cost: float                   # sum of the arc weights (relative distance of the map)

    @property
    def start(self) -> NodeId:
        return self.nodes[0]

    @property
    def goal(self) -> NodeId:
        return self.nodes[-1]


class GlobalPlanner:
    """Shortest paths over a directed map graph whose arcs carry a non-negative weight.

    The weight is the mapper's relative distance ``M_distance`` (arc attribute ``weight`` by
    default). Weights must be finite and non-negative (Dijkstra's condition); arcs without the
    attribute count 1.
    """

    def __init__(self, graph: nx.DiGraph, weight: str = "weight"):
        if not isinstance(graph, nx.DiGraph):
            raise PlanningError(f"the map graph must be a networkx.DiGraph, got {type(graph).__name__}")
        if graph.number_of_nodes() == 0:
            raise PlanningError("the map graph has no nodes")
        for u, v, data in graph.edges(data=True):
            w = data.get(weight, 1.0)
            if isinstance(w, bool) or not isinstance(w, (int, float)) or not math.isfinite(w) or w < 0:
                raise PlanningError(f"arc {u!r} -> {v!r} has weight {w!r}; weights must be finite "
                                    "and non-negative")
        self.graph = graph
        self.weight = weight

    @classmethod
    def from_arcs(cls, nodes: Iterable[NodeId],
                  arcs: Iterable[Tuple[NodeId, NodeId, float]]) -> "GlobalPlanner":
        """Build from node ids and ``(source, target, weight)`` arcs; arcs must name known nodes."""
        graph = nx.DiGraph()
        graph.add_nodes_from(nodes)
        for u, v, w in arcs:
            for n in (u, v):
                if n not in graph:
                    raise UnknownNodeError(f"arc {u!r} -> {v!r} names node {n!r}, which is not a node "
                                           "of the map")
            graph.add_edge(u, v, weight=w)
        return cls(graph)

    def check_node(self, node: NodeId, role: str = "node") -> None:
        """Raise :class:`UnknownNodeError` naming ``role`` when ``node`` is not in the map."""
        if node not in self.graph:
            raise UnknownNodeError(f"{role} {node!r} is not a node of the map "
                                   f"({self.graph.number_of_nodes()} nodes)")

    def plan(self, start: NodeId, goal: NodeId) -> Plan:
        """The cheapest navigation sequence from ``start`` to ``goal`` (re-plan from any node)."""
        self.check_node(start, "start node")
        self.check_node(goal, "goal node")
        try:
            cost, nodes = nx.single_source_dijkstra(self.graph, start, goal, weight=self._weight)
        except nx.NetworkXNoPath:
            reachable = len(nx.descendants(self.graph, start)) + 1
            raise UnreachableGoalError(start, goal, reachable) from None
        return Plan(nodes=tuple(nodes), cost=float(cost))

    def _weight(self, u: NodeId, v: NodeId, data: dict) -> float:
        return float(data.get(self.weight, 1.0))
