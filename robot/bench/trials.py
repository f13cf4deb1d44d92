"""Evaluation trials: what one navigation episode of the paper harness is, and running it.

A :class:`Trial` is plain data (it crosses process boundaries): world, route, method, map
folder, trial number, the start pose (the route's start plus a random offset), the appearance
seed and the route's shortest length. :func:`plan_trials` derives the offsets and appearance
seeds from one base seed with ``numpy.random.default_rng([seed, crc32(world/route), trial])``,
so a trial's conditions do not depend on which other routes or methods are run, and both
methods of a trial face the same start and the same conditions (paired comparison).

:func:`run_trial` runs one episode in the calling process; it caches the loaded world, map,
descriptor and baseline policy per process (``--workers`` processes each load them once).
Its result splits into the deterministic part (metrics, seeds, trajectory) and the wall-clock
part (``timing``): the same seeds give the same deterministic part, serial or parallel.
"""

from __future__ import annotations

import hashlib
import json
import math
import zlib
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

#: The paper's trial conditions: start offset up to 0.3 m and 15 degrees from the route start.
MAX_OFFSET_M = 0.3
MAX_OFFSET_YAW_DEG = 15.0
#: Appearance seeds of trials start here (the maps are built under appearance 0).
APPEARANCE_SEED_BASE = 1
#: Keep every n-th true pose in the results (trajectory plots); 10 = once per simulated second.
TRAJECTORY_EVERY = 10

#: The run folder's record of the configuration (:func:`write_run_config`).
RUN_CONFIG = "config.yaml"

#: "ours": the two-cycle voter with the configuration as given; "sptm": the learned baseline;
#: "paper": the paper's method as published (NavigationConfig.as_published, raw-cosine thirds);
#: "ours-hints" / "ours-no-hints": ours with the turn hints from the map's odometry forced on / off
#: (navigation.heading_hints; on in the default configuration), for the ablation.
METHODS = ("ours", "sptm", "paper", "ours-hints", "ours-no-hints")
#: What the harness runs unless --methods says otherwise (the paper's comparison).
DEFAULT_METHODS = ("ours", "sptm")


@dataclass(frozen=True)
class Trial:
    """One episode of the evaluation (plain values only: it is sent to worker processes)."""

    world: str                 # world name or path
    route: str
    method: str                # one of METHODS
    trial: int                 # 0-based trial number on this route
    map_dir: str
    appearance_seed: int
    start_x_m: float
    start_y_m: float
    start_yaw_deg: float
    offset_m: float            # distance of the start from the route's start
    offset_yaw_deg: float
    shortest_length_m: float   # the route's shortest length from this start (SPL)
    baseline_path: Optional[str] = None
    sparsity: Optional[float] = None   # the map's sparsity (the sparsity study)
    trace_png: Optional[str] = None
    config_digest: Optional[str] = None  # :func:`config_digest` of the stack config it ran with

    @property
    def key(self) -> str:
        sparsity = "" if self.sparsity is None else f"@{self.sparsity:g}"
        return f"{Path(self.world).stem}/{self.route}/{self.method}{sparsity}/{self.trial}"


def episode_path(out: Path, trial: Trial) -> Path:
    """Where a run in ``out`` keeps the trial's result (``episodes/<world>_<route>_<method>_<n>.json``)."""
    return Path(out) / "episodes" / (trial.key.replace("/", "_") + ".json")


def step_log_path(out: Path, trial: Trial) -> Path:
    """Where ``--step-logs`` (and a replay of the episode) writes the trial's per-step log."""
    return Path(out) / "replays" / (trial.key.replace("/", "_") + ".steps.jsonl")


#: the trial fields that name files; an episode file stores them relative to its run folder
PATH_FIELDS = ("map_dir", "trace_png", "baseline_path")


def portable_trial(trial: dict, run: Path) -> dict:
    """The trial (as a dict) with the paths inside the run folder ``run`` relative to it, so
    that a run folder can move (or be committed) and still be replayed; other paths stay."""
    fixed = dict(trial)
    for key in PATH_FIELDS:
        if fixed.get(key):
            try:
                fixed[key] = Path(fixed[key]).resolve().relative_to(Path(run).resolve()).as_posix()
            except ValueError:
                pass
    return fixed


def resolved_trial(trial: dict, run: Path) -> dict:
    """The inverse of :func:`portable_trial`: relative paths joined to the run folder."""
    fixed = dict(trial)
    for key in PATH_FIELDS:
        if fixed.get(key) and not Path(fixed[key]).is_absolute():
            fixed[key] = str(Path(run) / fixed[key])
    return fixed


def config_digest(config) -> str:
    """A short fingerprint of a stack configuration's values (not of its file): episodes record it,
    so that a run with another configuration (another ``--config``, or an edited default) does not
    reuse episodes made with the old one, and a replay can tell that the configuration changed."""
    text = json.dumps(asdict(config), sort_keys=True, default=repr)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def write_run_config(out: Path, config) -> Path:
    """Write the configuration a run's episodes run with into the run folder (``config.yaml``),
    every field resolved: a default changed later does not change what the run replays with."""
    import yaml

    from core.atomic import write_text

    header = ("# The configuration this run's episodes ran with, every field (written by python -m robot.bench "
              "paper;\n# python -m robot.bench replay reads it when no --config is given).\n")
    Path(out).mkdir(parents=True, exist_ok=True)
    return write_text(Path(out) / RUN_CONFIG, header + yaml.safe_dump(asdict(config), sort_keys=False))


def trial_rng(seed: int, world: str, route: str, trial: int) -> np.random.Generator:
    """The random generator of one trial's conditions (independent of the other routes)."""
    return np.random.default_rng([int(seed), zlib.crc32(f"{Path(world).stem}/{route}".encode()), int(trial)])


def plan_trials(world_spec, world: str, route: str, methods: Sequence[str], trials: int, seed: int,
                map_dir: str | Path, shortest_of, *, baseline_path: Optional[str] = None,
                sparsity: Optional[float] = None, trace_dir: Optional[Path] = None,
                config_digest: Optional[str] = None) -> list[Trial]:
    """The trials of one route: for each trial number a start offset (uniform in a disc of
    MAX_OFFSET_M, yaw uniform within MAX_OFFSET_YAW_DEG) and appearance seed
    ``APPEARANCE_SEED_BASE + trial``, the same for every method. ``shortest_of(x, y)`` gives the
    route's shortest length from a start position."""
    spec = world_spec.routes.evaluation[route]
    sx, sy, syaw = (float(v) for v in spec.start)
    out = []
    for t in range(trials):
        rng = trial_rng(seed, world, route, t)
        radius = MAX_OFFSET_M * math.sqrt(rng.uniform())
        angle = rng.uniform(0.0, 2.0 * math.pi)
        dyaw = rng.uniform(-MAX_OFFSET_YAW_DEG, MAX_OFFSET_YAW_DEG)
        x, y = sx + radius * math.cos(angle), sy + radius * math.sin(angle)
        shortest = round(float(shortest_of(x, y)), 4)
        for method in methods:
            trace = None
            if trace_dir is not None:
                tag = "" if sparsity is None else f"_s{sparsity:g}"
                trace = str(trace_dir / f"{Path(world).stem}_{route}_{method}{tag}_{t:02d}.png")
            out.append(Trial(world=world, route=route, method=method, trial=t, map_dir=str(map_dir),
                             appearance_seed=APPEARANCE_SEED_BASE + t, start_x_m=round(x, 4),
                             start_y_m=round(y, 4), start_yaw_deg=round(syaw + dyaw, 3),
                             offset_m=round(radius, 4), offset_yaw_deg=round(dyaw, 3),
                             shortest_length_m=shortest,
                             baseline_path=baseline_path if method == "sptm" else None,
                             sparsity=sparsity, trace_png=trace, config_digest=config_digest))
    return out


# -- running one trial (in whichever process) ---------------------------------------------------
_CACHE: dict = {}


def _cached(key, make):
    if key not in _CACHE:
        _CACHE[key] = make()
    return _CACHE[key]


def worker_init() -> None:
    """Every process that runs trials: one inference (ONNX Runtime or torch), BLAS and OpenCV
    thread, so that results do not depend on the number of workers (and N workers use N cores)."""
    import torch

    from descriptors.inference import set_threads
    from robot.threads import limit_helper_threads

    limit_helper_threads()
    torch.set_num_threads(1)            # the learned baseline's head and features run in torch
    set_threads(1)


def run_trial(trial: Trial, config_path: Optional[str] = None, *, config=None, step_log: Optional[str] = None,
              video_path: Optional[str] = None, viewer=None, progress: bool = False) -> dict:
    """Run one trial; returns ``{"trial": ..., "metrics": ..., "trajectory": ..., "timing": ...}``
    (``timing`` is the only wall-clock part). The stack configuration: ``config`` (a loaded
    :class:`robot.settings.StackConfig`), else the file at ``config_path`` read over
    ``configs/default.yaml``. ``step_log`` / ``video_path`` / ``viewer``: a per-step
    JSON-lines log, an MP4 with overlays and a :class:`robot.viewer.stream.ViewerTarget` (``python
    -m robot.bench replay``); none changes the run."""
    from controllers.localisation import GoalNotLocalisedError
    from controllers.planner import PlanningError
    from core.hal import Pose2D
    from descriptors.factory import make_descriptor
    from maps.store import load_map
    from robot.episode.sim import EpisodeOutputs, SimEpisode, run_sim_navigation
    from robot.settings import load_stack_config
    from sim.worlds import load_world

    if config is None:
        config = _cached(("config", config_path), lambda: load_stack_config(config_path))
    spec = _cached(("world", trial.world), lambda: load_world(trial.world))
    loaded = _cached(("map", trial.map_dir), lambda: load_map(trial.map_dir))
    descriptor = _cached(("descriptor", trial.map_dir),
                         lambda: make_descriptor(config.descriptor.backend, **config.descriptor.settings))
    policy = None
    if trial.method == "sptm":
        from robot.baseline import SptmPolicy, load_baseline

        head = _cached(("head", trial.baseline_path), lambda: load_baseline(trial.baseline_path))
        policy = _cached(("policy", trial.baseline_path, trial.map_dir), lambda: SptmPolicy(head, loaded))
    elif trial.method not in METHODS:
        raise ValueError(f"unknown method {trial.method!r} (methods: {', '.join(METHODS)})")
    navigation = config.navigation
    if trial.method in ("ours-hints", "ours-no-hints"):
        navigation = replace(navigation, heading_hints=trial.method == "ours-hints")
    if trial.method == "paper":      # as published: none of our additions, raw cosines for the voter
        navigation = navigation.as_published()
        config = replace(config, episode=replace(config.episode, thirds_contrast=False))
    start = Pose2D(trial.start_x_m, trial.start_y_m, math.radians(trial.start_yaw_deg))
    try:
        episode = SimEpisode(spec, trial.map_dir, route=trial.route, start=start,
                             appearance_seed=trial.appearance_seed, shortest_length_m=trial.shortest_length_m)
        outputs = EpisodeOutputs(trace_png=trial.trace_png, video_path=video_path, step_log=step_log,
                                 viewer=viewer, progress=progress)
        result = run_sim_navigation(episode, descriptor, replace(config, navigation=navigation), outputs,
                                    loaded_map=loaded, action_policy=policy)
    except (GoalNotLocalisedError, PlanningError) as exc:
        # the goal image matched no node, or the robot placed itself where no arc chain leads
        # to the goal (a wrong first localisation): a failed episode, not a broken run
        return _failed_before_driving(trial, spec, exc)
    metrics = result.metrics.to_dict()
    timing = {"wall_time_s": metrics.pop("wall_time_s"), "ms_per_step": metrics.pop("ms_per_step")}
    poses = result.true_poses
    keep = list(range(0, len(poses), TRAJECTORY_EVERY)) + ([len(poses) - 1] if len(poses) % TRAJECTORY_EVERY != 1 else [])
    trajectory = [[round(poses[i].x_m, 3), round(poses[i].y_m, 3)] for i in keep]
    record = {"trial": asdict(trial), "metrics": metrics, "goal_node": result.goal.node,
              "goal_rivals": list(result.goal.rivals), "trajectory": trajectory, "timing": timing}
    if step_log is not None:
        diagnosis = _diagnosis(step_log, trial, spec, result.goal.node)
        if diagnosis is not None:
            record["diagnosis"] = diagnosis
    return record


def _diagnosis(step_log: str, trial: Trial, spec, goal_node) -> Optional[dict]:
    """The episode's step log read against its map (:mod:`robot.bench.diagnosis`), for its record:
    the run's report counts wrong (re-)localisations from it where the logs are not at hand
    (they are not committed); None for a map without true node poses, or a log it cannot read
    against the map (the episode's result does not depend on it)."""
    from robot.bench.diagnosis import StepLogError, diagnose, map_node_poses, read_step_log, route_goal

    poses = _cached(("poses", trial.map_dir), lambda: map_node_poses(Path(trial.map_dir)))
    if poses is None:
        return None
    try:
        return diagnose(read_step_log(Path(step_log)), poses, route_goal(spec, trial.route, goal_node)).to_dict()
    except (StepLogError, KeyError):
        return None


def _failed_before_driving(trial: Trial, spec, exc: Exception) -> dict:
    """The record of an episode that ended with an error before or instead of driving to a goal
    (the robot was stopped where it stood: at its start)."""
    from robot.episode.metrics import EpisodeMetrics

    goal = spec.routes.evaluation[trial.route].goal
    distance = round(math.dist((trial.start_x_m, trial.start_y_m), goal[:2]), 4)
    metrics = {name: None for name in EpisodeMetrics.__dataclass_fields__}
    metrics.update(success=False, success_0_5m=False, arrived=False, end="error",
                   reason=f"{type(exc).__name__}: {exc}", final_distance_m=distance, path_length_m=0.0,
                   shortest_length_m=trial.shortest_length_m, spl=0.0, steps=0, sim_time_s=0.0,
                   relocalisations=0, replans=0, collisions=0, toppled=False, planned_nodes=[], plans=[],
                   visited_nodes=[], thresholds={})
    timing = {"wall_time_s": metrics.pop("wall_time_s"), "ms_per_step": {
        k: 0.0 for k in ("read_ms", "describe_ms", "decide_ms", "tick_ms", "total_ms", "total_p95_ms")}}
    metrics.pop("ms_per_step")
    timing["wall_time_s"] = 0.0
    return {"trial": asdict(trial), "metrics": metrics, "goal_node": None,
            "trajectory": [[trial.start_x_m, trial.start_y_m]], "timing": timing}
