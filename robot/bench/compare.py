"""``python -m robot.bench compare RUN [RUN ...]``: runs of the paper harness side by side, one
row per run, for A/B tests and ablations.

    python -m robot.bench compare docs/paper/run-2026-12-07 runs/ablation/* --trials 7 \\
        --routes office:main,hospital:hard,hospital:moderate,hospital:easy

Each RUN is a folder written by ``python -m robot.bench paper`` (finished or not: the episodes it
holds count). For one method (``--method``, default ``ours``) and the routes all runs share (or
``--routes``), each row gives the success rate per route and their mean, SR within 0.5 m, SPL,
collisions per episode, the (re-)localisations at a wrong place (from the step logs, where the run
kept them: ``--step-logs``), the final distance's median and 90th percentile, the steps, and what
the run's configuration (its ``config.yaml``) changes against the first RUN's: the first is the
reference. ``--trials N`` counts the first N trials of each route only, so a run of 7 trials
compares with the first 7 of a run of 14 (trial k has the same start and appearance in both).

Exit status: 0 done, 2 bad input (the folder, option or value named).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from core.cli import positive_int


class CompareError(ValueError):
    """Bad input to the comparison (names the folder, option or value)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", type=Path, nargs="+", help="run folders of python -m robot.bench paper; the first "
                                                            "is the reference")
    parser.add_argument("--method", default="ours", help="the method compared (default ours)")
    parser.add_argument("--routes", default=None,
                        help="WORLD:ROUTE,... (default: the routes every run has episodes of)")
    parser.add_argument("--trials", type=positive_int, default=None,
                        help="count only the first N trials of each route (default: all)")
    parser.add_argument("--json", type=Path, default=None, help="also write the rows as JSON here")


def read_episodes(run: Path, method: str, trials: Optional[int] = None) -> list[dict]:
    """The run's episodes of ``method`` (trial paths resolved against the run folder), the
    first ``trials`` of each route when given; raises :class:`CompareError` naming the file."""
    from robot.bench.trials import resolved_trial

    folder = Path(run) / "episodes"
    if not folder.is_dir():
        raise CompareError(f"{run}: no episodes/ folder (not a run of python -m robot.bench paper)")
    found = []
    for path in sorted(folder.glob("*.json")):
        try:
            episode = json.loads(path.read_text(encoding="utf-8"))
            trial = episode["trial"]
            episode["metrics"]["success"]
        except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
            raise CompareError(f"{path}: not an episode file ({exc})") from None
        if trial.get("method") != method or trial.get("sparsity") is not None:
            continue
        if trials is not None and trial.get("trial", 0) >= trials:
            continue
        found.append({**episode, "trial": resolved_trial(trial, run)})
    return found


def route_of(episode: dict) -> str:
    return f"{Path(episode['trial']['world']).stem}:{episode['trial']['route']}"


def flat(mapping, prefix: str = "") -> dict:
    """``{"a.b.c": value}`` of a nested mapping."""
    out = {}
    for key, value in (mapping or {}).items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flat(value, name + "."))
        else:
            out[name] = value
    return out


def config_changes(run: Path, reference: Path) -> str:
    """What ``run``'s config.yaml sets differently from ``reference``'s (``field=value``, ...)."""
    from core.configfile import ConfigError, read_yaml_mapping

    def read(folder: Path) -> dict:
        path = Path(folder) / "config.yaml"
        if not path.is_file():
            return {}
        try:
            return flat(read_yaml_mapping(path))
        except ConfigError as exc:
            raise CompareError(str(exc)) from None

    mine, theirs = read(run), read(reference)
    if not mine or not theirs:
        return "?" if Path(run) != Path(reference) else ""
    changed = [f"{k}={mine.get(k, '-')}" for k in sorted(set(mine) | set(theirs)) if mine.get(k) != theirs.get(k)]
    return ", ".join(changed)


def row(run: Path, reference: Path, episodes: Sequence[dict], routes: Sequence[str]) -> dict:
    """One run's numbers over ``routes`` (see the module docstring)."""
    from robot.bench.diagnosis import confirmation_counts
    from robot.bench.paper_report import diagnose_episodes, summarise_episodes
    from sim.worlds import load_world

    eps = [e for e in episodes if route_of(e) in routes]
    per_route = {r: summarise_episodes([e for e in eps if route_of(e) == r]) for r in routes}
    s = summarise_episodes(eps)
    specs = {w: load_world(w) for w in sorted({Path(e["trial"]["world"]).stem for e in eps})}
    judged = list(diagnose_episodes(eps, run, specs).values())
    counts = confirmation_counts(judged) if judged else None
    return {"run": str(run), "changes": config_changes(run, reference), "trials": s["trials"],
            "sr_per_route": {r: per_route[r].get("success_rate") for r in routes},
            "sr": round(float(np.mean([per_route[r]["success_rate"] for r in routes])), 4)
            if all(per_route[r]["trials"] for r in routes) else None,
            "sr_0_5m": s.get("success_rate_0_5m"), "spl": s.get("spl"),
            "collisions_per_episode": round(s["collisions"] / s["trials"], 3) if s["trials"] else None,
            "localisations": None if counts is None else counts["localisations"],
            "wrong_localisations": None if counts is None else counts["wrong_localisations"],
            "logged_episodes": len(judged),
            "final_p50_m": s.get("final_distance_p50_m"), "final_p90_m": s.get("final_distance_p90_m"),
            "steps": int(sum(e["metrics"]["steps"] for e in eps))}


def format_rows(rows: Sequence[dict], routes: Sequence[str], method: str) -> str:
    def num(v, fmt="{:.2f}"):
        return "-" if v is None else fmt.format(v)

    lines = [f"| run ({method}) | changes against the first | trials | SR {' / '.join(routes)} (mean) | "
             "SR 0.5 m | SPL | collisions per episode | wrong (re-)localisations | final p50 / p90 (m) | steps |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for k, r in enumerate(rows):
        changes = "(reference)" if k == 0 else r["changes"] or "(none)"
        n, bad = r["localisations"], r["wrong_localisations"]
        wrong = "-" if not n else f"{bad} of {n} ({bad / n:.0%})"
        lines.append(f"| {r['run']} | {changes} | {r['trials']} | "
                     + " / ".join(num(r["sr_per_route"][x]) for x in routes) + f" ({num(r['sr'])}) | "
                     f"{num(r['sr_0_5m'])} | {num(r['spl'])} | {num(r['collisions_per_episode'])} | {wrong} | "
                     f"{num(r['final_p50_m'])} / {num(r['final_p90_m'])} | {r['steps']:,} |")
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    from core.atomic import write_json
    from core.cli import UsageError, check_output_file
    from sim.world_spec import WorldError

    try:
        check_output_file("--json", args.json)
        for run in args.runs:
            if not run.is_dir():
                raise CompareError(f"{run}: no such run folder")
        episodes = {run: read_episodes(run, args.method, args.trials) for run in args.runs}
        empty = [str(r) for r, e in episodes.items() if not e]
        if empty:
            raise CompareError(f"no {args.method!r} episodes in {', '.join(empty)} (--method names another?)")
        if args.routes is not None:
            routes = [t.strip() for t in args.routes.split(",") if t.strip()]
            bad = [t for t in routes if t.count(":") != 1]
            if not routes or bad:
                raise CompareError(f"--routes {args.routes!r}: expected WORLD:ROUTE,...")
        else:
            shared = set.intersection(*({route_of(e) for e in eps} for eps in episodes.values()))
            routes = sorted(shared)
            if not routes:
                raise CompareError("the runs share no route; name the routes with --routes")
        rows = [row(run, args.runs[0], episodes[run], routes) for run in args.runs]
    except (CompareError, UsageError, WorldError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(format_rows(rows, routes, args.method))
    if args.json is not None:
        write_json(args.json, {"method": args.method, "routes": routes, "trials": args.trials, "rows": rows})
        print(f"\nwrote {args.json}")
    return 0
