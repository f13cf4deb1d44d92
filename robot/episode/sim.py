"""One navigation episode in the simulator: set up the world and the Limo, run the loop, measure.

:func:`run_sim_navigation` is what ``python -m robot.run --mode navigate`` calls in simulation
(and what the paper harness runs for every trial):

1. load the world and the map; attach the descriptor in use to the map (refused when the map
   was built with another one); derive the thresholds from the map (or take them as written);
2. place the simulated Limo at the start (:mod:`robot.episode.start`);
3. the goal: a node id, a goal image file, or - with a route and no explicit goal - the image
   the camera sees at the route's goal pose. That image is rendered by the same simulated Limo
   before the episode: it is connected at the goal pose, one frame is read, then it is
   teleported to the start at rest (one world build instead of two; the goal picture is taken
   under the episode's appearance seed, as a user would photograph the place that day);
4. run :func:`robot.episode.loop.run_episode` with an observer that records the true poses (for
   metrics and the trace only; the controller never sees them), aborts when the robot topples,
   and feeds the optional video and viewer (:mod:`robot.viewer`);
5. compute :class:`robot.episode.metrics.EpisodeMetrics`, write the ``--result`` JSON, the trace
   picture, the video and the step log (:class:`EpisodeOutputs`).

The goal position for success is the route's goal pose when the goal is the route's, otherwise
the true pose of the goal node (the place the map knows for that node).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Union

import numpy as np
from tqdm import tqdm

from controllers.config import NavigationConfig
from core.atomic import write_json
from core.hal import Pose2D
from descriptors.base import Descriptor
from maps.store import LoadedMap, load_map
from robot.episode.config import step_budget
from robot.episode.goal import ResolvedGoal, parse_goal, read_goal_image, resolve_goal
from robot.episode.loop import ActionPolicy, EpisodeOutcome, StepRecord, run_episode
from robot.episode.metrics import SUCCESS_RADIUS_M, EpisodeMetrics, compute_metrics, format_summary
from robot.episode.pictures import NavigationVideo, draw_trace
from robot.episode.setup import attach_descriptor, configure_navigation
from robot.episode.start import StartError, StartSpec, resolve_start, route_of, route_pose
from robot.episode.step_log import StepLog
from robot.settings import StackConfig
from robot.viewer.navigation import NavigationLogger, navigation_viewer
from robot.viewer.stream import ViewerTarget
from sim.hal import SimLimo
from sim.topdown import render_topdown
from sim.world_spec import WorldSpec
from sim.worlds import load_world

GoalArg = Union[int, str, Path, np.ndarray, None]
#: ``make_base(sim_config, start, world, appearance_seed)``: a simulated base with ``ground_truth``
MakeBase = Callable[..., SimLimo]


@dataclass(frozen=True)
class SimEpisode:
    """What to run: the world, the map, where to start and where to go.

    ``goal``: node id, image path (or the text of ``--goal``) or RGB array; None with ``route``:
    the image at the route's goal pose. ``start``: route name, Pose2D, node id (kidnapped), or
    None for the route's start. ``max_steps``: the step budget (default from the ``episode``
    config and the route length). ``shortest_length_m``: the shortest route length for SPL; by
    default the route's ``length_m`` when the episode starts at the route's start and goes to its
    goal, else unknown (SPL None).
    """

    world: Union[str, Path, WorldSpec]
    map_dir: Union[str, Path]
    goal: GoalArg = None
    route: Optional[str] = None
    start: StartSpec = None
    appearance_seed: int = 0
    max_steps: Optional[int] = None
    shortest_length_m: Optional[float] = None


@dataclass(frozen=True)
class EpisodeOutputs:
    """What to write: ``result_path`` (JSON with the metrics and the setup), ``trace_png`` (the
    top-down trace), ``video_path`` (MP4 with overlays), ``step_log`` (JSON lines, one per step:
    :mod:`robot.episode.step_log`); ``viewer``: the Rerun viewer or ``.rrd`` file the episode
    streams to (:mod:`robot.viewer`); ``progress``: a progress bar on the terminal."""

    result_path: Optional[Union[str, Path]] = None
    trace_png: Optional[Union[str, Path]] = None
    video_path: Optional[Union[str, Path]] = None
    step_log: Optional[Union[str, Path]] = None
    viewer: Optional[ViewerTarget] = None
    progress: bool = True


@dataclass(frozen=True)
class SimNavigationResult:
    """What one simulated episode produced."""

    metrics: EpisodeMetrics
    outcome: EpisodeOutcome
    start_pose: Pose2D
    goal_pose: Optional[Pose2D]
    goal: ResolvedGoal
    setup: dict
    summary: str                      # the human summary (format_summary)
    true_poses: tuple[Pose2D, ...] = ()  # the true pose at every step, start and end included
    viewer_step_ms: tuple[float, ...] = ()  # what logging each step to the viewer took (ms), if any


@dataclass(frozen=True)
class _GoalPlan:
    """The goal before the robot is placed: the pose success is measured at (when known yet),
    the goal image (when given as one), or the node (when given as an id)."""

    source: str
    pose: Optional[Pose2D] = None
    image: Optional[np.ndarray] = None
    resolved: Optional[ResolvedGoal] = None
    from_route: bool = False
    shortest_m: Optional[float] = None


class _TruthRecorder:
    """The observer: records true poses, aborts on toppling, feeds the video, the step log, the
    viewer and the progress bar."""

    def __init__(self, base: SimLimo, video: Optional[NavigationVideo], bar: Optional[tqdm],
                 log: Optional[StepLog] = None, viewer: Optional[NavigationLogger] = None):
        self.truth = base.ground_truth
        self.poses: list[Pose2D] = [self.truth.true_pose()]
        self._collisions_before = self.truth.collision_count()
        self.video = video
        self.bar = bar
        self.log = log
        self.viewer = viewer

    def __call__(self, record: StepRecord) -> Optional[str]:
        pose = self.truth.true_pose()
        self.poses.append(pose)
        if self.log is not None:
            self.log.write(record, pose, self.truth.collision_count() - self._collisions_before)
        if self.video is not None:
            self.video.add(record.frame.rgb, record.step, record.frame.stamp_s)
        if self.viewer is not None:
            self.viewer.step(record, pose)
        if self.bar is not None:
            s = record.step
            self.bar.update(1)
            if record.index % 10 == 0:
                self.bar.set_postfix_str(f"{s.state.value} node {s.current_node}->{s.target_node} "
                                         f"{s.action.value}", refresh=False)
        if self.truth.toppled():
            return f"the robot toppled at x={pose.x_m:.2f}, y={pose.y_m:.2f}"
        return None


def _pose_dict(p: Optional[Pose2D]) -> Optional[dict]:
    return None if p is None else {"x_m": round(p.x_m, 4), "y_m": round(p.y_m, 4),
                                   "yaw_deg": round(math.degrees(p.yaw_rad), 2)}


def _plan_goal(episode: SimEpisode, spec: WorldSpec, loaded: LoadedMap, descriptor: Descriptor,
               navigation: NavigationConfig) -> _GoalPlan:
    """What the goal is, checked before the robot moves (a bad node id or an unreadable image
    file fails here)."""
    goal = parse_goal(episode.goal) if isinstance(episode.goal, str) else episode.goal
    if episode.route is not None:
        route_of(spec, episode.route, "--route")       # an unknown route fails before the robot moves
    if goal is None:                          # the route's goal, as an image rendered there
        route = route_of(spec, episode.route, "--route")
        starts_at_route = episode.start is None or episode.start == episode.route
        return _GoalPlan(source=f"image at the goal of route {episode.route}", pose=route_pose(route.goal),
                         from_route=True, shortest_m=float(route.length_m) if starts_at_route else None)
    if isinstance(goal, Path):
        return _GoalPlan(source=f"image {goal}", image=read_goal_image(goal))
    if isinstance(goal, (int, np.integer)):
        return _GoalPlan(source="node id", resolved=resolve_goal(int(goal), loaded.topomap, descriptor,
                                                                navigation))
    return _GoalPlan(source="image", image=np.asarray(goal))


def run_sim_navigation(episode: SimEpisode, descriptor: Descriptor, config: StackConfig = StackConfig(),
                       outputs: EpisodeOutputs = EpisodeOutputs(), *, loaded_map: Optional[LoadedMap] = None,
                       make_base: Optional[MakeBase] = None,
                       action_policy: Optional[ActionPolicy] = None) -> SimNavigationResult:
    """Run one navigation episode in the simulator; see the module docstring.

    ``descriptor``: the descriptor the configuration asks for (its vocabulary is loaded from the
    map). ``config``: the stack configuration (its ``sim``, ``navigation`` and ``episode``
    sections are used). ``loaded_map``: an already loaded map (saves reloading it over many
    trials). ``make_base(sim_config, start, world, appearance_seed)``: the simulated base (default
    :class:`sim.hal.SimLimo`; :class:`sim.serial_twin.SerialTwinLimo` drives the same body
    through the serial backend); it must offer ``ground_truth``. ``action_policy``: a learned
    policy choosing the actions instead of the voter (the baseline).

    Raises: ``maps.graph.MapError`` (bad map folder), :class:`robot.episode.setup.DescriptorMismatchError`,
    :class:`StartError`, ``WorldError``, :class:`robot.episode.goal.GoalImageError`,
    ``controllers.localisation.GoalNotLocalisedError``, ``controllers.planner.UnknownNodeError``,
    ``controllers.planner.UnreachableGoalError``, ``HalError``; the robot is stopped on every way
    out, Ctrl-C (KeyboardInterrupt, re-raised) included.
    """
    sim_config = config.sim
    spec = episode.world if isinstance(episode.world, WorldSpec) else load_world(episode.world)
    loaded = loaded_map if loaded_map is not None else load_map(episode.map_dir)
    attach_descriptor(loaded, descriptor)
    nav_config = configure_navigation(loaded, config.navigation, config.episode)
    if episode.goal is None and episode.route is None:
        raise StartError("no goal: give --goal (node id or image file) or --route")
    start_pose, start_label = resolve_start(spec, loaded, episode.start, episode.route)
    plan = _plan_goal(episode, spec, loaded, descriptor, nav_config)
    shortest = episode.shortest_length_m if episode.shortest_length_m is not None else plan.shortest_m
    budget = episode.max_steps if episode.max_steps is not None else step_budget(
        config.episode, nav_config, sim_config.control_period_s, shortest)

    base = (make_base or SimLimo)(sim_config, start=plan.pose if plan.from_route else start_pose, world=spec,
                                  appearance_seed=episode.appearance_seed)
    video = NavigationVideo(outputs.video_path, loaded.thumbnail, fps=1.0 / sim_config.control_period_s) \
        if outputs.video_path is not None else None
    bar = tqdm(total=budget, unit="step", desc="navigating", disable=not outputs.progress, leave=False)
    log = StepLog(outputs.step_log, loaded.topomap.node_ids) if outputs.step_log is not None else None
    closing = contextlib.ExitStack()
    viewer = closing.enter_context(navigation_viewer(outputs.viewer, f"navigate {spec.name} {episode.route or ''}"
                                                     .strip(), loaded.topomap))
    try:
        with base:
            truth = base.ground_truth
            goal_image = plan.image
            if plan.from_route:
                goal_image = base.read().rgb
                truth.teleport(start_pose)
            resolved = plan.resolved or resolve_goal(goal_image, loaded.topomap, descriptor, nav_config)
            goal_pose = plan.pose if plan.pose is not None else loaded.topomap.node(resolved.node).true_pose
            setup = {
                "world": spec.name, "map": str(loaded.path), "route": episode.route, "start": start_label,
                "start_pose": _pose_dict(start_pose), "goal": plan.source, "goal_node": resolved.node,
                "goal_match": None if resolved.localisation is None else round(resolved.localisation.best_score, 4),
                "goal_pose": _pose_dict(goal_pose), "goal_rivals": list(resolved.rivals),
                "appearance_seed": episode.appearance_seed, "sim_seed": sim_config.seed, "max_steps": budget,
                "success_radius_m": SUCCESS_RADIUS_M, "thresholds_from_map": config.episode.thresholds_from_map,
                "descriptor": loaded.identity.backend,
                "method": ("bearing" if nav_config.bearing.enabled else "voter") if action_policy is None
                else action_policy.name,
            }
            collisions_before = truth.collision_count()
            if viewer is not None:
                viewer.setup(resolved.node, goal_image, plan.source, start_pose, goal_pose)
            recorder = _TruthRecorder(base, video, bar, log, viewer)
            outcome = run_episode(base, loaded.topomap, descriptor, resolved.node, nav_config, budget,
                                  observer=recorder, thirds_contrast=config.episode.thirds_contrast,
                                  action_policy=action_policy, goal_descriptor=resolved.descriptor,
                                  node_columns=loaded.columns)
            collisions = truth.collision_count() - collisions_before
            toppled = truth.toppled()
    finally:
        bar.close()
        if video is not None:
            video.close()
        if log is not None:
            log.close()
        closing.close()

    metrics = compute_metrics(outcome, recorder.poses, goal_pose, shortest, collisions, toppled)
    if outputs.result_path is not None:
        write_json(outputs.result_path, {**metrics.to_dict(), "setup": setup})
    if outputs.trace_png is not None:
        _draw_trace(outputs.trace_png, spec, episode, loaded, recorder.poses, outcome, start_pose, goal_pose,
                    resolved.node, metrics)
    return SimNavigationResult(metrics=metrics, outcome=outcome, start_pose=start_pose, goal_pose=goal_pose,
                               goal=resolved, setup=setup, summary=format_summary(metrics),
                               true_poses=tuple(recorder.poses),
                               viewer_step_ms=tuple(viewer.step_ms) if viewer is not None else ())


def _draw_trace(path, spec: WorldSpec, episode: SimEpisode, loaded: LoadedMap, poses, outcome: EpisodeOutcome,
                start_pose: Pose2D, goal_pose: Optional[Pose2D], goal_node: int, metrics: EpisodeMetrics) -> None:
    picture = render_topdown(spec, appearance_seed=episode.appearance_seed, show_routes=False)
    verdict = "success" if metrics.success else ("arrived" if metrics.arrived else metrics.end)
    dist = f", {metrics.final_distance_m:.2f} m from goal" if metrics.final_distance_m is not None else ""
    draw_trace(picture, loaded.topomap, poses, plans=outcome.plans, visited=outcome.visited_nodes,
               start=start_pose, goal=goal_pose, goal_node=goal_node,
               title=f"{spec.name} {episode.route or ''}: {verdict}{dist}").save_png(path)
