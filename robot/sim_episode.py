"""One navigation episode in the simulator: set up the world and the Limo, run the loop, measure.

:func:`run_sim_navigation` is what ``python -m robot.run --mode navigate`` calls in simulation:

1. load the world and the map; attach the descriptor in use to the map (refused when the map
   was built with another one); derive the thresholds from the map (or take them as written);
2. place the simulated Limo at the start: a route's start, an explicit ``x,y,yaw`` pose, or a
   map node's true pose (a *kidnapped* start, far from where the route begins);
3. the goal: a node id, a goal image file, or - with a route and no explicit goal - the image
   the camera sees at the route's goal pose. That image is rendered by the same simulated Limo
   before the episode: it is connected at the goal pose, one frame is read, then it is
   teleported to the start at rest (one world build instead of two; the goal picture is taken
   under the episode's appearance seed, as a user would photograph the place that day);
4. run :func:`robot.navigation.run_episode` with an observer that records the true poses (for
   metrics and the trace only; the controller never sees them), aborts when the robot topples,
   and feeds the optional video;
5. compute :class:`robot.episode_metrics.EpisodeMetrics`, write the ``--result`` JSON, the trace
   picture and the video.

The goal position for success is the route's goal pose when the goal is the route's, otherwise
the true pose of the goal node (the place the map knows for that node).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Union

import numpy as np
from tqdm import tqdm

from controllers.config import NavigationConfig
from maps.store import LoadedMap, load_map
from robot.descriptors.base import Descriptor
from robot.episode_metrics import SUCCESS_RADIUS_M, EpisodeMetrics, compute_metrics, format_summary
from robot.hal import Pose2D
from robot.navigation import (ActionPolicy, EpisodeConfig, EpisodeOutcome, ResolvedGoal, StepRecord, attach_descriptor,
                              configure_thresholds, parse_goal, read_goal_image, resolve_goal, run_episode,
                              step_budget)
from robot.navigation_pictures import NavigationVideo, draw_trace
from sim.hal import SimConfig, SimLimo
from sim.topdown import render_topdown
from sim.world_spec import WorldSpec, load_world


class StartError(ValueError):
    """A start that cannot be used (unknown route, malformed pose, node without a true pose)."""


StartSpec = Union[str, Pose2D, int, None]
GoalArg = Union[int, str, Path, np.ndarray, None]


def parse_start(text: str) -> Union[str, Pose2D, int]:
    """A command-line start: ``x,y,yaw_deg`` (metres, degrees), ``node:ID`` (a map node's true
    pose: a kidnapped start) or a route name (that route's start)."""
    text = str(text).strip()
    if text.startswith("node:"):
        ident = text[5:].strip()
        if not ident.lstrip("-").isdigit():
            raise StartError(f"--start {text!r}: expected node:ID with an integer ID")
        return int(ident)
    if "," in text:
        parts = text.split(",")
        try:
            values = [float(p) for p in parts]
        except ValueError:
            values = []
        if len(values) != 3 or not all(math.isfinite(v) for v in values):
            raise StartError(f"--start {text!r}: expected x,y,yaw_deg (three numbers, metres and degrees)")
        return Pose2D(values[0], values[1], math.radians(values[2]))
    if not text:
        raise StartError("--start is empty: give a route name, x,y,yaw_deg or node:ID")
    return text


def _route(world: WorldSpec, name: str, what: str):
    routes = world.routes.evaluation
    if name not in routes:
        raise StartError(f"{what} {name!r}: world {world.name!r} has no such route "
                         f"(routes: {', '.join(sorted(routes)) or 'none'})")
    return routes[name]


def route_pose(xy_yaw_deg) -> Pose2D:
    """A world-file pose (x_m, y_m, yaw_deg) as a Pose2D (radians)."""
    x, y, yaw_deg = xy_yaw_deg
    return Pose2D(float(x), float(y), math.radians(float(yaw_deg)))


def resolve_start(world: WorldSpec, loaded_map: LoadedMap, start: StartSpec,
                  route: Optional[str] = None) -> tuple[Pose2D, str]:
    """The start pose and a label for it; ``start`` None means the route's start."""
    if start is None:
        if route is None:
            raise StartError("no start: give --start (route name, x,y,yaw_deg or node:ID) or --route")
        return route_pose(_route(world, route, "--route").start), f"start of route {route}"
    if isinstance(start, Pose2D):
        return start, f"pose ({start.x_m:.2f}, {start.y_m:.2f}, {math.degrees(start.yaw_rad):.0f} deg)"
    if isinstance(start, int) and not isinstance(start, bool):
        if start not in loaded_map.topomap:
            raise StartError(f"--start node:{start}: the map {loaded_map.path} has no node {start}")
        pose = loaded_map.topomap.node(start).true_pose
        if pose is None:
            raise StartError(f"--start node:{start}: the map {loaded_map.path} has no true poses "
                             "(not a simulator map); give x,y,yaw_deg instead")
        return pose, f"node {start} (kidnapped)"
    if isinstance(start, str):
        return route_pose(_route(world, start, "--start").start), f"start of route {start}"
    raise StartError(f"start {start!r}: expected a route name, a Pose2D or a node id")


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


def step_log_entry(record: StepRecord, pose: Pose2D, node_ids: np.ndarray) -> dict:
    """One line of the step log: the true pose after the step, what the navigator decided, and
    the node the raw view matched best (``node_ids``: the similarity row's order)."""
    s = record.step
    sims = record.similarities
    best = int(np.argmax(sims))

    def r3(v):
        return None if v is None else round(float(v), 3)
    return {"step": record.index, "x_m": round(pose.x_m, 3), "y_m": round(pose.y_m, 3),
            "yaw_deg": round(math.degrees(pose.yaw_rad), 1), "state": s.state.value, "action": s.action.value,
            "current_node": s.current_node, "target_node": s.target_node,
            "current_score": r3(s.current_score), "target_score": r3(s.target_score),
            "thirds": None if s.thirds is None else [r3(s.thirds.left), r3(s.thirds.middle), r3(s.thirds.right)],
            "vote_scores": None if s.vote is None or s.vote.scores is None else
            [r3(s.vote.scores.left), r3(s.vote.scores.middle), r3(s.vote.scores.right)],
            "best_raw_node": int(node_ids[best]), "best_raw_score": r3(sims[best]),
            "relocalisations": s.relocalisations, "reason": s.reason}


class _StepLog:
    """The step log (JSON lines), written to a temporary file and moved into place at the end,
    whatever the end (so a crash leaves the log of the steps made, never a half-written line)."""

    def __init__(self, path: Path, node_ids: np.ndarray):
        self.node_ids = node_ids
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = self.path.with_name(f".{self.path.name}.tmp-{os.getpid()}")
        self.file = self.tmp.open("w", encoding="utf-8")

    def write(self, entry: dict) -> None:
        self.file.write(json.dumps(entry) + "\n")

    def close(self) -> None:
        self.file.close()
        os.replace(self.tmp, self.path)


class _TruthRecorder:
    """The observer: records true poses, aborts on toppling, feeds the video, the step log and
    the progress bar."""

    def __init__(self, base: SimLimo, video: Optional[NavigationVideo], bar: Optional[tqdm],
                 log: Optional[_StepLog] = None):
        self.truth = base.ground_truth
        self.poses: list[Pose2D] = [self.truth.true_pose()]
        self.video = video
        self.bar = bar
        self.log = log

    def __call__(self, record: StepRecord) -> Optional[str]:
        pose = self.truth.true_pose()
        self.poses.append(pose)
        if self.log is not None:
            self.log.write(step_log_entry(record, pose, self.log.node_ids))
        if self.video is not None:
            self.video.add(record.frame.rgb, record.step, record.frame.stamp_s)
        if self.bar is not None:
            s = record.step
            self.bar.update(1)
            if record.index % 10 == 0:
                self.bar.set_postfix_str(f"{s.state.value} node {s.current_node}->{s.target_node} "
                                         f"{s.action.value}", refresh=False)
        if self.truth.toppled():
            return f"the robot toppled at x={pose.x_m:.2f}, y={pose.y_m:.2f}"
        return None


def _write_json(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _pose_dict(p: Optional[Pose2D]) -> Optional[dict]:
    return None if p is None else {"x_m": round(p.x_m, 4), "y_m": round(p.y_m, 4),
                                   "yaw_deg": round(math.degrees(p.yaw_rad), 2)}


def run_sim_navigation(world: Union[str, Path, WorldSpec], map_dir: Union[str, Path], descriptor: Descriptor, *,
                       goal: GoalArg = None, route: Optional[str] = None, start: StartSpec = None,
                       appearance_seed: int = 0, sim_config: SimConfig = SimConfig(),
                       navigation: NavigationConfig = NavigationConfig(),
                       episode: EpisodeConfig = EpisodeConfig(), max_steps: Optional[int] = None,
                       result_path: Optional[Union[str, Path]] = None,
                       trace_png: Optional[Union[str, Path]] = None,
                       video_path: Optional[Union[str, Path]] = None,
                       progress: bool = True,
                       loaded_map: Optional[LoadedMap] = None,
                       shortest_length_m: Optional[float] = None,
                       on_setup: Optional[Callable[[dict], None]] = None,
                       make_base: Optional[Callable[..., SimLimo]] = None,
                       action_policy: Optional[ActionPolicy] = None,
                       step_log: Optional[Union[str, Path]] = None) -> SimNavigationResult:
    """Run one navigation episode in the simulator; see the module docstring.

    ``world``: a world name, path or spec. ``map_dir``: the map folder. ``descriptor``: the
    descriptor the configuration asks for (its vocabulary is loaded from the map).
    ``goal``: node id, image path (or the text of ``--goal``) or RGB array; None with ``route``:
    the image at the route's goal pose. ``start``: route name, Pose2D, node id (kidnapped), or
    None for the route's start. ``max_steps``: the step budget (default from ``episode`` and the
    route length). ``result_path``: JSON with the metrics and the setup; ``trace_png``: the
    top-down trace; ``video_path``: the MP4 with overlays. ``loaded_map``: an already loaded map
    (saves reloading it over many trials). ``shortest_length_m``: the shortest route length for
    SPL; by default the route's ``length_m`` when the episode starts at the route's start and
    goes to its goal, else unknown (SPL None). ``make_base(config, start, world, appearance_seed)``:
    the simulated base (default :class:`sim.hal.SimLimo`; :class:`sim.serial_twin.SerialTwinLimo`
    drives the same body through the serial backend); it must offer ``ground_truth``.
    ``action_policy``: a learned policy choosing the actions instead of the voter (the baseline).
    ``step_log``: a JSON-lines file with one line per step (:func:`step_log_entry`: true pose,
    state, action, nodes, scores, reason) for looking into an episode.

    Raises: ``maps.graph.MapError`` (bad map folder), :class:`robot.navigation.DescriptorMismatchError`,
    :class:`StartError`, ``WorldError``, :class:`robot.navigation.GoalImageError`,
    ``controllers.localisation.GoalNotLocalisedError``, ``controllers.planner.UnknownNodeError``,
    ``controllers.planner.UnreachableGoalError``, ``HalError``; the robot is stopped on every way
    out, Ctrl-C (KeyboardInterrupt, re-raised) included.
    """
    spec = world if isinstance(world, WorldSpec) else load_world(world)
    loaded = loaded_map if loaded_map is not None else load_map(map_dir)
    attach_descriptor(loaded, descriptor)
    nav_config = configure_thresholds(loaded, navigation, episode)
    if isinstance(goal, str):
        goal = parse_goal(goal)
    if goal is None and route is None:
        raise StartError("no goal: give --goal (node id or image file) or --route")
    start_pose, start_label = resolve_start(spec, loaded, start, route)
    route_spec = _route(spec, route, "--route") if route is not None else None

    goal_pose: Optional[Pose2D] = None
    goal_image: Optional[np.ndarray] = None
    shortest: Optional[float] = None
    resolved: Optional[ResolvedGoal] = None
    if goal is None:                         # the route's goal, as an image rendered there
        goal_pose = route_pose(route_spec.goal)
        if start is None or start == route:
            shortest = float(route_spec.length_m)
        goal_source = f"image at the goal of route {route}"
    elif isinstance(goal, Path):
        goal_image = read_goal_image(goal)   # an unreadable file fails before the robot moves
        goal_source = f"image {goal}"
    else:
        goal_source = "node id" if isinstance(goal, (int, np.integer)) else "image"
        if not isinstance(goal, (int, np.integer)):
            goal_image = np.asarray(goal)
        else:                                 # a bad node id fails before the robot moves
            resolved = resolve_goal(int(goal), loaded.topomap, descriptor, nav_config.thresholds)

    shortest = shortest_length_m if shortest_length_m is not None else shortest
    budget = max_steps if max_steps is not None else step_budget(
        episode, nav_config, sim_config.control_period_s,
        shortest if shortest is not None else None)
    base = (make_base or SimLimo)(sim_config, start=goal_pose if goal is None else start_pose, world=spec,
                                  appearance_seed=appearance_seed)
    video = NavigationVideo(video_path, loaded.thumbnail, fps=1.0 / sim_config.control_period_s) \
        if video_path is not None else None
    bar = tqdm(total=budget, unit="step", desc="navigating", disable=not progress, leave=False)
    log = _StepLog(step_log, loaded.topomap.node_ids) if step_log is not None else None
    try:
        with base:
            truth = base.ground_truth
            if goal is None:
                goal_image = base.read().rgb
                truth.teleport(start_pose)
            if resolved is None:
                resolved = resolve_goal(goal_image, loaded.topomap, descriptor, nav_config.thresholds)
            if goal_pose is None:
                goal_pose = loaded.topomap.node(resolved.node).true_pose
            setup = {
                "world": spec.name, "map": str(loaded.path), "route": route, "start": start_label,
                "start_pose": _pose_dict(start_pose), "goal": goal_source, "goal_node": resolved.node,
                "goal_match": None if resolved.localisation is None else round(resolved.localisation.best_score, 4),
                "goal_pose": _pose_dict(goal_pose), "goal_rivals": list(resolved.rivals), "appearance_seed": appearance_seed,
                "sim_seed": sim_config.seed, "max_steps": budget, "success_radius_m": SUCCESS_RADIUS_M,
                "thresholds_from_map": episode.thresholds_from_map,
                "descriptor": loaded.identity.backend,
                "method": "voter" if action_policy is None else action_policy.name,
            }
            if on_setup is not None:
                on_setup(setup)
            collisions_before = truth.collision_count()
            recorder = _TruthRecorder(base, video, bar, log)
            outcome = run_episode(base, loaded.topomap, descriptor, resolved.node, nav_config, budget,
                                  observer=recorder, thirds_contrast=episode.thirds_contrast,
                                  action_policy=action_policy)
            collisions = truth.collision_count() - collisions_before
            toppled = truth.toppled()
    finally:
        bar.close()
        if video is not None:
            video.close()
        if log is not None:
            log.close()

    metrics = compute_metrics(outcome, recorder.poses, goal_pose, shortest, collisions, toppled)
    summary = format_summary(metrics)
    if result_path is not None:
        _write_json(Path(result_path), {**metrics.to_dict(), "setup": setup})
    if trace_png is not None:
        picture = render_topdown(spec, appearance_seed=appearance_seed, show_routes=False)
        verdict = "success" if metrics.success else ("arrived" if metrics.arrived else metrics.end)
        dist = f", {metrics.final_distance_m:.2f} m from goal" if metrics.final_distance_m is not None else ""
        draw_trace(picture, loaded.topomap, recorder.poses, plans=outcome.plans, visited=outcome.visited_nodes,
                   start=start_pose, goal=goal_pose, goal_node=resolved.node,
                   title=f"{spec.name} {route or ''}: {verdict}{dist}").save_png(trace_png)
    return SimNavigationResult(metrics=metrics, outcome=outcome, start_pose=start_pose, goal_pose=goal_pose,
                               goal=resolved, setup=setup, summary=summary,
                               true_poses=tuple(recorder.poses))
