"""The goal of an episode: a node id, an image file or an image, turned into a node of the map."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import cv2
import numpy as np

from controllers.belief import LikelihoodError, SimilarityModel
from controllers.config import NavigationConfig
from controllers.localisation import GoalNotLocalisedError, Localisation, localise, localise_by_likelihood
from controllers.planner import UnknownNodeError
from descriptors.base import Descriptor, DescriptorError
from maps.graph import TopoMap


class GoalImageError(ValueError):
    """The goal image file cannot be read; the message names the file."""


GoalSpec = Union[int, str, Path, np.ndarray]


def parse_goal(text: str) -> Union[int, Path]:
    """A command-line goal: an integer is a node id, anything else a path to an image file."""
    stripped = str(text).strip()
    if stripped.lstrip("-").isdigit():
        return int(stripped)
    return Path(stripped)


def read_goal_image(path: Union[str, Path]) -> np.ndarray:
    """The goal image as RGB uint8 (H, W, 3); raises :class:`GoalImageError` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise GoalImageError(f"goal image {path}: no such file")
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise GoalImageError(f"goal image {path}: cannot read it as an image (not an image, or damaged)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


@dataclass(frozen=True)
class ResolvedGoal:
    """The goal node and how it was found (``localisation`` only for goal images)."""

    node: int
    source: str                                   # "node id 7" or "image goal.png" / "image"
    localisation: Optional[Localisation] = None
    image: Optional[np.ndarray] = None            # the goal image (RGB), for pictures
    #: other places the goal image resembles almost as much (nodes more than
    #: GOAL_RIVAL_HOPS arcs from the goal node scoring within GOAL_RIVAL_MARGIN of it): an
    #: ambiguous goal picture (a dead end, a blank wall); the robot may stop at the wrong one
    rivals: tuple[int, ...] = ()
    #: the goal image's descriptor (D,), for the final approach that compares the view with the
    #: goal image itself (None for a node-id goal)
    descriptor: Optional[np.ndarray] = None


GOAL_RIVAL_HOPS = 2
GOAL_RIVAL_MARGIN = 0.04


def resolve_goal(goal: GoalSpec, topomap: TopoMap, descriptor: Descriptor,
                 navigation: NavigationConfig) -> ResolvedGoal:
    """Turn a goal (node id, image path or RGB image) into a node of the map.

    A goal image is placed against every node (turning the robot cannot help a fixed goal
    picture, so no match is final: :class:`GoalNotLocalisedError`): with
    ``localiser.goal_by_likelihood`` by the map's likelihood
    (:func:`controllers.localisation.localise_by_likelihood`: the posterior mass near its best
    node at least ``belief.confidence``, its score above ``t_lost``), else, or when the map's
    keyframes support no likelihood, above ``t_milestone`` (the paper).
    """
    if isinstance(goal, (bool, np.bool_)):
        raise UnknownNodeError(f"goal {goal!r} is neither a node id nor an image")
    if isinstance(goal, (int, np.integer)):
        node = int(goal)
        if node not in topomap:
            ids = topomap.node_ids
            raise UnknownNodeError(f"goal node {node} is not a node of the map ({len(ids)} nodes, ids "
                                   f"{int(ids.min())}..{int(ids.max())})")
        return ResolvedGoal(node=node, source=f"node id {node}")
    if isinstance(goal, (str, Path)):
        image, source = read_goal_image(goal), f"image {goal}"
    else:
        image, source = np.asarray(goal), "image"
    try:
        view = np.asarray(descriptor.describe([image]), dtype=np.float32)[0]
    except DescriptorError as exc:
        raise GoalImageError(f"goal {source}: {exc}") from None
    row = topomap.similarities(view)
    found = _place_goal_image(topomap, row, navigation)
    if not found.accepted:
        raise GoalNotLocalisedError(f"goal {source}: the goal image matches no node of the map: {found.describe()}")
    return ResolvedGoal(node=int(found.node), source=source, localisation=found, image=image,
                        rivals=_goal_rivals(topomap, int(found.node), row), descriptor=view)


def _place_goal_image(topomap: TopoMap, row: np.ndarray, navigation: NavigationConfig) -> Localisation:
    """The goal image's best node, accepted or not by the configured rule."""
    ids = [int(n) for n in topomap.node_ids]
    thresholds = navigation.thresholds
    if navigation.localiser.goal_by_likelihood:
        try:
            model = SimilarityModel.from_references(topomap.descriptors, topomap.graph, ids)
        except LikelihoodError:
            model = None                   # keyframes alike or too few: the paper's rule below
        if model is not None:
            belief = navigation.belief
            return localise_by_likelihood(row, ids, topomap.graph, model, confidence=belief.confidence,
                                          hops=belief.confidence_hops, floor=thresholds.t_lost)
    return localise(row, ids, thresholds.t_milestone)


def _goal_rivals(topomap: TopoMap, node: int, row: np.ndarray, hops: int = GOAL_RIVAL_HOPS,
                 margin: float = GOAL_RIVAL_MARGIN) -> tuple[int, ...]:
    """Nodes more than ``hops`` arcs from ``node`` that score within ``margin`` of it, best first."""
    import networkx as nx

    near = nx.single_source_shortest_path_length(topomap.graph.to_undirected(as_view=True), node, cutoff=hops)
    ids = topomap.node_ids.tolist()
    best = float(row[ids.index(node)])
    return tuple(int(n) for n, score in sorted(zip(ids, row), key=lambda t: -t[1])
                 if n not in near and score >= best - margin)
