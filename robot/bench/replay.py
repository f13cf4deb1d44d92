"""Replay one episode of ``python -m robot.bench paper`` with a step log, to see why it went as it did.

``python -m robot.bench replay RUN/episodes/hospital_hard_ours_3.json`` re-runs the episode's
trial (world, map, start pose, appearance seed, method: everything is in the episode file) in
this process the way the harness ran it (one torch thread), and writes what a trace picture
cannot show: for every step the true pose, the navigator's state and action, the current and
target node with their filtered scores, the thirds' scores, the node the raw view matched best,
the navigator's reason and the belief over the map (top nodes with their mass, confidence, entropy,
direction) (JSON lines, ``RUN/replays/<episode>.steps.jsonl`` by default), and beside it what the
robot saw (``<episode>.views.npz``: the view's similarity to every node and the odometry, for
``python -m robot.bench belief``); ``--video`` adds the MP4 with overlays, ``--rerun`` /
``--rerun-save FILE.rrd`` the Rerun viewer's timeline (:mod:`robot.viewer`). It prints the episode's events (localised, node
reached, lost, searching, ...) and whether the replay reproduced the recorded episode (same
steps, end, success, final distance, re-localisations): the runs are deterministic, so a
difference means the code or the configuration changed since. The configuration is the run
folder's ``config.yaml`` (every field, as the harness ran it) unless ``--config`` names another.

Episode files name their map relative to the run folder, so a run folder replays wherever it
lies. A map that is not there (a committed run holds no maps) is built again into the run folder
the way the harness built it; it reproduces the episode when the code that builds maps has not
changed since.

Exit status: 0 reproduced, 1 not reproduced, 2 bad input (the file named).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from dataclasses import MISSING, fields, replace
from pathlib import Path
from typing import Optional

from core.shutdown import exit_status, interrupted_by
from robot.viewer.stream import add_viewer_arguments

#: What must match for an episode to count as reproduced.
COMPARED = ("steps", "end", "success", "final_distance_m", "relocalisations")


class ReplayError(ValueError):
    """The episode file cannot be replayed (names the file and what is wrong)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("episode", type=Path, help="an episode file of a paper run: RUN/episodes/<episode>.json")
    parser.add_argument("--log", type=Path, default=None,
                        help="step log to write (JSON lines; default RUN/replays/<episode>.steps.jsonl)")
    parser.add_argument("--video", type=Path, default=None, help="also write an MP4 of the camera with overlays")
    parser.add_argument("--trace", type=Path, default=None, help="also write the top-down trace picture here")
    parser.add_argument("--config", type=Path, default=None,
                        help="stack config YAML (default: the run folder's config.yaml, the configuration the "
                             "harness ran with; configs/default.yaml for a run without one)")
    parser.add_argument("--events", type=int, default=40, help="print the last N events (default 40; 0: none)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_viewer_arguments(parser)


def load_episode(path: Path):
    """The :class:`robot.bench.trials.Trial` and the recorded metrics of an episode file."""
    from robot.bench.trials import Trial, resolved_trial

    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise ReplayError(f"{path}: cannot read the episode file ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise ReplayError(f"{path}: not JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, dict) or not isinstance(data.get("trial"), dict) or not isinstance(data.get("metrics"), dict):
        raise ReplayError(f"{path}: not an episode file of python -m robot.bench paper (needs 'trial' and 'metrics'; "
                          "results.json is the summary: pass a file from the run's episodes/ folder)")
    known = {f.name for f in fields(Trial)}
    missing = [f.name for f in fields(Trial) if f.default is MISSING and f.name not in data["trial"]]
    if missing:
        raise ReplayError(f"{path}: trial field(s) {', '.join(missing)} missing")
    run = Path(path).resolve().parent.parent
    try:
        trial = Trial(**{k: v for k, v in resolved_trial(data["trial"], run).items() if k in known})
    except TypeError as exc:
        raise ReplayError(f"{path}: bad trial ({exc})") from None
    return trial, data["metrics"]


def run_folder(episode: Path) -> Path:
    """The run folder of an episode file (``RUN/episodes/<episode>.json``)."""
    return Path(episode).resolve().parent.parent


def replay_config(episode: Path, given: Optional[Path]) -> Optional[Path]:
    """The configuration file to replay with: ``given`` (``--config``), else the run folder's
    record of the one it ran with, else None (configs/default.yaml)."""
    from robot.bench.trials import RUN_CONFIG

    record = run_folder(episode) / RUN_CONFIG
    return given if given is not None else (record if record.is_file() else None)


def locate_inputs(trial, run: Path, config, progress: bool):
    """The trial with a map (and baseline head) that exist: as recorded; else the run folder's
    ``maps/<name>`` (episodes of older runs name their map by an absolute path of the machine
    that ran them); else the map built again, as the harness builds it (the world's walkthrough
    under appearance 0, the configuration's mapping at the sparsity of the folder's name), into
    the run folder. Returns the trial and notes for the user."""
    from core.cli import UsageError, check_output_folder
    from robot.bench.paper import ensure_map
    from sim.world_spec import WorldError
    from sim.worlds import load_world

    notes = []
    recorded = Path(trial.map_dir)
    local = run / "maps" / recorded.name
    if not (recorded / "manifest.json").is_file():
        if not (local / "manifest.json").is_file():
            try:
                spec = load_world(trial.world)
            except (WorldError, OSError) as exc:
                raise ReplayError(f"the episode's map {trial.map_dir} is missing and its world cannot be loaded "
                                  f"to build it again: {exc}") from None
            match = re.fullmatch(rf"{re.escape(spec.name)}-s(\d+(?:\.\d+)?)", recorded.name)
            if match is None:
                raise ReplayError(f"the episode's map {trial.map_dir} is missing, and it is not a map the harness "
                                  f"builds (<run>/maps/{spec.name}-s<sparsity>), so it cannot be built again")
            try:
                check_output_folder("the run folder's maps", run / "maps")
            except UsageError as exc:
                raise ReplayError(str(exc)) from None
            print(f"note: the episode's map {trial.map_dir} is missing; building it again into {local} (the "
                  f"walkthrough of {spec.name} under appearance 0, sparsity {match.group(1)}; a few minutes)",
                  file=sys.stderr)
            ensure_map(trial.world, float(match.group(1)), config, run, progress)
            notes.append(f"map built again into {local}: a map made by other code than the episode's differs")
        trial = replace(trial, map_dir=str(local))
    if trial.method == "sptm":
        head = Path(trial.baseline_path) if trial.baseline_path else None
        if head is None or not head.is_file():
            local_head = run / "baseline" / (head.name if head else "sptm_head.pt")
            if not local_head.is_file():
                raise ReplayError(f"the baseline head {trial.baseline_path} is missing (train it again with "
                                  "python -m robot.bench paper --out RUN, or python -m robot.bench baseline)")
            trial = replace(trial, baseline_path=str(local_head))
    return trial, notes


def differences(recorded: dict, replayed: dict) -> list[str]:
    """``["steps 1203 -> 1187", ...]`` for every compared metric that differs."""
    return [f"{k} {recorded.get(k)!r} -> {replayed.get(k)!r}" for k in COMPARED if recorded.get(k) != replayed.get(k)]


def events(log_path: Path) -> list[str]:
    """One line per change of state or current node in a step log."""
    out, last = [], None
    with open(log_path, encoding="utf-8") as f:
        for line in f:
            e = json.loads(line)
            key = (e["state"], e["current_node"])
            if key != last:
                out.append(f"{e['step']:>5}  ({e['x_m']:6.2f}, {e['y_m']:6.2f}, {e['yaw_deg']:6.1f} deg)  "
                           f"{e['state']:<12} node {e['current_node']} -> {e['target_node']}  {e['reason'][:110]}")
            last = key
    return out


def _diagnosis(record: dict) -> Optional[str]:
    """The diagnosis :func:`robot.bench.trials.run_trial` made of the episode's step log
    (:mod:`robot.bench.diagnosis`), in words; None when it made none (a map without true poses)."""
    from robot.bench.diagnosis import Diagnosis

    if record.get("diagnosis") is None:
        return None
    d = Diagnosis.from_dict(record["diagnosis"])
    text = f"step log: {len(d.confirmations)} nodes confirmed, {len(d.wrong)} at a wrong place; {d.summary()}"
    belief = d.belief_summary()
    return text if belief is None else f"{text}\n{belief}"


def main(args: argparse.Namespace) -> int:
    from core.cli import UsageError
    from robot.bench.trials import run_trial, step_log_path, worker_init
    from robot.viewer.stream import viewer_target

    try:
        viewer = viewer_target(args)
        trial, recorded = load_episode(args.episode)
        if args.config is not None and not args.config.is_file():
            raise ReplayError(f"--config {args.config}: no such file")
    except (ReplayError, UsageError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from core.configfile import ConfigError
    from robot.bench.trials import config_digest
    from robot.settings import load_run_record, load_stack_config

    given, dropped = args.config, []
    args.config = replay_config(args.episode, args.config)
    try:
        if given is None and args.config is not None:
            config, dropped = load_run_record(args.config)
            if dropped:
                print(f"note: {args.config} names {', '.join(dropped)}, which the code no longer has (removed since "
                      "the run): replayed without", file=sys.stderr)
        else:
            config = load_stack_config(args.config)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if trial.config_digest is not None:
        digest = config_digest(config)
        if digest != trial.config_digest:
            why = ("pass the run's --config to reproduce it" if given is not None or args.config is None else
                   "the code has changed since the run (the note above)" if dropped else
                   f"{args.config} is the run's record, read over configs/default.yaml: a field the code added "
                   "since takes today's default unless the record names it")
            print(f"note: the configuration differs from the one the episode ran with (digest {digest}, recorded "
                  f"{trial.config_digest}); {why}", file=sys.stderr)
    try:
        trial, notes = locate_inputs(trial, run_folder(args.episode), config, progress=not args.quiet)
    except ReplayError as exc:
        print(f"error: {args.episode}: {exc}", file=sys.stderr)
        return 2
    log = args.log or step_log_path(run_folder(args.episode), trial)
    trial = replace(trial, trace_png=None if args.trace is None else str(args.trace))
    worker_init()          # as the harness ran it: one torch / BLAS / OpenCV thread
    try:
        result = run_trial(trial, config=config, step_log=str(log),
                           video_path=None if args.video is None else str(args.video), viewer=viewer,
                           progress=not args.quiet)
    except KeyboardInterrupt as exc:
        print(f"{interrupted_by(exc)}: the steps made are in {log}", file=sys.stderr)
        return exit_status(exc)
    if args.events and log.is_file():
        lines = events(log)
        if len(lines) > args.events:
            print(f"... {len(lines) - args.events} earlier events (all steps: {log})")
        print("\n".join(lines[-args.events:]))
    m = result["metrics"]
    print(f"\n{trial.key}: {'success' if m['success'] else 'failure'}, {m['steps']} steps, end {m['end']}, "
          f"final distance {m['final_distance_m']} m, {m['relocalisations']} re-localisations, "
          f"{m['collisions']} collisions: {m['reason']}")
    diagnosis = _diagnosis(result)
    if diagnosis:
        print(diagnosis)
    from robot.episode.step_log import views_path

    written = [str(p) for p in (log, views_path(log)) if p.is_file()]
    written += [str(p) for p in (args.video, args.trace, args.rerun_save) if p is not None]
    if written:
        print(f"wrote {', '.join(written)}")
    diff = differences(recorded, m)
    if diff:
        for note in notes:
            print(f"note: {note}")
        print(f"NOT reproduced ({'; '.join(diff)}): the code, the configuration or the map changed since the "
              "episode ran")
        return 1
    print("reproduced: the same steps, end and final distance as the recorded episode")
    return 0
