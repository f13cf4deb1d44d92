"""The paper harness's outputs: results.json, timings.json, results.md and the plots.

``results.json`` holds only what the seeds determine (metrics, trial conditions, trajectories),
so a serial run and a ``--workers N`` run of the same seeds write the same file; wall-clock
numbers go to ``timings.json`` and the timing section of ``results.md``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from core.atomic import save_figure, write_text
from robot.bench.trials import portable_trial

#: The paper's success rates (Table "Comparison of Success Rates"), keyed by our routes.
PAPER_COLUMNS = {("hospital", "easy"): "Easy 10 m", ("hospital", "moderate"): "Moderate 20 m",
                 ("hospital", "hard"): "Hard 35 m", ("office", "main"): "Office 40 m"}
PAPER_SR = {
    "ours": {"Easy 10 m": 1.00, "Moderate 20 m": 0.92, "Hard 35 m": 0.86, "Office 40 m": 1.00, "Average": 0.95},
    "sptm": {"Easy 10 m": 1.00, "Moderate 20 m": 0.64, "Hard 35 m": 0.47, "Office 40 m": 0.25, "Average": 0.59},
}
METHOD_LABELS = {"ours": "Ours (AnyLoc-style VLAD + two-cycle voter)",
                 "ours-hints": "Ours with the turn hints from the map's odometry",
                 "ours-no-hints": "Ours without the turn hints",
                 "paper": "The paper's method as published (none of our additions)",
                 "sptm": "SPTM-style baseline (learned action head)"}
PAPER_LABELS = {"ours": "Paper: Ours", "sptm": "Paper: ResNet+AnyLoc"}
COLORS = {"ours": (0.12, 0.47, 0.71), "ours-hints": (0.17, 0.63, 0.17), "ours-no-hints": (0.58, 0.40, 0.74),
          "paper": (0.55, 0.55, 0.55), "sptm": (0.85, 0.37, 0.01)}


def summarise_episodes(episodes: Sequence[dict]) -> dict:
    """SR (1.0 m, 0.5 m), mean SPL, final distance (mean, median, 90th percentile),
    re-localisations and collisions."""
    n = len(episodes)
    if n == 0:
        return {"trials": 0}
    m = [e["metrics"] for e in episodes]
    spl = [x["spl"] if x["spl"] is not None else 0.0 for x in m]
    finals = [x["final_distance_m"] for x in m if x["final_distance_m"] is not None]
    return {"trials": n, "success_rate": round(sum(x["success"] for x in m) / n, 4),
            "success_rate_0_5m": round(sum(x["success_0_5m"] for x in m) / n, 4),
            "spl": round(float(np.mean(spl)), 4),
            "mean_final_distance_m": round(float(np.mean(finals)), 3) if finals else None,
            "final_distance_p50_m": round(float(np.percentile(finals, 50)), 3) if finals else None,
            "final_distance_p90_m": round(float(np.percentile(finals, 90)), 3) if finals else None,
            "mean_relocalisations": round(float(np.mean([x["relocalisations"] for x in m])), 3),
            "collisions": int(sum(x["collisions"] or 0 for x in m)),
            "failures": [e["trial"]["trial"] for e in episodes if not e["metrics"]["success"]]}


def overall(main: Sequence[dict], routes: Sequence[tuple[str, str]], methods: Sequence[str], summary: dict,
            diagnoses: Optional[dict] = None) -> dict:
    """Each method over all routes, the numbers a reader checks first: the route-mean SR and the
    lowest route's, SR within 0.5 m, SPL, final distance and collisions over all trials, the share
    of (re-)localisations at a wrong node (from the step logs, where there are some) and the margin
    of the route-mean SR over the SPTM-style baseline's. ``None`` where a route has no trial yet."""
    diagnoses = diagnoses or {}
    planned = set(routes)
    found = {}
    for m in methods:
        cells = {f"{w}:{r}": summary[f"{w}:{r}"][m] for w, r in routes}
        eps = [e for e in main if e["trial"]["method"] == m and _route_id(e) in planned]
        if not eps:
            continue
        s = summarise_episodes(eps)
        complete = all(c["trials"] for c in cells.values())
        lowest = min(cells, key=lambda k: cells[k]["success_rate"]) if complete else None
        counts = None
        judged = [diagnoses[id(e)] for e in eps if id(e) in diagnoses]
        if judged:
            from robot.bench.diagnosis import confirmation_counts

            c = confirmation_counts(judged)
            counts = {"localisations": c["localisations"], "wrong": c["wrong_localisations"],
                      "share": round(c["wrong_localisations"] / c["localisations"], 4) if c["localisations"] else None}
        found[m] = {"trials": s["trials"],
                    "route_mean_sr": round(float(np.mean([c["success_rate"] for c in cells.values()])), 4)
                    if complete else None,
                    "lowest_route": lowest, "lowest_route_sr": cells[lowest]["success_rate"] if lowest else None,
                    "success_rate_0_5m": s["success_rate_0_5m"], "spl": s["spl"],
                    "final_distance_p50_m": s["final_distance_p50_m"],
                    "final_distance_p90_m": s["final_distance_p90_m"],
                    "collisions_per_episode": round(s["collisions"] / s["trials"], 3),
                    "wrong_localisations": counts}
    base = found.get("sptm", {}).get("route_mean_sr")
    for m, o in found.items():
        o["margin_over_sptm"] = (round(o["route_mean_sr"] - base, 4)
                                 if m != "sptm" and base is not None and o["route_mean_sr"] is not None else None)
    return found


def _overall_lines(over: dict, routes: Sequence[tuple[str, str]]) -> list[str]:
    def num(v, fmt="{:.2f}"):
        return "-" if v is None else fmt.format(v)

    lines = ["## Over all routes", "",
             f"Each method over the {len(routes)} routes: SR is the mean of the routes' success rates (as in the "
             "table's Average), the lowest route beside it; SR within 0.5 m, SPL, the final distance to the goal "
             "and collisions are over all trials; wrong (re-)localisations come from the step logs (read as each "
             "episode ran and kept in its record; the rule in the section below); the margin is the SR's over the "
             "SPTM-style baseline's.", "",
             "| method | trials | SR | lowest route | SR 0.5 m | SPL | final distance p50 / p90 (m) | "
             "collisions per episode | wrong (re-)localisations | margin over the baseline |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for m, o in over.items():
        w = o["wrong_localisations"]
        wrong = "-" if not w or w["share"] is None else f"{w['wrong']} of {w['localisations']} ({w['share']:.0%})"
        lowest = "-" if o["lowest_route"] is None else f"{o['lowest_route_sr']:.2f} ({o['lowest_route']})"
        lines.append(f"| {m} | {o['trials']} | {num(o['route_mean_sr'])} | {lowest} | {o['success_rate_0_5m']:.2f} | "
                     f"{o['spl']:.2f} | {num(o['final_distance_p50_m'])} / {num(o['final_distance_p90_m'])} | "
                     f"{o['collisions_per_episode']:.2f} | {wrong} | {num(o['margin_over_sptm'], '{:+.2f}')} |")
    return lines


def _route_id(e: dict) -> tuple[str, str]:
    return Path(e["trial"]["world"]).stem, e["trial"]["route"]


def _column(world: str, route: str) -> str:
    return PAPER_COLUMNS.get((world, route), f"{world} {route}")


def _map_info(map_dir: Path) -> dict:
    manifest = json.loads((Path(map_dir) / "manifest.json").read_text(encoding="utf-8"))
    extra = manifest.get("extra", {})
    return {"dir": str(map_dir), "nodes": int(extra.get("nodes", len(manifest.get("nodes", [])))),
            "mean_arc_length_m": None if extra.get("mean_arc_length_m") is None
            else round(float(extra["mean_arc_length_m"]), 3),
            "loop_closures": len(extra.get("loop_closures", []))}


def _cell(s: dict) -> str:
    return f"{s['success_rate']:.2f} ({s['spl']:.2f})" if s["trials"] else "-"


def write_report(out: Path, main: Sequence[dict], study: Sequence[dict], *, specs: dict, maps: dict,
                 levels: Sequence[float], default_sparsity: float, sparsity_route: Optional[str],
                 sparsity_trials: int, command: str, seed: int, planned: Optional[int] = None,
                 planned_routes: Optional[Sequence[tuple[str, str]]] = None,
                 planned_methods: Optional[Sequence[str]] = None) -> dict:
    """Write every output; returns ``{"table": markdown table, "files": [paths]}``.

    ``planned``: the number of episodes the command plans; when more than ``main`` and ``study``
    hold, the report is marked partial (cells count the trials finished). ``planned_routes``
    (world, route) and ``planned_methods`` give the table's columns and rows (default: those of
    ``main``), so a partial report shows a "-" where nothing has finished yet."""
    out = Path(out)
    finished = len(main) + len(study)
    partial = {"finished": finished, "planned": planned} if planned is not None and finished < planned else None
    routes: list[tuple[str, str]] = [(Path(w).stem, r) for w, r in planned_routes or []]
    for e in main:
        if _route_id(e) not in routes:
            routes.append(_route_id(e))
    methods = [m for m in ("ours", "ours-hints", "ours-no-hints", "paper", "sptm") if m in (planned_methods or ())
               or any(e["trial"]["method"] == m for e in main)]
    summary = {f"{w}:{r}": {m: summarise_episodes([e for e in main if _route_id(e) == (w, r)
                                                    and e["trial"]["method"] == m]) for m in methods}
               for w, r in routes}

    # the sparsity study: the study's own episodes plus, for the default level, the main table's
    sparsity = {}
    if sparsity_route is not None:
        s_world, s_route = sparsity_route.rsplit(":", 1)
        for level in levels:
            eps = [e for e in study if e["trial"]["sparsity"] == level]
            if not eps and level == default_sparsity:
                eps = [e for e in main if _route_id(e) == (Path(s_world).stem, s_route)
                       and e["trial"]["method"] == "ours"][:sparsity_trials]
            if eps:
                info = _map_info(Path(eps[0]["trial"]["map_dir"]))
                info["dir"] = portable_trial({"map_dir": info["dir"]}, out)["map_dir"]
                sparsity[f"{level:g}"] = {"map": info,
                                          **summarise_episodes(eps)}

    deterministic = [{"trial": portable_trial(e["trial"], out), "goal_rivals": e.get("goal_rivals", []),
                      **{k: e[k] for k in ("metrics", "goal_node", "trajectory")}} for e in [*main, *study]]
    results = {"command": command, "seed": seed, "success_radius_m": 1.0,
               "maps": {w: {**_map_info(Path(d)), "dir": portable_trial({"map_dir": str(d)}, out)["map_dir"]}
                        for w, d in maps.items()},
               "summary": summary, "sparsity_route": sparsity_route, "sparsity": sparsity,
               **({"partial": partial} if partial else {}), "episodes": deterministic}
    timings = {e["trial"]["world"] + "/" + e["trial"]["route"] + "/" + e["trial"]["method"]
               + ("" if e["trial"]["sparsity"] is None else f"@{e['trial']['sparsity']:g}")
               + f"/{e['trial']['trial']}": e["timing"] for e in [*main, *study]}
    files = [write_text(out / "timings.json", json.dumps(timings, indent=2) + "\n")]

    table = _paper_table(routes, methods, summary)
    diagnoses = diagnose_episodes([*main, *study], out, specs)
    results["overall"] = overall(main, routes, methods, summary, diagnoses)
    files.insert(0, write_text(out / "results.json", json.dumps(results, indent=2) + "\n"))
    md = _markdown(command, table, routes, methods, summary, main, study, sparsity, sparsity_route,
                   results["maps"], [*main, *study], out, partial, diagnoses, results["overall"])
    files.append(write_text(out / "results.md", md))
    files += _plots(out, routes, methods, summary, main, specs, sparsity, diagnoses)
    return {"table": table, "files": files}


def _paper_table(routes, methods, summary) -> str:
    cols = [_column(w, r) for w, r in routes]
    lines = ["| Method | " + " | ".join(cols) + " | Average |", "|---" * (len(cols) + 2) + "|"]
    for m in methods:
        cells = [summary[f"{w}:{r}"][m] for w, r in routes]
        average = "-"                # an average needs every column
        if all(c["trials"] for c in cells):
            average = f"{np.mean([c['success_rate'] for c in cells]):.2f} ({np.mean([c['spl'] for c in cells]):.2f})"
        lines.append(f"| {METHOD_LABELS[m]} | " + " | ".join(_cell(c) for c in cells) + f" | {average} |")
    for m in methods:
        paper = PAPER_SR.get(m, {})
        if any(c in paper for c in cols):
            shown = [paper[c] for c in cols if c in paper]
            # the paper's own average for its four routes, else the mean over the columns shown
            average = (f"{paper['Average']:.2f}" if len(shown) == 4 == len(cols) else
                       f"{np.mean(shown):.2f}" if len(shown) == len(cols) else "-")
            lines.append(f"| {PAPER_LABELS[m]} (SR only) | " + " | ".join(
                f"{paper[c]:.2f}" if c in paper else "-" for c in cols) + f" | {average} |")
    return "\n".join(lines)


def diagnose_episodes(episodes: Sequence[dict], out: Path, specs: dict) -> dict:
    """``{id(episode): Diagnosis}`` for the episodes whose record holds the diagnosis made when
    they ran, or with a step log of all their steps in ``out`` and a map with true node poses
    (:mod:`robot.bench.diagnosis`); ``specs``: the world specs by name (the true goal of each
    route). The record comes first: a replay may have written the log since; but a record written
    before the diagnosis judged the nodes reached by odometry gives way to a log of the episode."""
    import sys

    from robot.bench.diagnosis import Diagnosis, StepLogError, diagnose, map_node_poses, read_step_log, route_goal
    from robot.bench.trials import Trial, step_log_path

    poses_of: dict = {}
    found = {}
    for e in episodes:
        if e.get("diagnosis") is not None:
            try:
                found[id(e)] = Diagnosis.from_dict(e["diagnosis"])
                if found[id(e)].odometry_judged or not found[id(e)].odometry_nodes:
                    continue
            except (KeyError, TypeError) as exc:
                print(f"note: {_episode_label(e)}: the diagnosis in its record is unreadable ({exc}); "
                      "reading its step log", file=sys.stderr)
        trial = Trial(**e["trial"])
        log = step_log_path(out, trial)
        if not log.is_file():
            continue
        if trial.map_dir not in poses_of:
            poses_of[trial.map_dir] = map_node_poses(Path(trial.map_dir))
        if poses_of[trial.map_dir] is None:
            continue
        try:
            steps = read_step_log(log)
            if len(steps) != e["metrics"]["steps"]:
                if id(e) in found:        # the record stands
                    continue
                print(f"note: {log} has {len(steps)} steps, the episode {e['metrics']['steps']}: a log of an earlier "
                      "run, left out of the report", file=sys.stderr)
                continue
            goal = route_goal(_spec_of(specs, Path(trial.world).stem), trial.route, e.get("goal_node"))
            found[id(e)] = diagnose(steps, poses_of[trial.map_dir], goal)
        except (StepLogError, KeyError) as exc:
            if id(e) not in found:
                print(f"note: {log}: left out of the report ({exc})", file=sys.stderr)
    return found


def _spec_of(specs: dict, world: str):
    return next((s for name, s in specs.items() if Path(name).stem == world or s.name == world), None)


def _episode_label(e: dict) -> str:
    t = e["trial"]
    level = "" if t.get("sparsity") is None else f" @{t['sparsity']:g}"
    return f"{Path(t['world']).stem} {t['route']}{level}"


def _markdown(command, table, routes, methods, summary, main, study, sparsity, sparsity_route, maps,
              episodes, out: Path, partial: Optional[dict] = None, diagnoses: Optional[dict] = None,
              over: Optional[dict] = None) -> str:
    diagnoses = diagnoses or {}
    trials = max((s["trials"] for r in summary.values() for s in r.values()), default=0)
    lines = ["# The paper's table in PyBullet", ""]
    if partial:
        lines += [f"**Partial: {partial['finished']} of the {partial['planned']} planned episodes have finished** "
                  "(the run was interrupted or is still running; the same command resumes it). Cells count the "
                  "trials finished (column `trials` below); an average needs every column.", ""]
    lines += [f"Made by `{command}` ({'up to ' if partial else ''}{trials} trials per route and method). "
             "Cells: success rate within "
             "1.0 m (SPL). SPL divides by the route's shortest length from the trial's start (within the "
             "route's corridor, corners cut: `sim/shortest_path.py`). Trials start at the route start "
             "offset by up to 0.3 m and 15 deg, under appearance seeds 1, 2, ... (the maps: seed 0).", "",
             table, "", "## Per route", "",
             "| route | method | trials | SR 1.0 m | SR 0.5 m | SPL | final distance mean / p50 / p90 (m) | "
             "mean re-localisations | collisions | failed trials |", "|---|---|---|---|---|---|---|---|---|---|"]
    for w, r in routes:
        for m in methods:
            s = summary[f"{w}:{r}"][m]
            if not s["trials"]:
                continue
            lines.append(f"| {w} {r} | {m} | {s['trials']} | {s['success_rate']:.2f} | {s['success_rate_0_5m']:.2f} | "
                         f"{s['spl']:.2f} | {s['mean_final_distance_m']} / {s['final_distance_p50_m']} / "
                         f"{s['final_distance_p90_m']} | {s['mean_relocalisations']:.2f} | "
                         f"{s['collisions']} | {', '.join(map(str, s['failures'])) or '-'} |")
    if over:
        lines += ["", *_overall_lines(over, routes)]
    lines += ["", "Maps (built from each world's walkthrough under appearance 0):", ""]
    for w, info in maps.items():
        lines.append(f"- {w}: {info['nodes']} nodes, mean arc {info['mean_arc_length_m']} m, "
                     f"{info['loop_closures']} loop closure(s)")
    failed = [e for e in main if not e["metrics"]["success"]]
    if failed:
        lines += ["", "## Failed episodes", ""]
        if diagnoses:
            lines += ["The last column reads the episode's step log against the map's true node poses "
                      "(`robot/bench/diagnosis.py`): the first node confirmed at a wrong place and where the robot "
                      "first got lost.", ""]
        lines += ["| episode | final distance (m) | end | goal node (ambiguous with) | reason | step log |",
                  "|---|---|---|---|---|---|"]
        for e in failed:
            t, m = e["trial"], e["metrics"]
            rivals = e.get("goal_rivals") or []
            goal = f"{e['goal_node']}" + (f" ({', '.join(map(str, rivals))})" if rivals else "")
            lines.append(f"| {Path(t['world']).stem}/{t['route']}/{t['method']}/{t['trial']} "
                         f"(appearance {t['appearance_seed']}) | {m['final_distance_m']} | {m['end']} | {goal} | "
                         f"{m['reason'][:150]} | {diagnoses[id(e)].summary() if id(e) in diagnoses else '-'} |")
    if sparsity:
        lines += ["", f"## Map sparsity ({sparsity_route}, our method)", "",
                  "| sparsity | nodes | mean arc (m) | SR | SPL | mean re-localisations |", "|---|---|---|---|---|---|"]
        for level, s in sparsity.items():
            lines.append(f"| {level} | {s['map']['nodes']} | {s['map']['mean_arc_length_m']} | "
                         f"{s['success_rate']:.2f} | {s['spl']:.2f} | {s['mean_relocalisations']:.2f} |")
    if diagnoses:
        from robot.bench.diagnosis import CONFIDENT, FAR_M, NEAR_M, PINNED_STEPS, TURNED_DEG, confirmation_counts

        lines += ["", "## Place recognition in the loop (step logs)", "",
                  "A confirmation is a node the navigator took as where the robot stood (localised at, or reached "
                  f"by driving); it is wrong when the robot stood more than {FAR_M:g} m from the node's true pose, or "
                  f"more than {NEAR_M:g} m from it facing more than {TURNED_DEG:g} deg away from the node's heading "
                  "(`robot/bench/diagnosis.py`). Pinned: episodes, and steps in them, where the robot commanded "
                  f"motion for {PINNED_STEPS} steps or more without moving (against a wall).", "",
                  "| route | method | episodes | confirmations | wrong | (re-)localisations | wrong | "
                  "median distance to the node (m) | pinned: episodes / steps |", "|---|---|---|---|---|---|---|---|---|"]
        groups: dict = {}
        for e in episodes:
            if id(e) in diagnoses:
                groups.setdefault((_episode_label(e), e["trial"]["method"]), []).append(diagnoses[id(e)])
        for (label, method), found in groups.items():
            c = confirmation_counts(found)
            lines.append(f"| {label} | {method} | {c['episodes']} | {c['confirmations']} | {c['wrong']} | "
                         f"{c['localisations']} | {c['wrong_localisations']} | {c['median_distance_m']} | "
                         f"{c['pinned_episodes']} / {c['pinned_steps']} |")
        counted = {key: confirmation_counts(found) for key, found in groups.items()}
        if any(c["belief_steps"] for c in counted.values()):
            lines += ["", "The belief over the map (`controllers/belief.py`), judged by the same rule: its mode at "
                      "every step, at the steps where its confidence reached "
                      f"{CONFIDENT:g}, and at the navigator's (re-)localisations.", "",
                      "| route | method | steps | mode right | confident | confident and right | "
                      "(re-)localisations | navigator wrong | belief wrong | both wrong |",
                      "|---|---|---|---|---|---|---|---|---|---|"]
            for (label, method), c in counted.items():
                if c["belief_steps"]:
                    lines.append(f"| {label} | {method} | {c['belief_steps']} | {c['belief_right']} | "
                                 f"{c['belief_confident']} | {c['belief_confident_right']} | "
                                 f"{c['belief_localisations']} | {c['wrong_localisations']} | "
                                 f"{c['belief_wrong_localisations']} | {c['both_wrong_localisations']} |")
        lines += odometry_lines(counted)
        if any(c["collisions"] for c in counted.values()):
            doings = ("turning in place", "driving", "retracing", "backing off", "standing")
            doings += tuple(sorted({d for c in counted.values() for d in c["collisions"]} - set(doings)))
            lines += ["", "Collisions (new contacts with walls and props, from the simulator) by what the robot was "
                      "commanded at the step each began (`robot/bench/diagnosis.py`).", "",
                      "| route | method | episodes | collisions | per episode | " + " | ".join(doings) + " |",
                      "|---|---|---|---|---|" + "---|" * len(doings)]
            for (label, method), c in counted.items():
                total = sum(c["collisions"].values())
                lines.append(f"| {label} | {method} | {c['episodes']} | {total} | {total / c['episodes']:.2f} | "
                             + " | ".join(str(c["collisions"].get(d, 0)) for d in doings) + " |")
    timed = [e["timing"] for e in episodes if e["timing"]["ms_per_step"]["total_ms"] > 0]
    if timed:
        keys = ("read_ms", "describe_ms", "decide_ms", "tick_ms", "total_ms")
        med = {k: float(np.median([t["ms_per_step"][k] for t in timed])) for k in keys}
        lines += ["", "## Wall time (median over episodes of the mean per step)", "",
                  f"read (render) {med['read_ms']:.0f} ms, describe {med['describe_ms']:.0f} ms, decide "
                  f"{med['decide_ms']:.1f} ms, physics {med['tick_ms']:.0f} ms; total {med['total_ms']:.0f} ms "
                  f"per 100 ms control period ({len(timed)} episodes; `timings.json`)."]
    lines += ["", "Pictures: `sr.png`, `trajectories_<world>_<route>.png`"
              + (", `sparsity.png`" if sparsity else "") + "; one trace per episode in `traces/`.", ""]
    return "\n".join(lines)


def odometry_lines(counted: dict) -> list[str]:
    """The report's table of driving on by odometry (``supervisor.odometry_max_m``) from
    ``{(route, method): confirmation_counts(...)}``; no lines where it never acted. Where the logs
    hold the belief, its mode at those nodes is judged beside the arc length's node."""
    if not any(c["odometry_steps"] for c in counted.values()):
        return []
    belief = any(c["belief_odometry_nodes"] for c in counted.values())
    lines = ["", "Driving on by odometry (`supervisor.odometry_max_m`): the episodes and steps where the views "
             "matched nothing and the supervisor drove on by the map's arc lengths, the nodes it took as "
             "reached so, and how many of them were at a wrong place, of those judged (an episode's record "
             "written before the diagnosis judged them counts only with its step log; routes and methods where "
             "it never acted are left out)" + ("; beside them, the belief's mode at the same steps." if belief else "."), "",
             "| route | method | episodes | driving on: episodes | steps | nodes reached by odometry | wrong |"
             + (" belief wrong | both wrong |" if belief else ""),
             "|---|---|---|---|---|---|---|" + ("---|---|" if belief else "")]
    for (label, method), c in counted.items():
        if c["odometry_steps"]:
            lines.append(f"| {label} | {method} | {c['episodes']} | {c['odometry_episodes']} | "
                         f"{c['odometry_steps']} | {c['odometry_nodes']} | "
                         f"{c['odometry_nodes_wrong']} of {c['odometry_nodes_judged']} |"
                         + (f" {c['belief_wrong_odometry_nodes']} | {c['both_wrong_odometry_nodes']} |"
                            if belief else ""))
    return lines


def _plots(out: Path, routes, methods, summary, main, specs, sparsity, diagnoses: Optional[dict] = None) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    cols = [_column(w, r) for w, r in routes]
    fig, ax = plt.subplots(figsize=(max(6.0, 1.8 + 1.6 * len(cols)), 4.2))
    width = 0.8 / max(1, len(methods))
    for k, m in enumerate(methods):
        x = np.arange(len(cols)) + (k - (len(methods) - 1) / 2) * width
        sr = [summary[f"{w}:{r}"][m].get("success_rate", np.nan) for w, r in routes]   # nan: none finished
        ax.bar(x, sr, width * 0.9, color=COLORS[m], label=METHOD_LABELS[m])
        paper = [PAPER_SR.get(m, {}).get(c) for c in cols]
        px = [xi for xi, p in zip(x, paper) if p is not None]
        ax.scatter(px, [p for p in paper if p is not None], marker="_", s=400, color="black", zorder=3,
                   label="paper" if k == 0 else None)
    ax.set_xticks(np.arange(len(cols)), cols)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("success rate (1.0 m)")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, frameon=False)
    ax.set_title("Success rate per route (black ticks: the paper's numbers)", fontsize=9)
    fig.tight_layout()
    files.append(out / "sr.png")
    save_figure(fig, files[-1], dpi=120)
    plt.close(fig)

    from sim.topdown import render_topdown

    for w, r in routes:
        spec = _spec_of(specs, w)
        if spec is None:
            continue
        panels = []
        for m in methods:
            td = render_topdown(spec, appearance_seed=0, show_routes=False)
            route = spec.routes.evaluation[r]
            td.draw_polyline([route.start[:2], *route.waypoints, route.goal[:2]], (160, 160, 160), 6)
            ok = 0
            for e in main:
                if _route_id(e) != (w, r) or e["trial"]["method"] != m:
                    continue
                good = e["metrics"]["success"]
                ok += good
                td.draw_polyline(e["trajectory"], (40, 160, 60) if good else (220, 40, 40), 2)
            for e in main:      # wrong confirmations: where the robot stood -> the node it was taken for
                if _route_id(e) == (w, r) and e["trial"]["method"] == m and id(e) in (diagnoses or {}):
                    for c in diagnoses[id(e)].wrong:
                        td.draw_polyline([(c.x_m, c.y_m), (c.node_x_m, c.node_y_m)], (240, 150, 20), 1)
                        td.draw_marker(c.x_m, c.y_m, (240, 150, 20), shape="diamond", size_px=4)
            td.draw_marker(*route.goal[:2], (0, 0, 0), label="goal", shape="square")
            td.draw_marker(*route.start[:2], (0, 0, 0), label="start", shape="circle")
            panels.append((m, td.image, ok))
        fig, axes = plt.subplots(len(panels), 1, figsize=(9, 4.2 * len(panels)), squeeze=False)
        for ax, (m, img, ok) in zip(axes[:, 0], panels):
            n = summary[f"{w}:{r}"][m]["trials"]
            ax.imshow(img)
            ax.set_axis_off()
            ax.set_title(f"{w} {r}: {METHOD_LABELS[m]}: {ok}/{n} successes (green), failures red"
                         + ("; orange: wrong confirmations" if diagnoses else ""), fontsize=9)
        fig.tight_layout()
        files.append(out / f"trajectories_{w}_{r}.png")
        save_figure(fig, files[-1], dpi=110)
        plt.close(fig)

    if sparsity:
        levels = list(sparsity)
        fig, ax = plt.subplots(figsize=(4.8, 3.4))
        x = [float(v) for v in levels]
        ax.plot(x, [sparsity[v]["success_rate"] for v in levels], "o-", color=COLORS["ours"], label="SR")
        ax.set_xlabel("map sparsity (calibrated mapping)")
        ax.set_ylabel("success rate")
        ax.set_ylim(0, 1.05)
        ax2 = ax.twinx()
        ax2.plot(x, [sparsity[v]["mean_relocalisations"] for v in levels], "s--", color="grey",
                 label="re-localisations")
        ax2.set_ylabel("mean re-localisations per episode")
        for v in levels:
            ax.annotate(f"{sparsity[v]['map']['nodes']} nodes", (float(v), sparsity[v]["success_rate"]),
                        textcoords="offset points", xytext=(0, -14), ha="center", fontsize=7)
        fig.legend(fontsize=7, loc="lower right")
        fig.tight_layout()
        files.append(out / "sparsity.png")
        save_figure(fig, files[-1], dpi=120)
        plt.close(fig)
    return files
