"""Reading step logs against the map's true node poses (robot.bench.diagnosis)."""

import json
import math

import pytest

from robot.bench.diagnosis import (
    Diagnosis,
    StepLogError,
    collision_onsets,
    confirmation_counts,
    diagnose,
    map_node_poses,
    node_poses,
    pinned_stretches,
    read_step_log,
    route_goal,
)

POSES = {0: (0.0, 0.0, 0.0), 1: (1.0, 0.0, 0.0), 2: (2.0, 0.0, 0.0), 3: (10.0, 0.0, math.pi)}


def _step(i, state, node, target=None, x=0.0, y=0.0, yaw=0.0):
    return {"step": i, "x_m": x, "y_m": y, "yaw_deg": yaw, "state": state, "current_node": node,
            "target_node": target, "reason": "..."}


STEPS = [
    _step(0, "localising", None),
    _step(1, "localising", None),
    _step(2, "navigating", 0, None, x=0.1),                 # localised at node 0, 0.1 m from it
    _step(3, "navigating", 0, 1, x=0.6),
    _step(4, "navigating", 1, 2, x=1.2),                    # reached node 1
    _step(5, "relocalising", 1, None, x=1.5),               # lost between 1 and 2
    _step(6, "relocalising", 1, None, x=1.5, yaw=20.0),
    _step(7, "navigating", 3, None, x=1.5),                 # re-localised at node 3, 8.5 m away: wrong
    _step(8, "navigating", 2, 1, x=1.5, y=0.5, yaw=90.0),   # node 2 0.7 m away facing 90 deg off: near enough
    _step(9, "searching", 1, 2, x=2.5, yaw=45.0),           # node 1 1.5 m away facing 45 deg off: wrong
    _step(10, "arrived", 1, None, x=2.5, yaw=45.0),         # the same node: no new confirmation
]


def test_confirmations_wrong_places_and_lost_events():
    d = diagnose(STEPS, POSES)
    assert [(c.step, c.node, c.kind) for c in d.confirmations] == \
        [(2, 0, "localised"), (4, 1, "reached"), (7, 3, "localised"), (8, 2, "reached"), (9, 1, "reached")]
    assert [c.distance_m for c in d.confirmations] == [0.1, 0.2, 8.5, pytest.approx(0.707, abs=1e-3), 1.5]
    assert d.confirmations[2].heading_error_deg == -180.0 and d.confirmations[3].heading_error_deg == 90.0
    assert (d.confirmations[2].node_x_m, d.confirmations[2].node_y_m) == (10.0, 0.0)
    assert [c.step for c in d.wrong] == [7, 9]
    assert [(e.step, e.current_node, e.target_node, e.x_m) for e in d.lost] == [(5, 1, 2, 1.5)]
    summary = d.summary()
    assert summary.startswith("first wrong place: step 7, node 3 localised 8.5 m from it at (1.5, 0.0)")
    assert summary.endswith("first lost: step 5 at (1.5, 0.0), 1 -> 2")
    counts = confirmation_counts([d, diagnose(STEPS[:5], POSES)])
    assert counts == {"episodes": 2, "confirmations": 7, "wrong": 2, "localisations": 3, "wrong_localisations": 1,
                      "belief_localisations": 0, "belief_wrong_localisations": 0, "both_wrong_localisations": 0,
                      "belief_steps": 0, "belief_right": 0, "belief_confident": 0, "belief_confident_right": 0,
                      "pinned_episodes": 0, "pinned_steps": 0, "odometry_episodes": 0, "odometry_steps": 0,
                      "odometry_nodes": 0, "odometry_nodes_judged": 0, "odometry_nodes_wrong": 0, "belief_odometry_nodes": 0,
                      "belief_wrong_odometry_nodes": 0, "both_wrong_odometry_nodes": 0, "collisions": {},
                      "median_distance_m": 0.2}
    assert d.belief_summary() is None                       # a log without the belief


def test_the_belief_in_the_log_is_judged_by_the_same_rule():
    """The belief's mode at every step, and at each confirmation beside the navigator's node."""
    tops = {2: [[0, 0.7]], 3: [[0, 0.5]], 4: [[1, 0.8]], 5: [[1, 0.9]], 6: [[1, 0.9]], 7: [[1, 0.65]],
            8: [[2, 0.4]], 9: [[2, 0.3]], 10: [[3, 0.9]]}
    steps = [{**s, "belief_top": tops.get(s["step"]), "belief_confidence": (tops.get(s["step"]) or [[0, None]])[0][1]}
             for s in STEPS]
    d = diagnose(steps, POSES)
    assert [(c.belief_node, c.belief_wrong) for c in d.confirmations] == \
        [(0, False), (1, False), (1, False), (2, False), (2, False)]
    # every mode lies within a metre of the robot but step 10's (node 3, 7.5 m away, at 0.9 confidence)
    assert (d.belief_steps, d.belief_right, d.belief_confident, d.belief_confident_right) == (9, 8, 6, 5)
    assert d.belief_summary() == ("belief: mode at the right place at 8 of 9 steps; confident at 6, right at 5 of "
                                  "them; at the 2 (re-)localisations the navigator was wrong at 1, the belief at 0")
    counts = confirmation_counts([d])
    assert counts["belief_localisations"] == 2 and counts["belief_wrong_localisations"] == 0
    assert counts["both_wrong_localisations"] == 0          # step 7: the navigator wrong, the mode right


def _moving(i, action, x=0.0, yaw=0.0):
    return {**_step(i, "navigating", 0, 1, x=x, yaw=yaw), "action": action}


def test_a_robot_that_commands_motion_and_does_not_move_is_pinned():
    stuck = [_moving(i, "right" if i % 2 else "forward_right", x=5.0 + 0.001 * (i % 3), yaw=88.0 + i % 2)
             for i in range(30)]
    assert [(p.step, p.steps, p.x_m) for p in pinned_stretches(stuck)] == [(0, 30, 5.0)]
    free = [_moving(i, "forward", x=0.025 * i) for i in range(40)]          # 2.5 cm a step: moving
    turning = [_moving(i, "search_rotate", yaw=3.0 * i) for i in range(40)]  # 3 deg a step: turning
    assert pinned_stretches(free) == () and pinned_stretches(turning) == ()
    # standing still on purpose is not pinned, and it ends a stretch
    held = stuck[:15] + [{**s, "action": "none"} for s in stuck[15:20]] + stuck[20:]
    assert pinned_stretches(held) == ()
    d = diagnose(STEPS + [{**s, "step": 11 + s["step"]} for s in stuck], POSES)
    assert d.pinned_steps == 30 and "pinned for 30 steps in 1 stretch(es), the longest 30 from step 11" in d.summary()
    counts = confirmation_counts([d, diagnose(STEPS, POSES)])
    assert (counts["pinned_episodes"], counts["pinned_steps"]) == (1, 30)
    assert diagnose(STEPS, POSES).pinned == ()


def test_a_goal_image_placed_at_a_far_node_is_named_first():
    d = diagnose(STEPS[:5], POSES, goal=(3, (0.0, 0.5)))
    assert d.goal_node == 3 and d.goal_node_error_m == pytest.approx(10.012, abs=1e-3)
    assert d.summary() == "the goal image matched node 3, 10.0 m from the goal; every node confirmed at its place"
    assert diagnose(STEPS[:5], POSES, goal=(1, (1.2, 0.0))).summary() == "every node confirmed at its place"
    with pytest.raises(KeyError, match="goal node 7"):
        diagnose(STEPS[:5], POSES, goal=(7, (0.0, 0.0)))


def test_a_clean_episode_says_so_and_a_log_of_another_map_is_refused():
    d = diagnose(STEPS[:5], POSES)
    assert d.wrong == () and d.lost == () and d.summary() == "every node confirmed at its place"
    with pytest.raises(KeyError, match="node 3"):
        diagnose(STEPS, {k: v for k, v in POSES.items() if k != 3})


def test_node_poses_need_a_true_pose_for_every_node(tmp_path):
    manifest = {"nodes": [{"id": 0, "true_pose": {"x_m": 1.0, "y_m": 2.0, "yaw_rad": 0.5}},
                          {"id": 1, "true_pose": {"x_m": 3.0, "y_m": 2.0, "yaw_rad": 0.0}}]}
    assert node_poses(manifest) == {0: (1.0, 2.0, 0.5), 1: (3.0, 2.0, 0.0)}
    manifest["nodes"].append({"id": 2})                     # a node of a video map: no true pose
    assert node_poses(manifest) is None
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    assert map_node_poses(tmp_path) is None
    assert map_node_poses(tmp_path / "nowhere") is None


def test_read_step_log_names_the_file_and_line(tmp_path):
    log = tmp_path / "steps.jsonl"
    log.write_text("\n".join(json.dumps(s) for s in STEPS) + "\n")
    assert read_step_log(log) == STEPS
    log.write_text(json.dumps(STEPS[0]) + "\n{cut off\n")
    with pytest.raises(StepLogError, match=r"steps.jsonl: line 2 is not JSON"):
        read_step_log(log)
    log.write_text(json.dumps({"step": 0, "x_m": 0.0}) + "\n")
    with pytest.raises(StepLogError, match=r"line 1 has no y_m, yaw_deg, state"):
        read_step_log(log)
    with pytest.raises(StepLogError, match="cannot read"):
        read_step_log(tmp_path / "missing.jsonl")


def test_route_goal_reads_the_true_goal_of_an_evaluation_route_from_the_world_spec():
    from sim.worlds import load_world

    spec = load_world("hospital")
    route = spec.routes.evaluation["easy"]
    assert route_goal(spec, "easy", 12) == (12, (route.goal[0], route.goal[1]))
    assert route_goal(spec, "no-such-route", 12) is None
    assert route_goal(spec, "easy", None) is None        # the episode placed no goal image
    assert route_goal(None, "easy", 12) is None           # world spec not found


def test_collisions_are_told_by_what_the_robot_was_commanded_then():
    actions = ["forward"] * 4 + ["backward"] * 3 + ["search_rotate"] * 6
    counts = [0, 0, 1, 1, 1, 1, 1, 1, 3, 3, 4, 4, 4]       # +1 driving, +2 and +1 turning in place
    steps = [{**_moving(i, a, x=0.02 * i), "collisions": c} for i, (a, c) in enumerate(zip(actions, counts))]
    onsets = collision_onsets(steps)
    assert [(c.step, c.count, c.doing) for c in onsets] == [(2, 1, "driving"), (8, 2, "turning in place"),
                                                           (10, 1, "turning in place")]
    d = diagnose(STEPS + [{**s, "step": 11 + s["step"]} for s in steps], POSES)
    assert d.collisions_by_doing() == {"driving": 1, "turning in place": 3}
    assert d.summary().endswith("4 collisions: 3 turning in place, 1 driving")
    assert confirmation_counts([d, d])["collisions"] == {"driving": 2, "turning in place": 6}
    # a log without the count (written before it was logged, or not by the simulator) has none
    assert collision_onsets(STEPS) == () and "collisions" not in diagnose(STEPS, POSES).summary()


def test_driving_on_by_odometry_is_counted_from_the_log():
    """The steps the supervisor drove on by odometry and the nodes it took as reached so, judged
    like every confirmation and beside the belief's mode; a log written before the field counts none."""
    marks = {3: "driving on", 4: "reached", 5: None, 8: "driving on", 9: "reached"}
    steps = [{**s, "odometry": marks.get(s["step"])} for s in STEPS]
    d = diagnose(steps, POSES)
    assert (d.odometry_steps, d.odometry_nodes) == (4, 2)
    assert [c.step for c in d.confirmations if c.by_odometry] == [4, 9]
    assert "drove on by odometry for 4 steps, 2 node(s) reached so" in d.summary()
    counts = confirmation_counts([d, d, diagnose(STEPS, POSES)])
    assert (counts["odometry_episodes"], counts["odometry_steps"], counts["odometry_nodes"]) == (2, 8, 4)
    assert counts["odometry_nodes_wrong"] == 2 and counts["belief_odometry_nodes"] == 0   # step 9, no belief
    # the belief's mode at those nodes: right at step 4, at node 3 (7.5 m away) at step 9 where the arc length erred too
    tops = {4: [[1, 0.8]], 9: [[3, 0.7]]}
    believed = diagnose([{**s, "belief_top": tops.get(s["step"])} for s in steps], POSES)
    counts = confirmation_counts([believed])
    assert (counts["belief_odometry_nodes"], counts["belief_wrong_odometry_nodes"],
            counts["both_wrong_odometry_nodes"], counts["odometry_nodes_wrong"]) == (2, 1, 1, 1)
    assert diagnose(STEPS, POSES).odometry_steps == 0 and "odometry" not in diagnose(STEPS, POSES).summary()
    assert Diagnosis.from_dict(json.loads(json.dumps(d.to_dict()))) == d


def test_a_diagnosis_survives_an_episode_record():
    """The harness keeps each episode's diagnosis in its JSON record (the step logs are not
    committed); read back, it is the same diagnosis, pinned stretches and collisions included."""
    stuck = [_moving(i, "right", x=5.0, yaw=88.0) for i in range(25)]
    bumps = [{**_moving(i, "forward", x=0.02 * i), "collisions": i // 3} for i in range(6)]
    steps = STEPS + [{**s, "step": 11 + i} for i, s in enumerate(stuck + bumps)]
    d = diagnose(steps, POSES, goal=(3, (0.0, 0.5)))
    assert d.pinned and d.collisions and d.wrong and d.lost and d.goal_node == 3
    back = Diagnosis.from_dict(json.loads(json.dumps(d.to_dict())))
    assert back == d and back.summary() == d.summary()
    assert confirmation_counts([back]) == confirmation_counts([d])
    with pytest.raises(TypeError):
        Diagnosis.from_dict({**d.to_dict(), "confirmations": [{"step": 1}]})
