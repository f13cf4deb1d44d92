"""The navigation episode: the closed loop that drives a base to a goal node of a saved map.

HAL-agnostic: the same loop runs the simulated Limo and the serial Limo. Every control period::

    frame = base.read()                                   # camera (+ odometry / IMU)
    x = descriptor.describe_thirds([frame.rgb])[0]        # (4, D): full view, Left, Middle, Right
    row = node_descriptors @ x[0]                         # similarity to every node (one product)
    thirds = node_descriptors @ x[1:].T                   # (N, 3): every third against every node
    belief.move(odometry motion); belief.observe(row)    # the belief over the map
    step = navigator.tick(row, thirds=thirds, thirds_contrast=contrast_thirds(thirds), heading_rad=yaw,
                          belief=belief.snapshot(),       # it places the robot with localiser.from_belief
                          goal_score=goal_descriptor @ x[0],   # image goals: the final approach
                          travelled_m=odometry distance so far,  # driving on where the views match nothing
                          bearings=node -> column_shift(view columns, node columns))  # navigation.bearing
    base.apply(step.velocity); base.tick()

and it stops when the navigator declares arrival or failure, the step budget runs out, the base
reports a fault, or an observer asks it to (e.g. the simulator saw the robot topple). The base is
commanded to zero velocity on every way out, Ctrl-C included (``finally``).

Ground truth never enters the loop: callers who have it (the simulator) pass an *observer*, a
callable that sees every :class:`StepRecord` after the step and may return a reason to abort.

Before the loop, :mod:`robot.episode.setup` attaches the map's descriptor and derives the
thresholds, and :mod:`robot.episode.goal` turns the goal into a node. During the loop, a goal that turns out to be unreachable in the directed graph from where the
robot localised raises :class:`controllers.planner.UnreachableGoalError` (naming both nodes),
after the base was stopped.
"""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass, replace
from typing import Callable, Optional, Protocol, Sequence

import numpy as np

from controllers.actions import Action
from controllers.belief import BeliefSnapshot
from controllers.choosers import PolicyChooser
from controllers.config import NavigationConfig, Thresholds
from controllers.navigator import DRIVING_STATES, NavigationStep, Navigator, NavState
from controllers.stall import StallMonitor
from controllers.voter import contrast_thirds
from core.hal import HalError, RobotBase, SensorFrame, VelocityCommand
from core.yaw_rate import YawRateIntegrator
from descriptors.base import Descriptor, has_columns
from descriptors.columns import column_shift
from maps.graph import MapError, TopoMap
from robot.episode.belief import BeliefTracker, OdometryMotion, map_belief


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
    belief: Optional[BeliefSnapshot] = None   # the belief over the map after this view (None: no belief)
    goal_score: Optional[float] = None        # the view's similarity to the goal image (None: a node-id goal)


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
    belief_setup: str = ""                      # how the belief over the map was set up, or why not

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


def navigation_headings(topomap: TopoMap, source: str) -> Optional[dict[int, float]]:
    """The map's node headings from ``source`` (``navigation.heading_source``); None for a map
    without any (from a video). A recorded map without that source's raises MapError: navigating
    on the other source's headings would mix two drifts."""
    headings = topomap.headings(source)
    if headings is None and source != "odometry" and topomap.odom_headings is not None:
        raise MapError(f"navigation.heading_source {source!r}: the map has no {source} headings (made before "
                       "they were kept); rebuild it from its recording")
    return headings


class _Heading:
    """Yaw for the navigator (``navigation.heading_source``): ``odometry``: the odometry's yaw,
    else the integrated IMU rate, else None; ``gyro``: the integrated IMU rate, else None."""

    def __init__(self, source: str = "odometry") -> None:
        self._source = source
        self._gyro = YawRateIntegrator()

    def update(self, frame: SensorFrame) -> Optional[float]:
        if self._source == "odometry" and frame.odometry is not None:
            return float(frame.odometry.yaw_rad)     # the gyro is not integrated where it is not used
        if frame.imu_yaw_rate_radps is not None:
            self._gyro.update(frame.stamp_s, frame.imu_yaw_rate_radps)
        return self._gyro.yaw_rad


class _Distance:
    """The distance the odometry has driven so far (metres along the heading, less when
    reversing), or None while the base gives no odometry."""

    def __init__(self) -> None:
        self._motion = OdometryMotion()
        self._m = 0.0

    def update(self, frame: SensorFrame) -> Optional[float]:
        if frame.odometry is None:
            return None
        self._m += self._motion.update(frame.odometry)[0]
        return self._m


class _Stall:
    """The stall monitor fed from the frames: the yaw rate applied over each period against the
    gyro's (:class:`controllers.stall.StallMonitor`), watched only while the robot drives."""

    def __init__(self, config: NavigationConfig) -> None:
        self.monitor = StallMonitor(config.recovery)
        self._w: Optional[float] = None       # the yaw rate applied since the last frame (None: not driving)

    def update(self, frame: SensorFrame) -> bool:
        if self._w is None:
            self.monitor.reset()
        return self.monitor.update(frame.stamp_s, self._w or 0.0, frame.imu_yaw_rate_radps)

    def applied(self, command: VelocityCommand, driving: bool) -> None:
        self._w = float(command.w_radps) if driving else None


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1000.0


def _plain(nodes: Sequence) -> tuple[int, ...]:
    return tuple(int(n) for n in nodes)


def run_episode(base: RobotBase, topomap: TopoMap, descriptor: Descriptor, goal_node: int,
                config: NavigationConfig, max_steps: int,
                observer: Optional[Observer] = None, *, thirds_contrast: bool = True,
                action_policy: Optional[ActionPolicy] = None,
                goal_descriptor: Optional[np.ndarray] = None,
                node_columns: Optional[np.ndarray] = None) -> EpisodeOutcome:
    """Drive the connected ``base`` to ``goal_node`` of ``topomap``; see the module docstring.

    ``descriptor`` must be the map's (see :func:`attach_descriptor`); ``config.thresholds`` are
    used as given (derive them with :func:`robot.episode.setup.derive_thresholds` first). ``max_steps``: the step
    budget (control ticks). ``observer(record)`` is called after every step; returning a string
    ends the episode as ABORTED with that reason. ``thirds_contrast``: the voter gets the thirds'
    contrast against all nodes (:func:`controllers.voter.contrast_thirds`) instead of raw cosines.
    ``action_policy``: a learned policy that picks the actions instead of the voter (its time
    counts as ``describe_ms``). ``goal_descriptor``: the goal image's descriptor (D,), when the
    goal is an image: every view is also compared with it, for the final approach
    (``supervisor.goal_image_arrival``). ``node_columns``: the map's column profiles
    (:attr:`maps.store.LoadedMap.columns`), needed with ``navigation.bearing.enabled``: each view's
    profile is aligned with the target node's (:func:`descriptors.columns.column_shift`).

    Raises :class:`UnreachableGoalError` when the robot localised at a node from which no arc
    chain leads to the goal, :class:`HalError` when the base gives no camera image; the base is
    stopped first in every case.
    """
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1:
        raise ValueError(f"max_steps must be an integer >= 1, got {max_steps!r}")
    node_ids = topomap.node_ids
    nodes = np.ascontiguousarray(topomap.descriptors, dtype=np.float32)
    goal_view = None
    if goal_descriptor is not None:
        goal_view = np.asarray(goal_descriptor, dtype=np.float32).reshape(-1)
        if goal_view.shape != (nodes.shape[1],):
            raise ValueError(f"goal_descriptor must have the map's descriptor length {nodes.shape[1]}, "
                             f"got shape {np.shape(goal_descriptor)}")
    columns_of = _bearing_columns(config, topomap, descriptor, node_columns)
    belief, belief_setup = map_belief(topomap, config.belief)
    if belief is None and config.localiser.from_belief != "off":
        config = replace(config, localiser=replace(config.localiser, from_belief="off"))
        belief_setup += "; the robot places itself by the thresholded match instead (localiser.from_belief off)"
    navigator = Navigator(topomap.graph, node_ids, goal_node, config,
                          node_headings=navigation_headings(topomap, config.heading_source),
                          chooser=None if action_policy is None else PolicyChooser(),
                          arc_lengths_m=topomap.arc_lengths_m)
    distance = _Distance()
    heading = _Heading(config.heading_source)
    stall = _Stall(config) if config.recovery.enabled else None
    tracker = None if belief is None else BeliefTracker(belief)
    snapshot: Optional[BeliefSnapshot] = None
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
            bearings = None
            if columns_of is None:
                views = np.asarray(descriptor.describe_thirds([frame.rgb]), dtype=np.float32)[0]
            else:
                described, view_columns = descriptor.describe_with_columns([frame.rgb])
                views = np.asarray(described, dtype=np.float32)[0]
                bearings = _bearings(np.asarray(view_columns, dtype=np.float32)[0], columns_of)
            similarities = nodes @ views[0]
            goal_score = None if goal_view is None else float(goal_view @ views[0])
            policy = action_policy.for_frame(frame.rgb) if action_policy is not None else None
            describe_ms = _ms(t0)

            t0 = time.perf_counter()
            if tracker is not None:
                snapshot = tracker.step(frame.odometry, similarities)
            # (N, 3): every third against every node, one product (the contrast needs them all)
            thirds = nodes @ views[1:].T
            step = navigator.tick(similarities, thirds=thirds,
                                  thirds_contrast=contrast_thirds(thirds) if thirds_contrast else None,
                                  heading_rad=heading.update(frame), policy=policy, belief=snapshot,
                                  goal_score=goal_score, stalled=stall.update(frame) if stall else False,
                                  travelled_m=distance.update(frame), bearings=bearings)
            applied = base.apply(step.velocity)
            if stall is not None:
                stall.applied(applied, driving=step.state in DRIVING_STATES)
            decide_ms = _ms(t0)
            if step.planned_path and (not plans or plans[-1] != _plain(step.planned_path)):
                plans.append(_plain(step.planned_path))

            if step.finished:
                timings.append(StepTiming(read_ms, describe_ms, decide_ms, 0.0))
                _notify(observer, StepRecord(index, frame, step, applied, similarities, timings[-1],
                                             snapshot, goal_score))
                if navigator.planning_error is not None:
                    raise navigator.planning_error
                end = EpisodeEnd.ARRIVED if step.state is NavState.ARRIVED else EpisodeEnd.FAILED
                reason = step.reason
                break
            t0 = time.perf_counter()
            base.tick()
            timings.append(StepTiming(read_ms, describe_ms, decide_ms, _ms(t0)))
            abort = _notify(observer, StepRecord(index, frame, step, applied, similarities, timings[-1],
                                                 snapshot, goal_score))
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
        thresholds=config.thresholds, timings=tuple(timings), belief_setup=belief_setup)


def _bearing_columns(config: NavigationConfig, topomap: TopoMap, descriptor: Descriptor,
                     node_columns: Optional[np.ndarray]) -> Optional[dict]:
    """node id -> its column profile when ``navigation.bearing`` is on, else None; raises
    MapError for a map or descriptor without column profiles."""
    if not config.bearing.enabled:
        return None
    fix = "rebuild the map from its recording, or set navigation.bearing.enabled: false"
    if node_columns is None:
        raise MapError(f"navigation.bearing.enabled: the map has no column profiles (made before 2026-12-07, or "
                       f"with a descriptor that gives none); {fix}")
    if not has_columns(descriptor):
        raise MapError(f"navigation.bearing.enabled: the descriptor {descriptor.identity.backend!r} gives no "
                       f"column profiles; {fix}")
    columns = np.asarray(node_columns, dtype=np.float32)
    if columns.ndim != 3 or columns.shape[0] != len(topomap):
        raise MapError(f"node_columns must have shape ({len(topomap)}, W, C), got {columns.shape}")
    return {int(n): columns[k] for k, n in enumerate(topomap.node_ids.tolist())}


def _bearings(view: np.ndarray, columns_of: dict) -> Callable[[int], Optional[float]]:
    """``bearing(node)``: where the node's view lies in ``view`` (a fraction of its width,
    positive to the left); None for a profile of another width."""
    def bearing(node: int) -> Optional[float]:
        reference = columns_of.get(int(node))
        if reference is None or reference.shape != view.shape:
            return None
        return column_shift(view, reference)[0]
    return bearing


def _notify(observer: Optional[Observer], record: StepRecord) -> Optional[str]:
    return None if observer is None else observer(record)
