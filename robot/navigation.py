"""The navigation episode: the closed loop that drives a base to a goal node of a saved map.

HAL-agnostic: the same loop runs the simulated Limo and the serial Limo. Every control period::

    frame = base.read()                                   # camera (+ odometry / IMU)
    x = descriptor.describe_thirds([frame.rgb])[0]        # (4, D): full view, Left, Middle, Right
    row = node_descriptors @ x[0]                         # similarity to every node (one product)
    thirds = node_descriptors @ x[1:].T                   # (N, 3): every third against every node
    step = navigator.tick(row, thirds=thirds, thirds_contrast=contrast_thirds(thirds), heading_rad=yaw)
    base.apply(step.velocity); base.tick()

and it stops when the navigator declares arrival or failure, the step budget runs out, the base
reports a fault, or an observer asks it to (e.g. the simulator saw the robot topple). The base is
commanded to zero velocity on every way out, Ctrl-C included (``finally``).

Ground truth never enters the loop: callers who have it (the simulator) pass an *observer*, a
callable that sees every :class:`StepRecord` after the step and may return a reason to abort.

Setting an episode up, before the loop:

* :func:`attach_descriptor` loads the map's vocabulary into the descriptor in use and refuses a
  map built with another descriptor (:class:`DescriptorMismatchError`);
* :func:`derive_thresholds` derives the navigation thresholds from the map (see there);
  explicit values come from ``NavigationConfig.thresholds`` with
  ``EpisodeConfig.thresholds_from_map: false``;
* :func:`resolve_goal` turns a goal (node id, image file or image array) into a node:
  unknown ids raise :class:`controllers.planner.UnknownNodeError`, unreadable files
  :class:`GoalImageError`, images that match no node above ``t_milestone``
  :class:`controllers.localisation.GoalNotLocalisedError`.

During the loop, a goal that turns out to be unreachable in the directed graph from where the
robot localised raises :class:`controllers.planner.UnreachableGoalError` (naming both nodes),
after the base was stopped.
"""

from __future__ import annotations

import enum
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Optional, Protocol, Sequence, Union

import cv2
import numpy as np

from controllers.config import NavigationConfig, Thresholds
from controllers.localisation import GoalNotLocalisedError, Localisation, localise_goal_image
from controllers.actions import Action
from controllers.navigator import NavigationStep, Navigator, NavState
from controllers.planner import UnknownNodeError, UnreachableGoalError
from controllers.voter import contrast_thirds
from maps.graph import MapError, TopoMap
from maps.store import LoadedMap
from robot.descriptors.base import Descriptor, DescriptorError
from robot.hal import HalError, RobotBase, SensorFrame, VelocityCommand

__all__ = [
    "ActionPolicy", "DescriptorMismatchError", "EpisodeConfig", "EpisodeEnd", "EpisodeOutcome", "GoalImageError",
    "GoalNotLocalisedError", "GoalSpec", "ResolvedGoal", "StepRecord", "StepTiming",
    "UnknownNodeError", "UnreachableGoalError", "attach_descriptor", "derive_thresholds",
    "parse_goal", "read_goal_image", "resolve_goal", "run_episode", "step_budget",
]


# -- errors -----------------------------------------------------------------------------------
class GoalImageError(ValueError):
    """The goal image file cannot be read; the message names the file."""


class DescriptorMismatchError(MapError):
    """The map was built with another descriptor (backend, settings, vocabulary or dimension)
    than the one in use; the message names the map folder and the difference."""


# -- configuration ----------------------------------------------------------------------------
@dataclass(frozen=True)
class EpisodeConfig:
    """How an episode is set up around the navigator (the ``episode`` section of the stack config).

    Thresholds: with ``thresholds_from_map`` (default) they are derived from the map's own
    statistics by :func:`derive_thresholds`; otherwise ``NavigationConfig.thresholds`` is used as
    written. Step budget: ``min_steps`` plus ``budget_factor`` times the ticks needed to drive
    the route's shortest length at the forward speed; ``default_max_steps`` when the length is
    unknown (a goal node or image without a route).
    """

    #: derive t_milestone, t_change_node, t_lost and t_limited_control from the map (default);
    #: false: use navigation.thresholds as written
    thresholds_from_map: bool = True
    #: the step budget allows this many times the time needed to drive the route at forward speed
    budget_factor: float = 3.0
    #: plus this many ticks for localisation turns and searches
    min_steps: int = 600
    #: the budget when the route length is unknown (10 minutes at 10 Hz)
    default_max_steps: int = 6000
    #: the voter sees each third's similarity to the target as a contrast against the other
    #: nodes (controllers.voter.contrast_thirds: 1 = the node this third resembles most,
    #: 0 = a typical node) instead of the raw cosine, so votes survive lighting changes that
    #: lower every cosine; t_limited_control is then on that scale (CONTROL_CONTRAST)
    thirds_contrast: bool = True

    def __post_init__(self) -> None:
        for name in ("thresholds_from_map", "thirds_contrast"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if not (isinstance(self.budget_factor, (int, float)) and math.isfinite(self.budget_factor)
                and self.budget_factor >= 1.0):
            raise ValueError(f"budget_factor must be a number >= 1, got {self.budget_factor!r}")
        for name in ("min_steps", "default_max_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")


def step_budget(config: EpisodeConfig, navigation: NavigationConfig, control_period_s: float,
                route_length_m: Optional[float] = None) -> int:
    """The episode's step budget (control ticks); see :class:`EpisodeConfig`."""
    if route_length_m is None:
        return config.default_max_steps
    drive_ticks = route_length_m / navigation.speeds.forward.v_mps / control_period_s
    return config.min_steps + int(math.ceil(config.budget_factor * drive_ticks))


# -- setting up: descriptor, thresholds, goal ----------------------------------------------------
def attach_descriptor(loaded_map: LoadedMap, descriptor: Descriptor) -> Descriptor:
    """Load the map's vocabulary into ``descriptor`` (the one the configuration asks for) and check
    that it is the descriptor the map was built with; returns it.

    Raises :class:`DescriptorMismatchError` naming the map folder when the backend, settings,
    vocabulary or dimension differ.
    """
    mine, theirs = descriptor.identity, loaded_map.identity
    if mine.backend != theirs.backend or dict(mine.settings) != dict(theirs.settings):
        raise DescriptorMismatchError(
            f"map {loaded_map.path}: built with descriptor {theirs.backend!r} {dict(theirs.settings)}, but "
            f"the configuration uses {mine.backend!r} {dict(mine.settings)}; navigate with the map's "
            "descriptor or map again")
    try:
        descriptor.load_state(loaded_map.descriptor_state)
    except DescriptorError as exc:
        raise DescriptorMismatchError(f"map {loaded_map.path}: its descriptor state does not fit the "
                                      f"descriptor in use: {exc}") from None
    problem = theirs.mismatch(descriptor.identity)
    if problem:
        raise DescriptorMismatchError(f"map {loaded_map.path}: built with another descriptor than the one "
                                      f"in use (map's value last): {problem}")
    if descriptor.identity.dim and descriptor.identity.dim != loaded_map.topomap.dim:
        raise DescriptorMismatchError(f"map {loaded_map.path}: descriptors have dimension "
                                      f"{loaded_map.topomap.dim}, the descriptor in use {descriptor.identity.dim}")
    return descriptor


#: Fractions of the band [T_add_new_node, self_similarity] (see controllers.config.Thresholds.from_map).
MILESTONE_FRACTION = 0.25
CHANGE_FRACTION = 0.15
LOST_FRACTION = 0.1


def map_self_similarity(loaded_map: LoadedMap) -> float:
    """How alike a view taken at a node is to that node, estimated from the walkthrough.

    The builder logs every frame's similarity to the node it stands at (``sim_to_node``); the
    frames right after a node are views from (nearly) the node's pose. The estimate is the median
    of that similarity over the first frame after each node (the first frame of every node's
    stretch); 1.0 when the map has no build log (the identical view).
    """
    log = loaded_map.log
    if log is None or log.n_frames < 3:
        return 1.0
    node = np.asarray(log.node)
    sims = np.asarray(log.sim_to_node, dtype=float)
    # frame k+1 is the first frame after frame k became (or returned to) a node
    firsts = np.flatnonzero(node[1:] != node[:-1]) + 2
    firsts = firsts[firsts < len(sims)]
    values = sims[firsts]
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else 1.0


#: t_limited_control on the contrast scale of controllers.voter.contrast_thirds: a third votes
#: when the target is closer to the node it resembles most than to a typical node of the map.
CONTROL_CONTRAST = 0.5


def derive_thresholds(loaded_map: LoadedMap, navigation: NavigationConfig, *,
                      thirds_contrast: bool = True) -> Thresholds:
    """The navigation thresholds derived from the map (the default; ``EpisodeConfig``).

    Two consecutive nodes score about ``T_add_new_node`` against each other (the mapper added a
    node when the similarity to the last one fell below it), and a view taken at a node scores
    about :func:`map_self_similarity` against it. ``Thresholds.from_map`` places ``t_milestone``,
    ``t_change_node`` and ``t_lost`` as fractions of that band (MILESTONE_FRACTION,
    CHANGE_FRACTION, LOST_FRACTION of this module). ``t_limited_control`` is CONTROL_CONTRAST when
    the voter sees contrast scores (``thirds_contrast``), else kept from ``navigation.thresholds``:
    the thirds' scale does not follow the map's node spacing.
    """
    t_add = float(loaded_map.thresholds.T_add_new_node)
    self_sim = map_self_similarity(loaded_map)
    if not self_sim > t_add + 0.02:
        self_sim = min(1.0, t_add + 0.1)   # a degenerate log: keep a usable band above T_add_new_node
    return Thresholds.from_map(t_add, self_sim, milestone_fraction=MILESTONE_FRACTION,
                               change_fraction=CHANGE_FRACTION, lost_fraction=LOST_FRACTION,
                               t_limited_control=CONTROL_CONTRAST if thirds_contrast
                               else navigation.thresholds.t_limited_control)


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


GOAL_RIVAL_HOPS = 2
GOAL_RIVAL_MARGIN = 0.04


def resolve_goal(goal: GoalSpec, topomap: TopoMap, descriptor: Descriptor,
                 thresholds: Thresholds) -> ResolvedGoal:
    """Turn a goal (node id, image path or RGB image) into a node of the map.

    A goal image is localised against every node with ``t_milestone`` (turning the robot cannot
    help a fixed goal picture, so no match is final: :class:`GoalNotLocalisedError`).
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
    try:
        found = localise_goal_image(topomap.similarities(view), topomap.node_ids, thresholds.t_milestone)
    except GoalNotLocalisedError as exc:
        raise GoalNotLocalisedError(f"goal {source}: {exc}") from None
    return ResolvedGoal(node=int(found.node), source=source, localisation=found, image=image,
                        rivals=_goal_rivals(topomap, int(found.node), topomap.similarities(view)))


def _goal_rivals(topomap: TopoMap, node: int, row: np.ndarray) -> tuple[int, ...]:
    import networkx as nx

    near = nx.single_source_shortest_path_length(topomap.graph.to_undirected(as_view=True), node,
                                                 cutoff=GOAL_RIVAL_HOPS)
    ids = topomap.node_ids.tolist()
    best = float(row[ids.index(node)])
    return tuple(int(n) for n, score in sorted(zip(ids, row), key=lambda t: -t[1])
                 if n not in near and score >= best - GOAL_RIVAL_MARGIN)


# -- the loop ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class StepTiming:
    """Wall time of one control step, in milliseconds, split by stage."""

    read_ms: float        # base.read(): the camera render in simulation, the frame grab on a real base
    describe_ms: float    # describe_thirds of the frame and the similarity products
    decide_ms: float      # navigator.tick and base.apply
    tick_ms: float        # base.tick(): physics steps (simulation) or waiting for the next period (real)

    @property
    def total_ms(self) -> float:
        return self.read_ms + self.describe_ms + self.decide_ms + self.tick_ms


@dataclass(frozen=True)
class StepRecord:
    """What an observer sees after each step (the frame, the decision, what was applied)."""

    index: int                    # 0-based step number
    frame: SensorFrame
    step: NavigationStep
    applied: VelocityCommand      # what the base accepted after its limits
    similarities: np.ndarray      # raw similarity of the view to every node (row order node_ids)
    timing: StepTiming


class EpisodeEnd(enum.Enum):
    """Why the loop ended."""

    ARRIVED = "arrived"           # the navigator confirmed the goal node and declared arrival
    FAILED = "failed"             # the navigator gave up (cannot place itself, lost too often)
    STEP_BUDGET = "step_budget"   # the step budget ran out
    ABORTED = "aborted"           # an observer stopped the episode (e.g. the robot toppled)
    BASE_FAULT = "base_fault"     # the base reported a fault


@dataclass(frozen=True)
class EpisodeOutcome:
    """The result of one episode, from the robot's own point of view (no ground truth)."""

    end: EpisodeEnd
    reason: str
    goal_node: int
    steps: int
    sim_time_s: float                           # base clock from the first to the last frame
    wall_time_s: float
    start_node: Optional[int]                   # the node of the first localisation
    plans: tuple[tuple[int, ...], ...]          # every plan made, in order (re-plans after the first)
    visited_nodes: tuple[int, ...]              # localised / confirmed nodes, in order
    relocalisations: int
    replans: int
    thresholds: Thresholds
    timings: tuple[StepTiming, ...]

    @property
    def arrived(self) -> bool:
        """The robot itself declared arrival."""
        return self.end is EpisodeEnd.ARRIVED

    @property
    def planned_nodes(self) -> tuple[int, ...]:
        """The first plan (empty when the robot never placed itself)."""
        return self.plans[0] if self.plans else ()

    def mean_timing(self) -> StepTiming:
        """Mean wall time per step by stage (zeros when no step ran)."""
        if not self.timings:
            return StepTiming(0.0, 0.0, 0.0, 0.0)
        t = np.array([[s.read_ms, s.describe_ms, s.decide_ms, s.tick_ms] for s in self.timings])
        return StepTiming(*(float(v) for v in t.mean(axis=0)))


Observer = Callable[[StepRecord], Optional[str]]


class ActionPolicy(Protocol):
    """A learned action chooser that replaces the two-cycle voter (the SPTM-style baseline).

    Every step the loop hands it the camera frame; it returns ``choose(target_node) -> Action``
    for that frame (the navigator asks for at most one target per tick). Localisation,
    planning and node switching stay the navigator's.
    """

    name: str

    def for_frame(self, rgb: np.ndarray) -> Callable[[int], Action]: ...


class _Heading:
    """Yaw for the navigator's turn meter: odometry yaw, else the integrated IMU rate, else None."""

    def __init__(self) -> None:
        self._yaw: Optional[float] = None
        self._stamp: Optional[float] = None

    def update(self, frame: SensorFrame) -> Optional[float]:
        if frame.odometry is not None:
            return float(frame.odometry.yaw_rad)
        if frame.imu_yaw_rate_radps is None:
            return None
        if self._yaw is None:
            self._yaw = 0.0
        elif self._stamp is not None:
            self._yaw += float(frame.imu_yaw_rate_radps) * max(0.0, frame.stamp_s - self._stamp)
        self._stamp = frame.stamp_s
        return self._yaw


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1000.0


def _plain(nodes: Sequence) -> tuple[int, ...]:
    return tuple(int(n) for n in nodes)


def run_episode(base: RobotBase, topomap: TopoMap, descriptor: Descriptor, goal_node: int,
                config: NavigationConfig, max_steps: int,
                observer: Optional[Observer] = None, *, thirds_contrast: bool = True,
                action_policy: Optional[ActionPolicy] = None) -> EpisodeOutcome:
    """Drive the connected ``base`` to ``goal_node`` of ``topomap``; see the module docstring.

    ``descriptor`` must be the map's (see :func:`attach_descriptor`); ``config.thresholds`` are
    used as given (derive them with :func:`derive_thresholds` first). ``max_steps``: the step
    budget (control ticks). ``observer(record)`` is called after every step; returning a string
    ends the episode as ABORTED with that reason. ``thirds_contrast``: the voter gets the thirds'
    contrast against all nodes (:func:`controllers.voter.contrast_thirds`) instead of raw cosines.
    ``action_policy``: a learned policy that picks the actions instead of the voter (its time
    counts as ``describe_ms``).

    Raises :class:`UnreachableGoalError` when the robot localised at a node from which no arc
    chain leads to the goal, :class:`HalError` when the base gives no camera image; the base is
    stopped first in every case.
    """
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1:
        raise ValueError(f"max_steps must be an integer >= 1, got {max_steps!r}")
    node_ids = topomap.node_ids
    nodes = np.ascontiguousarray(topomap.descriptors, dtype=np.float32)
    navigator = Navigator(topomap.graph, node_ids, goal_node, config,
                          node_headings=topomap.odom_headings)
    heading = _Heading()
    timings: list[StepTiming] = []
    plans: list[tuple[int, ...]] = []
    first_stamp = last_stamp = None
    step: Optional[NavigationStep] = None
    end, reason = EpisodeEnd.STEP_BUDGET, f"step budget of {max_steps} steps ran out"
    started = time.perf_counter()
    try:
        for index in range(max_steps):
            t0 = time.perf_counter()
            frame = base.read()
            read_ms = _ms(t0)
            if frame.fault:
                end, reason = EpisodeEnd.BASE_FAULT, f"the base reported a fault: {frame.fault}"
                break
            if frame.rgb is None:
                raise HalError("the base delivered a frame without a camera image; navigation needs the camera")
            first_stamp = frame.stamp_s if first_stamp is None else first_stamp
            last_stamp = frame.stamp_s

            t0 = time.perf_counter()
            views = np.asarray(descriptor.describe_thirds([frame.rgb]), dtype=np.float32)[0]
            similarities = nodes @ views[0]
            policy = action_policy.for_frame(frame.rgb) if action_policy is not None else None
            describe_ms = _ms(t0)

            t0 = time.perf_counter()
            # (N, 3): every third against every node, one product (the contrast needs them all)
            thirds = nodes @ views[1:].T
            step = navigator.tick(similarities, thirds=thirds,
                                  thirds_contrast=contrast_thirds(thirds) if thirds_contrast else None,
                                  heading_rad=heading.update(frame), policy=policy)
            applied = base.apply(step.velocity)
            decide_ms = _ms(t0)
            if step.planned_path and (not plans or plans[-1] != _plain(step.planned_path)):
                plans.append(_plain(step.planned_path))

            if step.finished:
                timings.append(StepTiming(read_ms, describe_ms, decide_ms, 0.0))
                _notify(observer, index, frame, step, applied, similarities, timings[-1])
                if navigator.planning_error is not None:
                    raise navigator.planning_error
                end = EpisodeEnd.ARRIVED if step.state is NavState.ARRIVED else EpisodeEnd.FAILED
                reason = step.reason
                break
            t0 = time.perf_counter()
            base.tick()
            timings.append(StepTiming(read_ms, describe_ms, decide_ms, _ms(t0)))
            abort = _notify(observer, index, frame, step, applied, similarities, timings[-1])
            if abort:
                end, reason = EpisodeEnd.ABORTED, abort
                break
    finally:
        base.stop()
    return EpisodeOutcome(
        end=end, reason=reason, goal_node=int(goal_node), steps=len(timings),
        sim_time_s=float(last_stamp - first_stamp) if first_stamp is not None else 0.0,
        wall_time_s=time.perf_counter() - started,
        start_node=int(step.visited_nodes[0]) if step is not None and step.visited_nodes else None,
        plans=tuple(plans), visited_nodes=_plain(step.visited_nodes) if step is not None else (),
        relocalisations=step.relocalisations if step is not None else 0,
        replans=step.replans if step is not None else 0,
        thresholds=config.thresholds, timings=tuple(timings))


def _notify(observer: Optional[Observer], index: int, frame: SensorFrame, step: NavigationStep,
            applied: VelocityCommand, similarities: np.ndarray, timing: StepTiming) -> Optional[str]:
    if observer is None:
        return None
    return observer(StepRecord(index=index, frame=frame, step=step, applied=applied,
                               similarities=similarities, timing=timing))


def configure_thresholds(loaded_map: LoadedMap, navigation: NavigationConfig,
                         episode: EpisodeConfig) -> NavigationConfig:
    """``navigation`` with the thresholds the episode uses: derived from the map when
    ``episode.thresholds_from_map``, else as written."""
    if not episode.thresholds_from_map:
        return navigation
    return replace(navigation, thresholds=derive_thresholds(loaded_map, navigation,
                                                            thirds_contrast=episode.thirds_contrast))
