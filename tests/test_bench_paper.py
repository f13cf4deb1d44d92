"""The paper harness (python -m robot.bench paper) end to end on the tiny world, and its parts."""

import argparse
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from controllers.navigator import NavState
from robot.bench import paper
from robot.bench.trials import MAX_OFFSET_M, MAX_OFFSET_YAW_DEG, plan_trials
from sim.worlds import load_world

pytestmark = pytest.mark.slow      # the paper harness on the tiny world: maps, a baseline, episodes

TINY = str(Path(__file__).parent / "data" / "tiny_world.yaml")


def _args(*argv):
    parser = argparse.ArgumentParser()
    paper.add_arguments(parser)
    return parser.parse_args(list(argv))


def test_trials_share_conditions_across_methods_and_do_not_depend_on_other_routes():
    spec = load_world("hospital")
    a = plan_trials(spec, "hospital", "easy", ["ours", "sptm"], 6, 0, "m", lambda x, y: 10.0)
    b = plan_trials(spec, "hospital", "easy", ["ours"], 6, 0, "m", lambda x, y: 10.0)
    c = plan_trials(spec, "hospital", "easy", ["ours"], 6, 1, "m", lambda x, y: 10.0)
    ours = [t for t in a if t.method == "ours"]
    sptm = [t for t in a if t.method == "sptm"]
    assert [(t.start_x_m, t.start_y_m, t.start_yaw_deg, t.appearance_seed) for t in ours] == \
           [(t.start_x_m, t.start_y_m, t.start_yaw_deg, t.appearance_seed) for t in sptm] == \
           [(t.start_x_m, t.start_y_m, t.start_yaw_deg, t.appearance_seed) for t in b]
    assert [t.start_x_m for t in c] != [t.start_x_m for t in b]          # the base seed matters
    sx, sy, syaw = spec.routes.evaluation["easy"].start
    for t in b:
        assert math.dist((t.start_x_m, t.start_y_m), (sx, sy)) <= MAX_OFFSET_M + 1e-3
        assert abs(t.start_yaw_deg - syaw) <= MAX_OFFSET_YAW_DEG + 1e-3
    assert len({t.appearance_seed for t in b}) == 6 and 0 not in {t.appearance_seed for t in b}
    assert len({(t.start_x_m, t.start_y_m) for t in b}) == 6


@pytest.mark.parametrize("argv, message", [
    (["--routes", "hospital"], "expected WORLD:ROUTE"),
    (["--routes", "hospital:nowhere"], "has no such route"),
    (["--routes", "atlantis:easy"], "atlantis"),
    (["--methods", "ours,magic"], "--methods"),
    (["--trials", "0"], "--trials"),
    (["--sparsity", "0.5,2"], "--sparsity"),
    (["--workers", "0"], "--workers"),
])
def test_bad_arguments_exit_2_naming_the_option(argv, message, tmp_path, capsys):
    assert paper.main(_args(*argv, "--out", str(tmp_path))) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "results.json").exists()


@pytest.fixture(scope="module")
def serial_run(tmp_path_factory):
    """The harness on the tiny world: one trial of both methods, and the sparsity study. The
    baseline's head is trained on a few short expert drives in the tiny world itself (the
    harness would train it on the hospital, minutes)."""
    from robot.baseline import train_baseline
    from robot.baseline.exploration import ExplorationConfig
    from robot.settings import load_stack_config

    out = tmp_path_factory.mktemp("paper_serial")
    map_dir = paper.ensure_map(TINY, 0.5, load_stack_config(None), out, progress=False)
    head = train_baseline(TINY, map_dir, out / "tiny_head.pt", progress=False,
                          exploration=ExplorationConfig(episodes=6, steps_per_episode=15, appearances=1))
    argv = ["--routes", f"{TINY}:short", "--methods", "ours,sptm", "--trials", "1", "--sparsity", "0.5,0.75",
            "--sparsity-route", f"{TINY}:short", "--workers", "1", "--quiet", "--out", str(out),
            "--baseline", str(head), "--step-logs"]
    assert paper.main(_args(*argv)) == 0
    return out, argv


def test_the_harness_writes_results_table_and_pictures(serial_run):
    out, _ = serial_run
    results = json.loads((out / "results.json").read_text())
    episodes = results["episodes"]
    # one main episode per method, plus one study episode at sparsity 0.75 (0.5 reuses the main one)
    assert [(e["trial"]["method"], e["trial"]["sparsity"]) for e in episodes] == \
        [("ours", None), ("sptm", None), ("ours", 0.75)]
    main, baseline = episodes[0], episodes[1]
    from robot.settings import load_stack_config
    assert load_stack_config(out / "config.yaml") == load_stack_config(None)    # what replay runs with
    # both methods faced the same start and conditions
    for key in ("start_x_m", "start_y_m", "start_yaw_deg", "appearance_seed", "shortest_length_m"):
        assert main["trial"][key] == baseline["trial"][key]
    assert main["trial"]["appearance_seed"] == 1 and main["trial"]["offset_m"] <= 0.3
    assert 0 < main["trial"]["shortest_length_m"] <= 4.5 + 0.3
    m = main["metrics"]
    # an episode either drove, or ended in an error before driving (e.g. the tiny room's view
    # placed the robot past the goal: unreachable), recorded as a failure where it stood
    assert m["final_distance_m"] is not None and "wall_time_s" not in m
    if m["steps"] > 0:
        assert len(main["trajectory"]) >= 2
    else:
        assert m["end"] == "error" and not m["success"] and m["reason"] and len(main["trajectory"]) == 1
    summary = results["summary"]["tiny_world:short"]["ours"]
    assert summary["trials"] == 1 and summary["success_rate"] == float(m["success"])
    assert results["summary"]["tiny_world:short"]["sptm"]["trials"] == 1
    assert set(results["sparsity"]) == {"0.5", "0.75"}
    assert results["sparsity"]["0.75"]["map"]["nodes"] < results["sparsity"]["0.5"]["map"]["nodes"]
    timings = json.loads((out / "timings.json").read_text())
    assert len(timings) == 3 and all(t["wall_time_s"] >= 0 for t in timings.values())
    md = (out / "results.md").read_text()
    assert "| Method | tiny_world short | Average |" in md and "## Map sparsity" in md
    assert "Ours (" in md and "SPTM-style baseline" in md
    for name in ("sr.png", "trajectories_tiny_world_short.png", "sparsity.png"):
        assert (out / name).stat().st_size > 5000
    # a trace picture for every episode that drove (one that ended in an error before driving has none)
    drove = {Path(e["trial"]["trace_png"]).name for e in episodes if e["metrics"]["steps"] > 0}
    assert drove and {p.name for p in (out / "traces").glob("*.png")} == drove
    # --step-logs: a per-step log of every episode that drove, one line per step
    for e in episodes:
        log = paper.step_log_path(out, paper.Trial(**e["trial"]))
        if e["metrics"]["steps"] > 0:
            assert len(log.read_text().splitlines()) == e["metrics"]["steps"]
    # ... read against the map's true node poses in a section of results.md
    from robot.bench.diagnosis import diagnose, map_node_poses, read_step_log

    ours_log = paper.step_log_path(out, paper.Trial(**main["trial"]))
    if m["steps"] > 0 and diagnose(read_step_log(ours_log), map_node_poses(out / main["trial"]["map_dir"])).confirmations:
        assert "## Place recognition in the loop (step logs)" in md and "| tiny_world short | ours | 1 |" in md
        belief = md.split("The belief over the map")[1]
        assert f"| tiny_world short | ours | {m['steps']} |" in belief       # judged at every step


def test_parallel_workers_give_the_same_results_and_reruns_resume(serial_run, tmp_path):
    out, argv = serial_run
    # the same command with 2 workers in another folder (maps copied: mapping is not the point)
    other = tmp_path / "parallel"
    shutil.copytree(out / "maps", other / "maps")
    shutil.copy(out / "tiny_head.pt", other / "tiny_head.pt")
    parallel_argv = [a.replace(str(out), str(other)) for a in argv]
    parallel_argv[parallel_argv.index("--workers") + 1] = "2"
    assert paper.main(_args(*parallel_argv)) == 0

    def comparable(folder):
        data = json.loads((folder / "results.json").read_text())
        data.pop("command")
        return data
    assert comparable(other) == comparable(out)

    # a re-run reuses the finished episodes (their files are not rewritten)
    stamps = {p: p.stat().st_mtime_ns for p in (out / "episodes").glob("*.json")}
    assert len(stamps) == 3
    assert paper.main(_args(*argv)) == 0
    assert {p: p.stat().st_mtime_ns for p in (out / "episodes").glob("*.json")} == stamps
    assert comparable(out) == comparable(other)


def test_report_only_reports_the_finished_episodes_and_runs_none(serial_run, tmp_path, capsys):
    out, argv = serial_run           # episodes are reused only where they ran (their trial names the map)
    report_argv = argv + ["--report-only"]
    sptm_episode = next((out / "episodes").glob("*sptm*.json"))
    aside = tmp_path / sptm_episode.name
    shutil.move(sptm_episode, aside)           # as if the run had been interrupted before it
    try:
        assert paper.main(_args(*report_argv)) == 0
        assert not sptm_episode.exists()       # nothing ran
        results = json.loads((out / "results.json").read_text())
        assert results["partial"] == {"finished": 2, "planned": 3}
        assert "--report-only" not in results["command"]
        assert [e["trial"]["method"] for e in results["episodes"]] == ["ours", "ours"]
        assert results["summary"]["tiny_world:short"]["sptm"] == {"trials": 0}
        md = (out / "results.md").read_text()
        assert "**Partial: 2 of the 3 planned episodes have finished**" in md
        baseline_row = next(line for line in md.splitlines() if line.startswith("| SPTM-style baseline"))
        assert baseline_row.endswith("| - | - |")      # no finished trial: no cell, no average
        assert "partial" in capsys.readouterr().out
    finally:
        shutil.move(aside, sptm_episode)
    # the complete set of episodes is not partial
    assert paper.main(_args(*report_argv)) == 0
    assert "partial" not in json.loads((out / "results.json").read_text())

    # elsewhere: no map, or maps but nothing finished: exit 2 naming what is missing, no report
    other = tmp_path / "other"
    other_argv = [a.replace(str(out), str(other)) for a in report_argv]
    assert paper.main(_args(*other_argv)) == 2
    assert "no map in" in capsys.readouterr().err
    shutil.copytree(out / "maps", other / "maps")
    shutil.copy(out / "tiny_head.pt", other / "tiny_head.pt")
    assert paper.main(_args(*other_argv)) == 2
    assert "no finished episode" in capsys.readouterr().err
    assert not (other / "results.json").exists()


def test_episodes_keep_their_diagnosis_and_the_report_reads_it_without_the_logs(serial_run, capsys):
    """An episode run with --step-logs keeps its step log's diagnosis in its record (the logs are
    not committed); the report reads the record first, a log only for a record without one."""
    from robot.bench.diagnosis import Diagnosis, diagnose, map_node_poses, read_step_log

    out, argv = serial_run
    ours = next((out / "episodes").glob("*_ours_0.json"))
    episode = json.loads(ours.read_text())
    ours_log = paper.step_log_path(out, paper.Trial(**episode["trial"]))
    if episode["metrics"]["steps"] > 0:
        found = diagnose(read_step_log(ours_log), map_node_poses(out / episode["trial"]["map_dir"]))
        assert Diagnosis.from_dict(episode["diagnosis"]).confirmations == found.confirmations
    records = {p: p.read_text() for p in (out / "episodes").glob("*.json")}
    logs = sorted((out / "replays").glob("*.steps.jsonl"))
    assert logs
    kept = {log: log.read_text() for log in logs}
    try:
        for log in logs:                # as if the episodes had run again since, without --step-logs
            log.write_text(kept[log].splitlines()[0] + "\n")
        assert paper.main(_args(*argv, "--report-only")) == 0
        assert "a log of an earlier run" not in capsys.readouterr().err       # the records hold theirs
        assert ("## Place recognition in the loop" in (out / "results.md").read_text()) == any(
            json.loads(text).get("diagnosis", {}).get("confirmations") for text in records.values())
        for path, text in records.items():      # records of older runs hold no diagnosis
            path.write_text(json.dumps({k: v for k, v in json.loads(text).items() if k != "diagnosis"}))
        assert paper.main(_args(*argv, "--report-only")) == 0
        err = capsys.readouterr().err
        assert "a log of an earlier run, left out of the report" in err and logs[0].name in err
        assert "## Place recognition in the loop" not in (out / "results.md").read_text()
        for log, text in kept.items():
            log.write_text(text)
        # a confirmation moved 5 m from where the robot stood counts as wrong, in the table and the pictures
        steps = [json.loads(line) for line in kept[ours_log].splitlines()]
        found = diagnose(steps, map_node_poses(out / episode["trial"]["map_dir"]))   # relative to the run
        right = next((c for c in found.confirmations if not c.is_wrong()), None)
        if right is not None:
            steps[right.step]["x_m"] += 5.0
            ours_log.write_text("".join(json.dumps(e) + "\n" for e in steps))
            assert paper.main(_args(*argv, "--report-only")) == 0
            section = (out / "results.md").read_text().split("## Place recognition in the loop")[1]
            row = next(line for line in section.splitlines() if line.startswith("| tiny_world short | ours |"))
            assert int(row.split(" | ")[4]) == len(found.wrong) + 1      # one more wrong confirmation
    finally:
        for log, text in kept.items():
            log.write_text(text)
        for path, text in records.items():
            path.write_text(text)
    assert paper.main(_args(*argv, "--report-only")) == 0


def _replay_args(*argv):
    from robot.bench import replay

    parser = argparse.ArgumentParser()
    replay.add_arguments(parser)
    return replay, parser.parse_args([str(a) for a in argv])


def test_replay_reproduces_an_episode_with_a_step_log(serial_run, tmp_path, capsys):
    out, _ = serial_run
    episode = next((out / "episodes").glob("*_ours_0.json"))
    recorded = json.loads(episode.read_text())
    log = tmp_path / "steps.jsonl"
    replay, args = _replay_args(episode, "--log", log, "--quiet", "--events", "5")
    assert replay.main(args) == 0
    printed = capsys.readouterr().out
    assert "reproduced" in printed and "NOT" not in printed
    assert "nodes confirmed" in printed        # the step log read against the map's true node poses
    lines = [json.loads(line) for line in log.read_text().splitlines()]
    assert len(lines) == recorded["metrics"]["steps"] > 0
    assert [e["step"] for e in lines] == list(range(len(lines)))
    assert lines[0]["state"] in ("localising", "navigating")
    # the last logged state says how the episode ended: arrived, failed, or still going when the
    # step budget ran out
    end = recorded["metrics"]["end"]
    final = {NavState.ARRIVED.value, NavState.FAILED.value}
    assert lines[-1]["state"] == end if end in final else lines[-1]["state"] not in final, end
    # the simulator's collision count, never falling, ends at the episode's collisions
    counts = [e["collisions"] for e in lines]
    assert counts == sorted(counts) and counts[-1] == recorded["metrics"]["collisions"]
    first = recorded["trajectory"][1] if len(recorded["trajectory"]) > 1 else recorded["trajectory"][0]
    assert math.dist((lines[min(len(lines) - 1, 9)]["x_m"], lines[min(len(lines) - 1, 9)]["y_m"]), first) < 1e-6
    assert not list(tmp_path.glob(".steps.jsonl.tmp-*"))

    # an episode whose record differs (as if the code had changed since): exit 1, naming what differs
    tampered = tmp_path / "run" / "episodes" / episode.name
    tampered.parent.mkdir(parents=True)
    recorded["metrics"]["steps"] += 7
    tampered.write_text(json.dumps(recorded))
    replay, args = _replay_args(tampered, "--quiet", "--events", "0")
    assert replay.main(args) == 1
    assert "NOT reproduced (steps" in capsys.readouterr().out
    assert (tmp_path / "run" / "replays" / (episode.stem + ".steps.jsonl")).is_file()   # the default log


def test_a_run_folder_replays_elsewhere_and_rebuilds_a_missing_map(serial_run, tmp_path, capsys):
    """Episode files name their map relative to the run folder; a copy of the episodes alone (a
    committed run, a fresh clone) replays by building the map again, the same map, the same episode."""
    import shutil

    out, _ = serial_run
    episode = next((out / "episodes").glob("*_ours_0.json"))
    trial = json.loads(episode.read_text())["trial"]
    assert trial["map_dir"] == "maps/tiny-s0.5" and not Path(trial["trace_png"] or "x").is_absolute()
    moved = tmp_path / "moved"
    shutil.copytree(out / "episodes", moved / "episodes")
    # the run's record naming a field the code has removed since: a note, and the replay goes on
    (moved / "config.yaml").write_text((out / "config.yaml").read_text() + "retired_addition: {enabled: true}\n")
    replay, args = _replay_args(moved / "episodes" / episode.name, "--quiet", "--events", "0")
    assert replay.main(args) == 0
    captured = capsys.readouterr()
    assert "building it again" in captured.err and "reproduced" in captured.out and "NOT" not in captured.out
    assert "names retired_addition, which the code no longer has" in captured.err
    assert (moved / "maps" / "tiny-s0.5" / "manifest.json").is_file()
    original = json.loads((out / "maps" / "tiny-s0.5" / "manifest.json").read_text())
    rebuilt = json.loads((moved / "maps" / "tiny-s0.5" / "manifest.json").read_text())
    assert rebuilt["files"] == original["files"]          # byte-identical contents (per-file digests)
    # a map that is missing and not one the harness builds is named, exit 2
    shutil.copy(out / "config.yaml", moved / "config.yaml")
    odd = json.loads(episode.read_text())
    odd["trial"]["map_dir"] = "/nowhere/custom-map"
    (moved / "episodes" / "odd.json").write_text(json.dumps(odd))
    replay, args = _replay_args(moved / "episodes" / "odd.json", "--quiet")
    assert replay.main(args) == 2
    err = capsys.readouterr().err
    assert "/nowhere/custom-map is missing" in err and len(err.strip().splitlines()) == 1


def test_the_belief_runs_offline_over_the_views_as_it_ran_in_the_loop(serial_run, tmp_path, capsys):
    """``--step-logs`` writes the views beside each step log; ``bench belief`` runs the filter over
    them and, with the run's own settings, finds the belief the loop logged."""
    from robot.bench import belief as bench_belief
    from robot.bench.belief import load_recorded, run_filter
    from robot.episode.step_log import read_views
    from robot.settings import load_stack_config

    out, _ = serial_run
    run = tmp_path / "run"
    for part in ("episodes", "maps", "replays"):
        shutil.copytree(out / part, run / part)
    episode = next((run / "episodes").glob("*_ours_0.json"))
    steps = json.loads(episode.read_text())["metrics"]["steps"]
    views = read_views(run / "replays" / (episode.stem + ".views.npz"))
    assert views.similarities.shape == (steps, views.node_ids.size) and np.isfinite(views.odometry).all()

    recorded = load_recorded(episode, load_stack_config(None), progress=False)
    logged = [s["belief_top"][0][0] for s in recorded.steps]
    offline = [s["belief_top"][0][0] for s in run_filter(recorded, load_stack_config(None).navigation.belief)]
    assert np.mean(np.equal(logged, offline)) >= 0.98        # float16 views: rare ties may differ

    parser = argparse.ArgumentParser()
    bench_belief.add_arguments(parser)
    table = tmp_path / "belief.json"
    args = parser.parse_args([str(episode), "--set", "heading_bins=1,8", "--json", str(table), "--quiet"])
    assert bench_belief.main(args) == 0
    printed = capsys.readouterr().out
    assert "| heading_bins=1 |" in printed and "| heading_bins=8 |" in printed
    results = json.loads(table.read_text())["results"]
    assert [r["setting"]["heading_bins"] for r in results] == [1, 8]
    assert all(r["belief_steps"] == steps for r in results)

    (run / "replays" / (episode.stem + ".views.npz")).unlink()
    args = parser.parse_args([str(episode), "--quiet"])
    assert bench_belief.main(args) == 2
    assert "replay it first" in capsys.readouterr().err


@pytest.mark.parametrize("make, message", [
    (lambda d, out: d / "missing.json", "cannot read"),
    (lambda d, out: out / "results.json", "not an episode file"),
    (lambda d, out: (d / "bad.json").write_text("{not json") and d / "bad.json", "not JSON"),
])
def test_replay_refuses_what_is_not_an_episode(serial_run, tmp_path, capsys, make, message):
    out, _ = serial_run
    path = make(tmp_path, out)
    replay, args = _replay_args(path, "--quiet")
    assert replay.main(args) == 2
    err = capsys.readouterr().err
    assert message in err and str(path) in err


def test_ours_with_turn_hints_turns_by_the_maps_odometry(serial_run, tmp_path):
    from dataclasses import replace as dc_replace

    from maps.store import load_map
    from robot.bench.trials import Trial, resolved_trial, run_trial

    out, _ = serial_run
    episode = json.loads(next((out / "episodes").glob("*_ours_0.json")).read_text())
    sx, sy, syaw = load_world(TINY).routes.evaluation["short"].start
    # under the map's own appearance from the route's start, so that it certainly drives
    trial = dc_replace(Trial(**resolved_trial(episode["trial"], out)), method="ours-hints", trace_png=None,
                       appearance_seed=0,
                       start_x_m=sx, start_y_m=sy, start_yaw_deg=syaw)
    assert load_map(trial.map_dir).topomap.odom_headings is not None   # the harness's maps carry them
    log = tmp_path / "hints.jsonl"
    result = run_trial(trial, step_log=str(log))
    assert result["trial"]["method"] == "ours-hints" and result["metrics"]["steps"] > 0
    reasons = [json.loads(line)["reason"] for line in log.read_text().splitlines()]
    assert any("the map turned" in r for r in reasons)
    # the ablation without them steers by the thirds alone
    result = run_trial(dc_replace(trial, method="ours-no-hints"), step_log=str(log))
    assert result["trial"]["method"] == "ours-no-hints" and result["metrics"]["steps"] > 0
    assert not any("the map turned" in json.loads(line)["reason"] for line in log.read_text().splitlines())


def test_episodes_record_the_configuration_and_another_one_is_not_reused(serial_run, tmp_path):
    from dataclasses import replace as dc_replace

    from robot.bench.trials import Trial, config_digest
    from robot.settings import load_stack_config

    out, _ = serial_run
    default = load_stack_config(None)
    changed_yaml = tmp_path / "changed.yaml"
    changed_yaml.write_text("navigation:\n  max_relocalisations: 2\n")
    changed = load_stack_config(changed_yaml)
    assert config_digest(default) == config_digest(load_stack_config(None))    # a fingerprint of values
    assert config_digest(changed) != config_digest(default)

    episode = json.loads(next((out / "episodes").glob("*_ours_0.json")).read_text())
    trial = Trial(**episode["trial"])
    assert trial.config_digest == config_digest(default)
    assert paper._reusable(out, trial) is not None
    # the same trial under another configuration must run again, not reuse the old episode
    assert paper._reusable(out, dc_replace(trial, config_digest=config_digest(changed))) is None


def test_the_papers_method_runs_as_its_own_method(serial_run, tmp_path):
    from dataclasses import replace as dc_replace

    from robot.bench.trials import Trial, resolved_trial, run_trial

    out, _ = serial_run
    episode = json.loads(next((out / "episodes").glob("*_ours_0.json")).read_text())
    sx, sy, syaw = load_world(TINY).routes.evaluation["short"].start
    trial = dc_replace(Trial(**resolved_trial(episode["trial"], out)), method="paper", trace_png=None,
                       appearance_seed=0, start_x_m=sx, start_y_m=sy, start_yaw_deg=syaw)
    log = tmp_path / "paper.jsonl"
    result = run_trial(trial, step_log=str(log))
    assert result["trial"]["method"] == "paper" and result["metrics"]["steps"] > 0
    reasons = [json.loads(line)["reason"] for line in log.read_text().splitlines()]
    assert len(reasons) == result["metrics"]["steps"]
    for ours in ("the map turned", "second look", "ambiguous: margin"):
        assert not any(ours in r for r in reasons), ours


def _comparable(folder: Path) -> dict:
    data = json.loads((folder / "results.json").read_text())
    data.pop("command")
    return data


def _differences(got: dict, want: dict) -> list[str]:
    """Where two runs' results differ: per episode (by its trial key) the metrics that differ, then
    any other top-level field; empty when they are the same."""
    def by_key(data: dict) -> dict:
        return {f"{e['trial']['route']}/{e['trial']['method']}/{e['trial']['trial']}/{e['trial']['sparsity']}": e
                for e in data["episodes"]}

    found = []
    mine, theirs = by_key(got), by_key(want)
    for key in sorted(set(mine) | set(theirs)):
        a, b = mine.get(key), theirs.get(key)
        if a is None or b is None:
            found.append(f"{key}: only in {'the second' if a is None else 'the first'} run")
        elif a != b:
            fields = sorted(k for k in set(a.get("metrics", {})) | set(b.get("metrics", {}))
                            if a["metrics"].get(k) != b["metrics"].get(k))
            found.append(f"{key}: metrics {fields or 'equal'}; other fields "
                         f"{sorted(k for k in set(a) | set(b) if k != 'metrics' and a.get(k) != b.get(k))}")
    found += [f"{k} differs" for k in sorted(set(got) | set(want)) if k != "episodes" and got.get(k) != want.get(k)]
    return found


def _copy_inputs(out: Path, other: Path, argv: list[str], workers: list[str]) -> list[str]:
    """The serial run's command for another folder (maps and head copied: mapping is not the point)."""
    shutil.copytree(out / "maps", other / "maps")
    shutil.copy(out / "tiny_head.pt", other / "tiny_head.pt")
    moved = [a.replace(str(out), str(other)) for a in argv]
    at = moved.index("--workers")
    return moved[:at] + workers + moved[at + 2:]


def _outputs(folder: Path) -> dict:
    """Trace pictures, step logs and their views by name (step logs by their line count: they hold
    timings)."""
    found = {p.name: p.stat().st_size > 5000 for p in (folder / "traces").glob("*")}
    found.update({p.name: len(p.read_text().splitlines()) if p.suffix == ".jsonl" else p.stat().st_size > 0
                  for p in (folder / "replays").glob("*")})
    return found


def test_ray_gives_the_same_results_as_a_serial_run(serial_run, tmp_path):
    """A local Ray instance of 2 CPUs; maps, head and world file travel through the object store and
    the traces and step logs come back to the driver."""
    out, argv = serial_run
    other = tmp_path / "ray"
    assert paper.main(_args(*_copy_inputs(out, other, argv, ["--ray", "--workers", "2"]))) == 0
    assert _differences(_comparable(other), _comparable(out)) == []
    assert _comparable(other) == _comparable(out)        # the episodes in the same order too
    assert _outputs(other) == _outputs(out) and len(_outputs(out)) >= 3
    timings = json.loads((other / "timings.json").read_text())
    assert len(timings) == 3 and all(":" in t["worker"] for t in timings.values())
    import ray
    assert not ray.is_initialized()           # the instance it started is shut down


def _episode_workers() -> list[int]:
    """Process ids of Ray workers running an episode (Ray names the process after its task)."""
    pids = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and (proc / "cmdline").read_bytes().startswith(b"ray::_episode_task"):
                pids.append(int(proc.name))
        except OSError:
            continue
    return pids


def test_an_episode_whose_worker_is_killed_runs_again_and_the_results_hold(serial_run, tmp_path):
    """SIGKILL of a worker in the middle of an episode: Ray reruns the task, the run finishes with
    the serial run's results, and no half-written output is left (shared folder: workers write
    there themselves)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out, argv = serial_run
    other = tmp_path / "ray-killed"
    command = _copy_inputs(out, other, argv, ["--ray", "--workers", "2", "--ray-shared"])
    proc = subprocess.Popen([sys.executable, "-m", "robot.bench", "paper", *command],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed = None
    try:
        deadline = time.monotonic() + 240
        while killed is None and time.monotonic() < deadline and proc.poll() is None:
            running = _episode_workers()
            if running:
                time.sleep(2.0)                # into the episode: the world and the map are loaded
                if running[0] in _episode_workers():
                    os.kill(running[0], signal.SIGKILL)
                    killed = running[0]
            time.sleep(0.2)
        stdout, stderr = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert killed is not None, "no episode task was seen running"
    assert proc.returncode == 0, stderr
    assert _differences(_comparable(other), _comparable(out)) == []
    assert _comparable(other) == _comparable(out)        # the episodes in the same order too
    timings = json.loads((other / "timings.json").read_text())
    assert str(killed) not in {t["worker"].rsplit(":", 1)[1] for t in timings.values()}
    assert _outputs(other) == _outputs(out)
    assert not [p for d in ("traces", "replays", "episodes") for p in (other / d).iterdir() if p.name.startswith(".")]
