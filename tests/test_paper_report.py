"""The paper report's summaries, from hand-made episodes (no simulator)."""

from robot.bench.paper_report import _overall_lines, odometry_lines, overall, summarise_episodes


def _episode(world, route, method, trial, *, success, near, spl, distance, collisions=0):
    return {"trial": {"world": world, "route": route, "method": method, "trial": trial},
            "metrics": {"success": success, "success_0_5m": near, "spl": spl, "final_distance_m": distance,
                        "relocalisations": 1, "collisions": collisions}}


def _run():
    eps = []
    for i in range(4):   # hospital easy: ours 4/4 (one of them 0.8 m off), the baseline 2/4
        eps.append(_episode("hospital", "easy", "ours", i, success=True, near=i != 3, spl=0.9,
                            distance=0.8 if i == 3 else 0.2))
        eps.append(_episode("hospital", "easy", "sptm", i, success=i < 2, near=i < 2, spl=0.5 if i < 2 else 0.0,
                            distance=0.1 if i < 2 else 9.0))
    for i in range(2):   # office: ours 1/2 with three collisions, the baseline 0/2
        eps.append(_episode("office", "main", "ours", i, success=i == 0, near=i == 0, spl=0.7 if i == 0 else 0.0,
                            distance=0.3 if i == 0 else 12.0, collisions=3))
        eps.append(_episode("office", "main", "sptm", i, success=False, near=False, spl=0.0, distance=11.0))
    return eps


def _summary(eps, routes, methods):
    return {f"{w}:{r}": {m: summarise_episodes([e for e in eps if (e["trial"]["world"], e["trial"]["route"]) == (w, r)
                                                 and e["trial"]["method"] == m]) for m in methods} for w, r in routes}


def test_the_final_distance_percentiles_are_over_the_trials():
    s = summarise_episodes([e for e in _run() if e["trial"]["method"] == "sptm"])
    assert s["trials"] == 6 and s["final_distance_p50_m"] == 9.0        # 0.1 0.1 9 9 11 11
    assert s["final_distance_p90_m"] == 11.0 and s["mean_final_distance_m"] == round(40.2 / 6, 3)


def test_over_all_routes_each_method_has_its_route_mean_lowest_route_and_margin():
    eps, routes, methods = _run(), [("hospital", "easy"), ("office", "main")], ["ours", "sptm"]
    over = overall(eps, routes, methods, _summary(eps, routes, methods))
    ours, base = over["ours"], over["sptm"]
    assert ours["trials"] == 6 and ours["route_mean_sr"] == 0.75 and base["route_mean_sr"] == 0.25
    assert ours["lowest_route"] == "office:main" and ours["lowest_route_sr"] == 0.5
    assert ours["success_rate_0_5m"] == round(4 / 6, 4) and ours["collisions_per_episode"] == 1.0
    assert ours["margin_over_sptm"] == 0.5 and base["margin_over_sptm"] is None
    assert ours["wrong_localisations"] is None            # no step logs
    row = next(line for line in _overall_lines(over, routes) if line.startswith("| ours |"))
    assert row == "| ours | 6 | 0.75 | 0.50 (office:main) | 0.67 | 0.72 | 0.25 / 6.40 | 1.00 | - | +0.50 |"


def test_a_route_without_trials_leaves_the_averages_open():
    eps = [e for e in _run() if not (e["trial"]["route"] == "main" and e["trial"]["method"] == "ours")]
    routes, methods = [("hospital", "easy"), ("office", "main")], ["ours", "sptm"]
    over = overall(eps, routes, methods, _summary(eps, routes, methods))
    assert over["ours"]["trials"] == 4 and over["ours"]["route_mean_sr"] is None
    assert over["ours"]["lowest_route"] is None and over["ours"]["margin_over_sptm"] is None
    row = next(line for line in _overall_lines(over, routes) if line.startswith("| ours |"))
    assert "| ours | 4 | - | - |" in row and row.endswith("| - |")


def test_the_odometry_table_names_only_where_driving_on_acted():
    from robot.bench.diagnosis import confirmation_counts, diagnose

    poses = {0: (0.0, 0.0, 0.0), 1: (1.0, 0.0, 0.0)}
    steps = [{"step": i, "x_m": 0.5 * i, "y_m": 0.0, "yaw_deg": 0.0, "state": "navigating", "current_node": i // 2,
              "target_node": 1, "odometry": mark} for i, mark in enumerate([None, "driving on", "reached", None])]
    blind = diagnose(steps, poses)
    seen = diagnose([{**s, "odometry": None} for s in steps], poses)
    counted = {("hospital easy", "ours"): confirmation_counts([blind, seen]),
               ("office", "ours"): confirmation_counts([seen])}
    lines = odometry_lines(counted)
    assert lines[-1] == "| hospital easy | ours | 2 | 1 | 2 | 1 | 0 of 1 |" and not any("office" in line for line in lines)
    assert odometry_lines({("office", "ours"): confirmation_counts([seen])}) == []
    # with the belief in the log, its mode at the node reached by odometry stands beside it (node 0, 1 m back: right)
    believed = diagnose([{**s, "belief_top": [[0, 0.9]]} for s in steps], poses)
    lines = odometry_lines({("hospital easy", "ours"): confirmation_counts([believed])})
    assert lines[-1] == "| hospital easy | ours | 1 | 1 | 2 | 1 | 0 of 1 | 0 | 0 |" and "belief wrong" in lines[-3]


def test_a_record_from_before_the_odometry_judgement_gives_way_to_its_step_log(tmp_path):
    """A record whose diagnosis predates the marks of nodes reached by odometry cannot say whether
    they were right: the report reads the episode's step log instead, and without one keeps the
    record and counts none of its odometry nodes as judged (unknown, not right)."""
    import dataclasses
    import json

    from robot.bench.diagnosis import confirmation_counts, diagnose
    from robot.bench.paper_report import diagnose_episodes
    from robot.bench.trials import Trial, step_log_path

    maps = tmp_path / "map"
    maps.mkdir()
    poses = {0: (0.0, 0.0, 0.0), 1: (1.0, 0.0, 0.0)}
    (maps / "manifest.json").write_text(json.dumps({"nodes": [
        {"id": n, "true_pose": {"x_m": x, "y_m": y, "yaw_rad": yaw}} for n, (x, y, yaw) in poses.items()]}))
    steps = [{"step": i, "x_m": 2.0 * i, "y_m": 0.0, "yaw_deg": 0.0, "state": "navigating", "current_node": min(i, 1),
              "target_node": 1, "odometry": ["driving on", "reached"][i]} for i in range(2)]   # node 1 reached 1 m off
    trial = Trial(world="hospital", route="easy", method="ours", trial=0, map_dir=str(maps), appearance_seed=1,
                  start_x_m=0.0, start_y_m=0.0, start_yaw_deg=0.0, offset_m=0.0, offset_yaw_deg=0.0,
                  shortest_length_m=1.0)
    old = diagnose(steps, poses).to_dict()
    old.pop("odometry_judged")
    for c in old["confirmations"]:
        c.pop("by_odometry")
    episode = {"trial": dataclasses.asdict(trial), "metrics": {"steps": 2}, "diagnosis": old}

    kept = confirmation_counts(list(diagnose_episodes([episode], tmp_path, {}).values()))
    assert (kept["odometry_nodes"], kept["odometry_nodes_judged"], kept["confirmations"]) == (1, 0, 2)
    log = step_log_path(tmp_path, trial)
    log.parent.mkdir()
    log.write_text("".join(json.dumps(s) + "\n" for s in steps))
    read = confirmation_counts(list(diagnose_episodes([episode], tmp_path, {}).values()))
    assert (read["odometry_nodes"], read["odometry_nodes_judged"], read["odometry_nodes_wrong"]) == (1, 1, 0)
