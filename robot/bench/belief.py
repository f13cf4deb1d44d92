"""Run the belief filter over recorded episodes, offline, and judge it against the true poses.

``python -m robot.bench belief RUN/episodes/hospital_easy_ours_*.json --set heading_bins=1,8``
reads, for each episode, what a replay recorded (``python -m robot.bench replay`` writes the
step log and, beside it, the views: the view's similarity to every node and the odometry at
every step, :mod:`robot.episode.step_log`), runs the filter of :mod:`controllers.belief` over
them with the configuration's ``navigation.belief`` section, once per combination of the
``--set`` values, and judges its mode at every step by the step-log diagnosis's rule
(:mod:`robot.bench.diagnosis`: more than 3 m from the robot, or more than 1 m and facing 30 deg
away, is a wrong place). The filter does not steer yet, so the views are the same whatever its
settings, and a sweep over 20 episodes takes seconds instead of a simulator hour.

Per setting it prints: the steps whose mode was at the right place, and how far the mode's
node lay from the robot (median and 90th percentile over steps); the steps where the belief
was confident (mass near the mode at least ``confidence``) and how many of those were right
(what a navigator acting on the belief would have trusted); at the navigator's
(re-)localisations, how often it and the belief were wrong; and from the start, the first
confident mode of every episode (right or wrong, and when).

Iterate here on the worlds you develop on; never on the ones you report as held out.
Exit status: 0 done, 2 bad input (the file, option or value named).
"""

from __future__ import annotations

import argparse
import itertools
import statistics
import sys
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from controllers.config import BeliefConfig


class BeliefBenchError(ValueError):
    """Bad input to the offline belief run (names the file, option or value)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("episodes", type=Path, nargs="+",
                        help="episode files of a paper run (RUN/episodes/<episode>.json), replayed with step logs")
    parser.add_argument("--config", type=Path, default=None,
                        help="stack configuration (YAML); its navigation.belief section is the starting point")
    parser.add_argument("--set", dest="settings", action="append", default=[], metavar="FIELD=V1[,V2...]",
                        help="a navigation.belief field and the values to try (repeatable; every combination runs)")
    parser.add_argument("--json", type=Path, default=None, help="also write the table as JSON here")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


@dataclass(frozen=True)
class Recorded:
    """One replayed episode: its name, map, node poses, steps and views."""

    name: str
    topomap: object
    poses: dict
    steps: list
    similarities: np.ndarray
    odometry: np.ndarray


def sweep(base: BeliefConfig, settings: Sequence[str]) -> list[BeliefConfig]:
    """Every combination of the ``FIELD=V1,V2`` settings applied to ``base`` (in the order given)."""
    known = {f.name: f for f in fields(BeliefConfig)}
    axes = []
    for text in settings:
        name, sep, values = text.partition("=")
        name = name.strip()
        if not sep or not values.strip():
            raise BeliefBenchError(f"--set {text!r}: expected FIELD=VALUE[,VALUE...]")
        if name not in known:
            raise BeliefBenchError(f"--set {text!r}: navigation.belief has no field {name!r} "
                                   f"(fields: {', '.join(known)})")
        kind = type(getattr(base, name))
        parsed = []
        for v in values.split(","):
            try:
                parsed.append(kind(v.strip()))
            except ValueError:
                raise BeliefBenchError(f"--set {text!r}: {v.strip()!r} is not a valid {kind.__name__}") from None
        axes.append([(name, v) for v in parsed])
    configs = []
    for combo in itertools.product(*axes):
        try:
            configs.append(replace(base, **dict(combo)))
        except ValueError as exc:
            raise BeliefBenchError(f"--set {', '.join(f'{k}={v}' for k, v in combo)}: {exc}") from None
    return configs


def load_recorded(episode: Path, config, progress: bool) -> Recorded:
    """An episode's map, node poses, step log and views; raises :class:`BeliefBenchError`."""
    from maps.graph import MapError
    from maps.store import load_map
    from robot.bench.diagnosis import StepLogError, map_node_poses, read_step_log
    from robot.bench.replay import ReplayError, load_episode, locate_inputs, run_folder
    from robot.bench.trials import step_log_path
    from robot.episode.step_log import ViewsError, read_views, views_path

    try:
        trial, _ = load_episode(episode)
        trial, _ = locate_inputs(trial, run_folder(episode), config, progress)
    except ReplayError as exc:
        raise BeliefBenchError(f"{episode}: {exc}") from None
    log = step_log_path(run_folder(episode), trial)
    views = views_path(log)
    if not views.is_file():
        raise BeliefBenchError(f"{episode}: no views at {views} (replay it first: python -m robot.bench replay "
                               f"{episode})")
    try:
        steps = read_step_log(log)
        seen = read_views(views)
        loaded = load_map(trial.map_dir)
    except (StepLogError, ViewsError, MapError) as exc:
        raise BeliefBenchError(str(exc)) from None
    if len(steps) != len(seen.similarities):
        raise BeliefBenchError(f"{views}: {len(seen.similarities)} views for the {len(steps)} steps of {log} "
                               "(written by different replays: replay the episode again)")
    if not np.array_equal(seen.node_ids, loaded.topomap.node_ids):
        raise BeliefBenchError(f"{views}: the views are of another map than {trial.map_dir}")
    poses = map_node_poses(Path(trial.map_dir))
    if poses is None:
        raise BeliefBenchError(f"{episode}: the map {trial.map_dir} has no true node poses to judge the belief by")
    return Recorded(episode.stem, loaded.topomap, poses, steps, seen.similarities, seen.odometry)


def run_filter(recorded: Recorded, config: BeliefConfig) -> list[dict]:
    """The episode's steps with the belief of ``config`` in place of the logged one."""
    from core.hal import Odometry
    from robot.episode.belief import BeliefTracker, map_belief

    belief, why = map_belief(recorded.topomap, config)
    if belief is None:
        raise BeliefBenchError(f"{recorded.name}: {why}")
    tracker = BeliefTracker(belief)
    out = []
    for step, row, (x, y, yaw) in zip(recorded.steps, recorded.similarities, recorded.odometry):
        odometry = None if np.isnan(x) else Odometry(float(x), float(y), float(yaw), 0.0, 0.0, 0.0, 0.0)
        snap = tracker.step(odometry, row)
        out.append({**step, "belief_top": [[n, m] for n, m in snap.top], "belief_confidence": snap.confidence})
    return out


def judge(recorded: Sequence[Recorded], config: BeliefConfig) -> dict:
    """The belief of ``config`` over every episode, judged (see the module docstring)."""
    from robot.bench.diagnosis import CONFIDENT, confirmation_counts, diagnose, placement, wrong_place

    diagnoses, first, distances = [], [], []
    for r in recorded:
        steps = run_filter(r, config)
        diagnoses.append(diagnose(steps, r.poses))
        placements = [placement(s, s["belief_top"][0][0], r.poses) for s in steps]
        distances.extend(d for d, _ in placements)
        for s, where in zip(steps, placements):
            if s["belief_confidence"] >= CONFIDENT:
                first.append((s["step"], not wrong_place(*where)))
                break
    counts = confirmation_counts(diagnoses)
    return {"setting": {f.name: getattr(config, f.name) for f in fields(config)}, **counts,
            "mode_distance_median_m": round(float(np.median(distances)), 2) if distances else None,
            "mode_distance_p90_m": round(float(np.percentile(distances, 90)), 2) if distances else None,
            "first_confident": len(first), "first_confident_right": sum(ok for _, ok in first),
            "first_confident_median_step": statistics.median(s for s, _ in first) if first else None}


def _row(label: str, c: dict) -> str:
    def share(a, b):
        return f"{a:,} of {b:,} ({a / b:.2f})" if b else "-"
    return (f"| {label} | {share(c['belief_right'], c['belief_steps'])} | {c['mode_distance_median_m']} / "
            f"{c['mode_distance_p90_m']} | {share(c['belief_confident'], c['belief_steps'])}"
            f" | {share(c['belief_confident_right'], c['belief_confident'])} | {c['localisations']} | "
            f"{c['wrong_localisations']} | {c['belief_wrong_localisations']} | "
            f"{share(c['first_confident_right'], c['first_confident'])}, median step "
            f"{c['first_confident_median_step']} |")


def main(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from core.atomic import write_json
    from core.cli import UsageError, check_output_file
    from core.configfile import ConfigError
    from robot.settings import load_stack_config

    try:
        check_output_file("--json", args.json)
        for e in args.episodes:
            if not e.is_file():
                raise BeliefBenchError(f"{e}: no such episode file")
        if args.config is not None and not args.config.is_file():
            raise BeliefBenchError(f"--config {args.config}: no such file")
        config = load_stack_config(args.config)
        configs = sweep(config.navigation.belief, args.settings)
        recorded = [load_recorded(e, config, progress=not args.quiet)
                    for e in tqdm(args.episodes, desc="reading episodes", disable=args.quiet, leave=False)]
    except (BeliefBenchError, UsageError, ConfigError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    varied = sorted({text.partition("=")[0].strip() for text in args.settings})
    print(f"{len(recorded)} episodes, {sum(len(r.steps) for r in recorded):,} steps; the belief judged at every "
          f"step (mode right: within the diagnosis's rule; confident: mass >= "
          f"{config.navigation.belief.confidence} near the mode)\n")
    print("| setting | mode right | mode to robot, median / p90 (m) | confident | confident and right | "
          "(re-)localisations | navigator wrong | belief wrong | first confident mode right |")
    print("|---|---|---|---|---|---|---|---|---|")
    table = []
    for cfg in tqdm(configs, desc="settings", disable=args.quiet or len(configs) == 1, leave=False):
        try:
            c = judge(recorded, cfg)
        except BeliefBenchError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        table.append(c)
        print(_row(", ".join(f"{k}={getattr(cfg, k)}" for k in varied) or "configuration", c), flush=True)
    if args.json is not None:
        write_json(args.json, {"episodes": [str(e) for e in args.episodes], "results": table})
        print(f"\nwrote {args.json}")
    return 0
