"""``python -m robot.bench paper``: the paper's table in PyBullet, with the learned baseline and
the map sparsity study.

    python -m robot.bench paper                      # 14 trials per route, both methods, sparsity study
    python -m robot.bench paper --quick              # 2 trials of hospital easy: a smoke test
    python -m robot.bench paper --trials 5 --routes hospital:hard --methods ours --workers 2
    python -m robot.bench paper --ray auto           # every episode a Ray task on a cluster

What it does, in ``--out`` (default ``runs/paper``):

0. ``config.yaml``: the configuration the episodes run with, every field resolved (what
   ``bench replay`` reads unless told another).
1. ``maps/``: for each world, one mapping walkthrough (appearance 0, the stack config's
   teleoperator) and a map per sparsity level needed; existing maps are reused.
2. ``baseline/sptm_head.pt``: the SPTM-style baseline's action head, trained on expert drives
   in ``hospital`` (reused when present; ``--baseline PATH`` names another file). It is tested in
   every world, so the office column measures generalisation, as in the paper.
3. ``episodes/``: every trial's result as it finishes; a re-run reuses those whose trial
   description is unchanged (an interrupted run resumes). Trials start at the route start with
   a random offset (up to 0.3 m, 15 deg) and appearance seed 1, 2, ... (``robot.bench.trials``).
4. ``results.json`` (every episode: metrics, seeds, trajectory; no wall-clock values, so serial,
   ``--workers N`` and ``--ray`` runs are identical), ``timings.json`` (wall time per episode and
   step, and with ``--ray`` the host and process that ran it),
   ``results.md`` (the paper's table layout with the paper's numbers), ``sr.png``,
   ``trajectories_<world>_<route>.png``, ``sparsity.png``, and a trace picture per episode in
   ``traces/``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import Optional

from tqdm import tqdm

from core.atomic import write_json
from core.shutdown import exit_status, interrupted_by
from robot.bench.cluster import LOCAL, ClusterError, EpisodeLost, RayRunner
from robot.bench.runners import Job, LocalRunner, TrialRunner
from robot.bench.trials import (
    DEFAULT_METHODS,
    METHODS,
    Trial,
    config_digest,
    episode_path,
    plan_trials,
    portable_trial,
    step_log_path,
    write_run_config,
)

DEFAULT_ROUTES = ("hospital:easy", "hospital:moderate", "hospital:hard", "office:main")
DEFAULT_SPARSITY_LEVELS = (0.25, 0.5, 0.75)
BASELINE_WORLD = "hospital"


class PaperBenchError(ValueError):
    """Arguments or inputs the harness cannot use; the message names the option or file."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=int, default=14, help="episodes per route and method (default 14, as the paper)")
    parser.add_argument("--out", type=Path, default=Path("runs/paper"), help="output folder (default runs/paper)")
    parser.add_argument("--workers", type=int, default=None,
                        help="episodes run in this many processes (default: the number of CPUs; with --ray, the "
                             "local instance's CPUs); results do not depend on it")
    parser.add_argument("--ray", nargs="?", const=LOCAL, default=None, metavar="ADDRESS",
                        help="run every episode as a Ray task: on a local instance (no ADDRESS), or on the cluster "
                             "at ADDRESS (auto, HOST:PORT, ray://HOST:PORT); pip install -e '.[cluster]'")
    parser.add_argument("--ray-shared", action="store_true",
                        help="with --ray: --out is on a file system every node mounts at the same path (workers "
                             "read maps and write traces there; otherwise they travel through Ray's object store)")
    parser.add_argument("--seed", type=int, default=0, help="base seed of the trials' offsets (default 0)")
    parser.add_argument("--routes", default=",".join(DEFAULT_ROUTES),
                        help="comma-separated WORLD:ROUTE list (default: %(default)s); WORLD may be a world file")
    parser.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                        help="comma-separated: ours, sptm, paper (the paper's method as published, none of our "
                             "additions), ours-hints, ours-no-hints (ours with the turn hints from the map's odometry "
                             "forced on / off; default: ours,sptm)")
    parser.add_argument("--sparsity", default=",".join(f"{s:g}" for s in DEFAULT_SPARSITY_LEVELS),
                        help="map sparsity levels of the study (default %(default)s); 'none' skips the study")
    parser.add_argument("--sparsity-route", default="hospital:moderate",
                        help="the route of the sparsity study (default %(default)s)")
    parser.add_argument("--sparsity-trials", type=int, default=None, help="trials per level (default --trials)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke test: 2 trials of hospital easy (or the first --routes entry), both methods, no study")
    parser.add_argument("--config", type=Path, default=None, help="stack config YAML (default configs/default.yaml)")
    parser.add_argument("--baseline", type=Path, default=None,
                        help="the baseline's trained head (default <out>/baseline/sptm_head.pt, trained when missing)")
    parser.add_argument("--baseline-episodes", type=int, default=None,
                        help="expert exploration episodes to train the baseline (default: the trainer's)")
    parser.add_argument("--no-traces", action="store_true", help="skip the per-episode trace pictures")
    parser.add_argument("--step-logs", action="store_true",
                        help="also write every episode run's per-step log (JSON lines, as python -m robot.bench replay "
                             "does) to <out>/replays/; reused episodes keep theirs")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--report-only", action="store_true",
                        help="run no episode: write the report of the episodes of this command already finished "
                             "under --out (an interrupted or still running run; marked partial if some are missing)")


# -- arguments ----------------------------------------------------------------------------------
def _routes(text: str) -> list[tuple[str, str]]:
    out = []
    for item in (t.strip() for t in text.split(",")):
        if not item:
            continue
        if ":" not in item:
            raise PaperBenchError(f"--routes {item!r}: expected WORLD:ROUTE, e.g. hospital:easy")
        world, route = item.rsplit(":", 1)
        out.append((world, route))
    if not out:
        raise PaperBenchError("--routes is empty")
    return out


def _methods(text: str) -> list[str]:
    methods = [m.strip() for m in text.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise PaperBenchError(f"--methods {text!r}: expected a comma-separated list of {', '.join(METHODS)}")
    return methods


def _levels(text: str) -> list[float]:
    if text.strip().lower() in ("", "none", "off"):
        return []
    try:
        levels = [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise PaperBenchError(f"--sparsity {text!r}: expected comma-separated numbers in [0, 1] or 'none'") from None
    if any(not 0.0 <= s <= 1.0 for s in levels):
        raise PaperBenchError(f"--sparsity {text!r}: every level must be in [0, 1]")
    return levels


# -- maps and the baseline ------------------------------------------------------------------------
def _map_is_usable(map_dir: Path) -> bool:
    return (map_dir / "manifest.json").is_file()


def ensure_map(world_name: str, sparsity: float, config, out: Path, progress: bool, build: bool = True) -> Path:
    """The map of ``world_name``'s walkthrough at ``sparsity`` under ``out/maps`` (built when
    missing unless ``build`` is false; the walkthrough is driven once per world and reused for
    every level)."""
    from descriptors.factory import make_descriptor
    from maps.store import load_map
    from robot.mapping.drive import drive_walkthrough
    from robot.mapping.make import build_map_from_frames, world_picture_of
    from robot.mapping.sources import RecordingSource, Sampling
    from sim.worlds import load_world

    spec = load_world(world_name)
    map_dir = out / "maps" / f"{spec.name}-s{sparsity:g}"
    if _map_is_usable(map_dir):
        load_map(map_dir)     # fails loudly (naming the folder) on a damaged map
        return map_dir
    if not build:
        raise PaperBenchError(f"no map in {map_dir}: run without --report-only to build it")
    drive = out / "maps" / f"{spec.name}-walkthrough"
    if not (drive / "summary.json").is_file():
        drive_walkthrough(spec, config, drive, appearance_seed=0, progress=progress)
    source = RecordingSource(drive, Sampling())
    mapping = replace(config.mapping, sparsity=float(sparsity))
    build_map_from_frames(source, make_descriptor(config.descriptor.backend, **config.descriptor.settings),
                          mapping, map_dir, total=len(source), world_picture=world_picture_of(spec, 0),
                          fit_max_frames=config.descriptor.fit_max_frames, source=source.description,
                          progress=progress, extra={"world": spec.name, "appearance_seed": 0})
    return map_dir


def ensure_baseline(path: Optional[Path], out: Path, hospital_map: Path, episodes: Optional[int],
                    seed: int, progress: bool, config, train: bool = True) -> Path:
    """The baseline's head: ``path`` when given, else ``out/baseline/sptm_head.pt``, trained on
    expert drives in the hospital when missing and ``train`` (one torch thread: the same seed gives
    the same head)."""
    import torch

    from robot.baseline import train_baseline

    if path is not None:
        if not path.is_file():
            raise PaperBenchError(f"--baseline {path}: no such file (train one with python -m robot.bench baseline)")
        return path
    target = out / "baseline" / "sptm_head.pt"
    if target.is_file():
        return target
    if not train:
        raise PaperBenchError(f"no baseline head at {target}: run without --report-only to train it")
    kwargs = {"seed": seed, "progress": progress, "sim_config": config.sim, "speeds": config.navigation.speeds}
    if episodes is not None:
        kwargs["episodes"] = episodes
    torch.set_num_threads(1)
    return Path(train_baseline(BASELINE_WORLD, hospital_map, target, **kwargs))


# -- running --------------------------------------------------------------------------------------
def _reusable(out: Path, trial: Trial) -> Optional[dict]:
    path = episode_path(out, trial)
    if not path.is_file():
        return None
    try:
        done = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None
    if done.get("trial") not in (asdict(trial), portable_trial(asdict(trial), out)):
        return None
    return {**done, "trial": asdict(trial)}


def run_trials(trials: list[Trial], out: Path, runner: TrialRunner, progress: bool,
               step_logs: bool = False) -> list[dict]:
    """Run (or reuse) every trial on ``runner``; results in the order of ``trials``, each episode's
    file written as it finishes. ``step_logs``: each episode run also writes its per-step log
    (:func:`step_log_path`)."""
    results: dict[int, dict] = {}
    todo = []
    for i, trial in enumerate(trials):
        done = _reusable(out, trial)
        if done is not None:
            results[i] = done
        else:
            todo.append(i)
    # trial number first, then route and method: an interrupted run has every route's first trials
    todo.sort(key=lambda i: (trials[i].trial, i))
    bar = tqdm(total=len(trials), initial=len(results), unit="episode", desc="episodes", disable=not progress)
    if step_logs:
        (out / "replays").mkdir(parents=True, exist_ok=True)
    jobs = [Job(i, trials[i], str(step_log_path(out, trials[i])) if step_logs else None) for i in todo]
    try:
        for i, result in runner.results(jobs):
            results[i] = result
            write_json(episode_path(out, trials[i]), {**result, "trial": portable_trial(result["trial"], out)})
            m = result["metrics"]
            bar.set_postfix_str(f"{trials[i].key}: {'ok' if m['success'] else 'FAIL'}", refresh=False)
            bar.update(1)
    finally:
        bar.close()
    return [results[i] for i in range(len(trials))]


def runner_choice(args: argparse.Namespace) -> tuple[int | None, Optional[str]]:
    """``(workers, ray)`` from ``--workers`` / ``--ray`` / ``--ray-shared``, checked: ``ray`` is None
    (local processes), :data:`LOCAL` (a local Ray instance) or a cluster address."""
    if args.workers is not None and args.workers < 1:
        raise PaperBenchError(f"--workers must be >= 1, got {args.workers}")
    if args.ray_shared and args.ray is None:
        raise PaperBenchError("--ray-shared needs --ray")
    if args.ray not in (None, LOCAL) and args.workers is not None:
        raise PaperBenchError(f"--workers with --ray {args.ray}: the cluster's CPUs set how many episodes run at "
                              "once (--workers sizes a local instance only)")
    return args.workers, args.ray


def make_runner(workers: Optional[int], ray: Optional[str], shared: bool, config_path: Optional[str]) -> TrialRunner:
    """The runner of :func:`runner_choice`'s answer (a Ray runner connects here)."""
    if ray is None:
        return LocalRunner(workers if workers is not None else (os.cpu_count() or 1), config_path)
    return RayRunner(None if ray == LOCAL else ray, workers, config_path, shared=shared)


# -- main -----------------------------------------------------------------------------------------
def main(args: argparse.Namespace) -> int:
    from core.configfile import ConfigError
    from robot.bench.paper_report import write_report
    from robot.settings import load_stack_config
    from sim.shortest_path import route_shortest_length_m
    from sim.world_spec import WorldError
    from sim.worlds import load_world

    started = time.perf_counter()
    try:
        routes = _routes(args.routes)
        methods = _methods(args.methods)
        levels = _levels(args.sparsity)
        trials = args.trials
        sparsity_trials = args.sparsity_trials
        if args.quick:            # the first route (hospital easy by default), 2 trials, no study
            routes, trials, levels = routes[:1], 2, []
        if trials < 1:
            raise PaperBenchError(f"--trials must be >= 1, got {trials}")
        sparsity_trials = trials if sparsity_trials is None else sparsity_trials
        if levels and sparsity_trials < 1:
            raise PaperBenchError(f"--sparsity-trials must be >= 1, got {sparsity_trials}")
        workers, ray = runner_choice(args)
        config = load_stack_config(args.config)
        specs = {}
        for world, route in routes + ([tuple(args.sparsity_route.rsplit(":", 1))] if levels else []):
            spec = specs.setdefault(world, load_world(world))
            if route not in spec.routes.evaluation:
                raise PaperBenchError(f"route {world}:{route}: world {spec.name!r} has no such route (routes: "
                                      f"{', '.join(sorted(spec.routes.evaluation))})")
    except (PaperBenchError, ConfigError, WorldError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    out: Path = args.out
    progress = not args.quiet
    default_sparsity = float(config.mapping.sparsity)
    config_path = None if args.config is None else str(args.config)
    runner = None
    try:         # before the maps: a cluster that cannot be reached is told at once, not after mapping
        runner = None if args.report_only else make_runner(workers, ray, args.ray_shared, config_path)
    except ClusterError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        build = not args.report_only
        if build:    # before the maps: an --out that cannot be written is told at once
            try:
                write_run_config(out, config)
            except OSError as exc:
                raise PaperBenchError(f"--out {out}: cannot write the run's configuration there: {exc}") from exc
        maps = {world: ensure_map(world, default_sparsity, config, out, progress, build) for world, _ in routes}
        if "ours-hints" in methods or ("ours" in methods and config.navigation.heading_hints):
            from maps.store import load_map

            source = config.navigation.heading_source
            for map_dir in maps.values():
                if load_map(map_dir).topomap.headings(source) is None:
                    raise PaperBenchError(f"{map_dir}: the map has no {source} headings (made by an older version); "
                                          "the turn hints need them: delete the folder to rebuild it")
        baseline = None
        if "sptm" in methods:
            hospital = maps.get(BASELINE_WORLD) or ensure_map(BASELINE_WORLD, default_sparsity, config, out, progress,
                                                              build)
            baseline = str(ensure_baseline(args.baseline, out, hospital, args.baseline_episodes, args.seed, progress,
                                           config, train=build))
        trace_dir = None if args.no_traces else out / "traces"
        shortest_cache: dict = {}

        def shortest_of(world, route):
            def f(x, y):
                key = (world, route, round(x, 4), round(y, 4))
                if key not in shortest_cache:
                    shortest_cache[key] = route_shortest_length_m(specs[world], route, (x, y))
                return shortest_cache[key]
            return f

        digest = config_digest(config)
        plan: list[Trial] = []
        for world, route in routes:
            plan += plan_trials(specs[world], world, route, methods, trials, args.seed, maps[world],
                                shortest_of(world, route), baseline_path=baseline, trace_dir=trace_dir,
                                config_digest=digest)
        study: list[Trial] = []
        if levels:
            s_world, s_route = args.sparsity_route.rsplit(":", 1)
            for level in levels:
                if level == default_sparsity and (s_world, s_route) in routes and sparsity_trials <= trials:
                    continue      # the main table's episodes of this route are this level's
                level_map = ensure_map(s_world, level, config, out, progress, build)
                study += plan_trials(specs[s_world], s_world, s_route, ["ours"], sparsity_trials, args.seed,
                                     level_map, shortest_of(s_world, s_route), sparsity=level,
                                     trace_dir=trace_dir, config_digest=digest)
        if runner is None:
            results = [_reusable(out, t) for t in plan + study]
            if not any(results):
                raise PaperBenchError(f"no finished episode of this command in {out / 'episodes'}: run it "
                                      "without --report-only")
        else:
            results = run_trials(plan + study, out, runner, progress, step_logs=args.step_logs)
    except PaperBenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except EpisodeLost as exc:
        print(f"error: {exc}; run the same command to resume", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        print(f"{interrupted_by(exc)}: finished episodes are kept in {out / 'episodes'}; run the same command to "
              "resume, or add --report-only for the report of those finished", file=sys.stderr)
        return exit_status(exc)
    finally:
        if runner is not None:
            runner.close()
    argv = sys.argv[2:] if sys.argv[1:2] == ["paper"] else sys.argv[1:]
    command = "python -m robot.bench paper " + " ".join(a for a in argv if a != "--report-only")
    written = write_report(out, [r for r in results[:len(plan)] if r], [r for r in results[len(plan):] if r],
                           planned=len(results), planned_routes=routes, planned_methods=methods,
                           specs=specs, maps=maps,
                           levels=levels, default_sparsity=default_sparsity,
                           sparsity_route=args.sparsity_route if levels else None,
                           sparsity_trials=sparsity_trials, command=command.strip(), seed=args.seed)
    elapsed = time.perf_counter() - started
    print(written["table"])
    print(f"\nwrote {', '.join(str(p) for p in written['files'])}")
    finished = sum(1 for r in results if r)
    if args.report_only:
        print(f"report of {finished} finished of {len(results)} planned episodes"
              + ("" if finished == len(results) else " (partial: run the command without --report-only to finish)"))
    else:
        print(f"{len(results)} episodes, {elapsed / 60:.1f} min wall with {runner.label}")
    return 0
