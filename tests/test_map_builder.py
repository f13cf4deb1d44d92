"""The map builder and the optimisation pass on scripted descriptor sequences (no images).

Sequences are unit vectors turning in planes by known angles, so every similarity is a known
cosine; expected node frames come from those cosines, not from the builder.
"""

from __future__ import annotations

import math
from dataclasses import replace

import networkx as nx
import numpy as np
import pytest

from core.hal import Pose2D
from maps.builder import MapBuilder
from maps.config import MappingConfig, MapThresholds
from maps.graph import MapBuildError, MapError, TopoMap
from maps.optimise import merge_near_duplicates
from maps.pipeline import build_map
from tests.map_synthetic import arc_sequence, place_route


def thresholds(**kw) -> MapThresholds:
    base = dict(T_add_new_node=0.85, T_interval=1, T_add_distance=0.9999, T_loop_closure=0.9,
                T_merge=0.9, loop_min_gap_frames=30, loop_exclude_recent_nodes=2)
    base.update(kw)
    return MapThresholds(**base)


def run(x: np.ndarray, t: MapThresholds, **kw):
    b = MapBuilder(t)
    b.add_frames(x, **kw)
    return b.finish()


def node_seqs(log) -> list[int]:
    return [e.seq for e in log.node_events()]


def expected_node_frames(sim, n_frames: int, t_add: float, t_interval: int) -> list[int]:
    """The paper's node rule applied to an analytic similarity function sim(i, j)."""
    nodes = [0]
    for i in range(1, n_frames):
        if sim(i, nodes[-1]) < t_add and i - nodes[-1] >= t_interval:
            nodes.append(i)
    return nodes


# -- node addition -----------------------------------------------------------------------
def test_distance_case_adds_a_node_each_time_similarity_decays_below_threshold():
    step = 0.05
    x = arc_sequence(np.full(59, step))            # 60 frames, sim(i, j) = cos(step * |i - j|)
    topo, log = run(x, thresholds(loop_min_gap_frames=10_000))
    k = math.ceil(math.acos(0.85) / step + 1e-9)   # frames until cos drops below 0.85
    assert node_seqs(log) == list(range(0, 60, k))
    assert len(topo) == len(range(0, 60, k))
    for arc in topo.arcs():                        # a chain of driven arcs, each k moving frames
        assert arc.kind == "sequential" and arc.dst == arc.src + 1
        assert arc.weight == k and arc.n_frames == k
    first = log.node_events()[1]
    assert first.score_to_prev_node < 0.85 <= math.cos(step * (k - 1))
    assert "T_add_new_node" in first.reason


def _drive_and_turn() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """4-D descriptors (cos p, sin p, cos h, sin h) / sqrt(2): position angle p grows while
    driving, heading angle h while turning in place; sim = (cos dp + cos dh) / 2."""
    dp = np.r_[np.full(100, 0.02), np.zeros(12), np.full(60, 0.02)]
    dh = np.r_[np.zeros(100), np.full(12, 0.25), np.zeros(60)]
    p = np.r_[0.0, np.cumsum(dp)]
    h = np.r_[0.0, np.cumsum(dh)]
    x = np.stack([np.cos(p), np.sin(p), np.cos(h), np.sin(h)], axis=1) / math.sqrt(2)
    return x.astype(np.float32), p, h


def test_turning_case_adds_nodes_quickly_while_turning_in_place():
    x, p, h = _drive_and_turn()
    sim = lambda i, j: (math.cos(p[i] - p[j]) + math.cos(h[i] - h[j])) / 2   # noqa: E731
    # a driving step changes sim by only 1e-4 here, so the motion threshold sits closer to 1
    topo, log = run(x, thresholds(loop_min_gap_frames=10_000, T_add_distance=0.99995))
    expected = expected_node_frames(sim, len(x), 0.85, 1)
    assert node_seqs(log) == expected
    in_turn = [s for s in expected if 100 < s <= 112]
    driving = [b - a for a, b in zip(expected, expected[1:]) if b <= 100]
    assert len(in_turn) >= 2, "a 3-radian turn in place must add nodes (case 2)"
    assert max(b - a for a, b in zip(in_turn, in_turn[1:])) < min(driving) / 4
    # turning changes the view, so it counts as relative distance too
    assert all(topo.arc(a.src, a.dst).weight == a.n_frames for a in topo.arcs())


def test_T_interval_is_the_least_number_of_frames_between_nodes():
    x, p, h = _drive_and_turn()
    sim = lambda i, j: (math.cos(p[i] - p[j]) + math.cos(h[i] - h[j])) / 2   # noqa: E731
    _, fast = run(x, thresholds(loop_min_gap_frames=10_000))
    topo, slow = run(x, thresholds(T_interval=6, loop_min_gap_frames=10_000))
    seqs = node_seqs(slow)
    assert seqs == expected_node_frames(sim, len(x), 0.85, 6)
    assert min(b - a for a, b in zip(seqs, seqs[1:])) >= 6
    in_turn = lambda log: [s for s in node_seqs(log) if 100 < s <= 112]   # noqa: E731
    assert len(in_turn(slow)) < len(in_turn(fast))
    assert slow.deferred_frames > 0 and fast.deferred_frames == 0
    assert any(e.frames_since_prev == 6 for e in slow.node_events())


def test_standing_still_adds_no_distance_and_no_node():
    steps = np.full(79, 0.05)
    moving = arc_sequence(steps)
    still = np.r_[moving[:21], np.repeat(moving[20:21], 50, axis=0), moving[21:]]   # 50 frames standing at 20
    topo_a, log_a = run(moving, thresholds(loop_min_gap_frames=10_000))
    topo_b, log_b = run(still, thresholds(loop_min_gap_frames=10_000))
    shifted = [s if s <= 20 else s + 50 for s in node_seqs(log_a)]
    assert node_seqs(log_b) == shifted
    assert [a.weight for a in topo_b.arcs()] == [a.weight for a in topo_a.arcs()]
    # while standing, the counter and the current node do not change
    standing = slice(21, 71)
    assert np.all(log_b.m_distance[standing] == log_b.m_distance[20])
    assert np.all(log_b.node[standing] == log_b.node[20])
    assert np.all(log_b.sim_to_prev[standing] >= 0.9999)


def test_arc_weight_counts_only_frames_that_moved():
    rng = np.random.default_rng(3)
    big = rng.random(120) < 0.5
    steps = np.where(big, 0.04, 1e-5)          # 1e-5 rad: sim(i, i-1) > T_add_distance, counts nothing
    x = arc_sequence(steps)
    topo, log = run(x, thresholds(loop_min_gap_frames=10_000))
    seqs = node_seqs(log)
    assert len(seqs) >= 3
    for arc, (a, b) in zip(topo.arcs(), zip(seqs, seqs[1:])):
        assert arc.weight == int(big[a:b].sum())          # steps a..b-1 lead into frames a+1..b
        assert arc.n_frames == b - a


# -- loop closure ------------------------------------------------------------------------
def test_loop_closure_links_previous_node_to_matched_node_and_adds_no_duplicate():
    step = 0.05
    x = arc_sequence(np.full(199, step))            # 1.6 turns of a circle
    angle = step * np.arange(200)
    topo, log = run(x, thresholds())
    loops = log.loop_closure_events()
    assert loops, "coming back to the start must close the loop"
    first = loops[0]
    assert all(e.seq < first.seq for e in log.node_events()), "no node after the loop closed"
    node_angle = {e.node_id: angle[e.seq] for e in log.node_events()}
    for e in loops:
        diffs = {n: abs(math.remainder(angle[e.seq] - a, 2 * math.pi)) for n, a in node_angle.items()}
        assert e.loop_score == pytest.approx(math.cos(diffs[e.node_id]), abs=1e-5)
        assert e.loop_score > 0.9
    assert first.prev_node == max(node_angle)       # from the last new node ...
    arc = topo.arc(first.prev_node, first.node_id)  # ... to the best-matching earlier node
    assert arc.kind == "loop_closure" and arc.weight == first.m_distance and first.new_arc
    # afterwards the walk retraces the first turn: it hops along the old nodes, adding no arcs
    assert len(loops) > 1 and not any(e.new_arc for e in loops[1:])
    assert [e.node_id for e in loops[1:]] == sorted(e.node_id for e in loops[1:])
    assert nx.find_cycle(topo.graph)
    # without loop closure the same walk duplicates the places of the first turn
    no_loop, _ = run(x, thresholds(T_loop_closure=1.0))
    assert len(no_loop) > len(topo)
    assert not no_loop.loop_closures()


@pytest.mark.parametrize("gap, recent, closes", [(30, 2, False), (0, 1, False), (0, 0, True)])
def test_loop_closure_exclusion_rule(gap, recent, closes):
    # look right for 12 frames, then back: the frame that leaves node 1 looks like node 0 again
    x = arc_sequence(np.r_[np.full(12, 0.05), np.full(14, -0.05)])
    topo, log = run(x, thresholds(loop_min_gap_frames=gap, loop_exclude_recent_nodes=recent))
    assert bool(log.loop_closure_events()) is closes
    assert len(topo) == (2 if closes else 3)


def test_builder_refuses_bad_frames():
    b = MapBuilder(thresholds())
    b.add_frame(np.array([1.0, 0.0, 0.0], np.float32), 0, 0.0)
    with pytest.raises(MapBuildError, match="shape"):
        b.add_frame(np.array([1.0, 0.0], np.float32), 1, 0.1)
    with pytest.raises(MapBuildError, match="L2-normalised"):
        b.add_frame(np.array([2.0, 0.0, 0.0], np.float32), 1, 0.1)
    with pytest.raises(MapBuildError, match="NaN"):
        b.add_frame(np.array([np.nan, 0.0, 0.0], np.float32), 1, 0.1)
    with pytest.raises(MapBuildError, match="frame_index must increase"):
        b.add_frame(np.array([1.0, 0.0, 0.0], np.float32), 0, 0.1)
    with pytest.raises(MapBuildError, match="every frame or for none"):
        b.add_frame(np.array([1.0, 0.0, 0.0], np.float32), 1, 0.1, Pose2D(0, 0, 0))
    with pytest.raises(MapBuildError, match="no frames"):
        MapBuilder(thresholds()).finish()


def test_thresholds_and_config_validate_with_field_names():
    with pytest.raises(ValueError, match="T_add_new_node"):
        thresholds(T_add_new_node=1.5)
    with pytest.raises(ValueError, match="T_interval"):
        thresholds(T_interval=0)
    with pytest.raises(ValueError, match="sparsity"):
        MappingConfig(sparsity=2.0)
    with pytest.raises(ValueError, match="T_loop_closure"):
        MappingConfig(T_loop_closure=float("nan"))


def test_poses_give_true_lengths_on_arcs():
    x = arc_sequence(np.full(59, 0.05))
    poses = [Pose2D(0.1 * i, 0.0, 0.0) for i in range(60)]
    topo, log = run(x, thresholds(loop_min_gap_frames=10_000), true_poses=poses)
    assert topo.has_true_poses
    for arc in topo.arcs():
        assert arc.length_m == pytest.approx(0.1 * arc.n_frames)
    assert log.travelled_m == pytest.approx(5.9)


# -- the optimisation pass ---------------------------------------------------------------
def _chain_map(descs: np.ndarray, extra_arcs=()) -> TopoMap:
    topo = TopoMap(descs.shape[1])
    for k, d in enumerate(descs):
        topo.add_node(d, keyframe_index=10 * k, stamp_s=float(k))
    for k in range(len(descs) - 1):
        topo.add_arc(k, k + 1, weight=10, kind="sequential", n_frames=20)
    for src, dst, w in extra_arcs:
        topo.add_arc(src, dst, weight=w, kind="sequential", n_frames=20)
    return topo


def test_merge_rewires_arcs_keeping_direction_and_the_cheaper_parallel_arc():
    rng = np.random.default_rng(0)
    d = rng.standard_normal((7, 64))
    d[4] = d[1] + 0.1 * rng.standard_normal(64)     # node 4 shows node 1's place again
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # 0->1->2->3->4->5->6, plus 1->5 (expensive) and 6->4 (will become 6->1)
    topo = _chain_map(d.astype(np.float32), extra_arcs=[(1, 5, 50), (6, 4, 7)])
    t = thresholds(T_merge=0.9, loop_min_gap_frames=30, loop_exclude_recent_nodes=1)
    result = merge_near_duplicates(topo, t)
    out = result.topomap
    assert result.merged == {4: 1}
    assert 4 not in out and len(out) == 6
    arcs = {(a.src, a.dst): a for a in out.arcs()}
    assert set(arcs) == {(0, 1), (1, 2), (2, 3), (3, 1), (1, 5), (5, 6), (6, 1)}
    assert arcs[(3, 1)].kind == "merged"                  # was 3 -> 4, direction kept
    assert arcs[(1, 5)].weight == 10 and arcs[(1, 5)].kind == "merged"   # 4->5 (10) beat 1->5 (50)
    assert arcs[(0, 1)].kind == "sequential"
    assert all(a.src != a.dst for a in out.arcs())
    np.testing.assert_array_equal(out.descriptor(1), topo.descriptor(1))   # the earlier node is kept


def test_merge_drops_self_loops_and_never_merges_route_neighbours():
    rng = np.random.default_rng(1)
    d = rng.standard_normal((5, 64))
    d[2] = d[1] + 0.05 * rng.standard_normal(64)    # neighbours that look alike: not a revisit
    d[4] = d[3] + 0.05 * rng.standard_normal(64)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    topo = _chain_map(d.astype(np.float32))
    t = thresholds(T_merge=0.9, loop_min_gap_frames=0, loop_exclude_recent_nodes=1)
    assert merge_near_duplicates(topo, t).merged == {}
    far = _chain_map(d.astype(np.float32)[[0, 1, 2, 3, 4]], extra_arcs=[(1, 3, 5)])
    # 1 -> 3 makes 1 and 3 neighbours; 2 and 4 are not alike; nothing to merge either
    assert merge_near_duplicates(far, t).merged == {}


def test_merge_pass_on_a_walk_that_missed_its_loop_closure():
    x = arc_sequence(np.full(199, 0.05))
    raw, _ = run(x, thresholds(T_loop_closure=1.0))        # the builder never closes the loop
    result = merge_near_duplicates(raw, thresholds(T_merge=0.95))
    out = result.topomap
    assert result.merged and len(out) == len(raw) - len(result.merged)
    assert any(a.kind == "merged" for a in out.arcs())
    assert nx.find_cycle(out.graph)
    for removed, kept in result.merged.items():
        assert float(raw.descriptor(removed) @ raw.descriptor(kept)) >= 0.95
        assert raw.node(kept).keyframe_index < raw.node(removed).keyframe_index
    assert all(a.src in out and a.dst in out and a.src != a.dst for a in out.arcs())


def test_build_map_with_explicit_thresholds_runs_builder_and_merge():
    x = arc_sequence(np.full(199, 0.05))
    cfg = MappingConfig(calibrated=False, T_add_new_node=0.85, T_interval=1, T_add_distance=0.9999,
                        T_loop_closure=0.9, T_merge=0.9, loop_min_gap_frames=30, loop_exclude_recent_nodes=2)
    made = build_map(x, cfg)
    assert made.calibration is None and made.thresholds == cfg.explicit_thresholds()
    assert made.log.n_frames == 200 and made.log.loop_closure_events()
    assert len(made.topomap) <= len(made.raw_map)


def test_topomap_refuses_bad_arcs():
    topo = _chain_map(np.eye(3, dtype=np.float32))
    with pytest.raises(MapError, match="self-loop"):
        topo.add_arc(1, 1, 1.0, "sequential")
    with pytest.raises(MapError, match="unknown node"):
        topo.add_arc(0, 9, 1.0, "sequential")
    with pytest.raises(MapError, match="kind"):
        topo.add_arc(0, 2, 1.0, "teleport")
    assert topo.add_arc(0, 1, 3.0, "loop_closure").weight == 3.0      # cheaper replaces
    assert topo.add_arc(0, 1, 8.0, "sequential").kind == "loop_closure"   # dearer is ignored


# -- sequence verification ----------------------------------------------------------------
# places 0..16, where 12 and 13 look like 3 and 4 (a look-alike stretch: a single frame there
# matches an old node above T_loop_closure), then back to 0..5 (a true revisit)
TWIN_ROUTE = list(range(17)) + [0, 1, 2, 3, 4, 5]
TWINS = {12: (3, 0.97), 13: (4, 0.97)}
LEG = 8        # frames per leg of place_route


def _twin_thresholds(k: int) -> MapThresholds:
    return thresholds(T_add_new_node=0.8, T_loop_closure=0.9, T_merge=0.9, T_add_distance=0.999,
                      loop_min_gap_frames=20, T_loop_verify=0.8, loop_verify_frames=k, loop_verify_hops=2)


def _leg(seq: int) -> int:
    """The position in TWIN_ROUTE of the leg a frame lies on."""
    return seq // LEG


def test_without_verification_a_look_alike_closes_a_wrong_loop():
    x = place_route(TWIN_ROUTE, frames_per_leg=LEG, twins=TWINS)
    _, log = run(x, _twin_thresholds(0))
    wrong = [e for e in log.loop_closure_events() if _leg(e.seq) in (11, 12, 13)]
    assert wrong, "the paper's unverified rule takes the look-alike for a revisit"
    assert not log.rejected_loop_events()


def test_sequence_verification_rejects_the_look_alike_and_keeps_the_true_revisit():
    x = place_route(TWIN_ROUTE, frames_per_leg=LEG, twins=TWINS)
    t = _twin_thresholds(16)
    topo, log = run(x, t)
    assert not [e for e in log.loop_closure_events() if _leg(e.seq) < 16], "no loop before the revisit"
    rejected = log.rejected_loop_events()
    assert rejected and all(_leg(e.seq) in (11, 12, 13) for e in rejected)
    for e in rejected:                      # logged with the scores the picture shows
        assert e.kind == "node" and e.loop_score > t.T_loop_closure
        assert e.verify_frames == 17 and e.verify_support < t.T_loop_verify
        assert "rejected" in e.reason
    first = log.loop_closure_events()[0]
    assert _leg(first.seq) >= 16 and first.node_id == 0, "the revisit of place 0 closes onto node 0"
    assert first.verify_support >= t.T_loop_verify and first.verify_rival < first.verify_support
    # after it the builder hops along the old nodes, each hop verified, adding no nodes
    assert all(e.seq < first.seq for e in log.node_events())
    assert topo.arc(first.prev_node, 0).kind == "loop_closure"
    assert log.summary()["loop_closures_rejected"][0]["candidate"] == rejected[0].loop_candidate


def test_verified_decisions_wait_for_their_frames_and_finish_decides_the_last_one():
    x = place_route(TWIN_ROUTE, frames_per_leg=LEG, twins=TWINS)
    t = _twin_thresholds(16)
    _, batch = run(x, t)
    b = MapBuilder(t)
    came_out_at = {}
    for i, d in enumerate(x):
        for e in b.add_frame(d, i, float(i)):
            came_out_at[e.seq] = i
    topo, log = b.finish()
    assert log.events == batch.events
    assert log.n_frames == len(x) and log.node.shape == (len(x),)
    for e in log.rejected_loop_events():
        assert came_out_at[e.seq] == e.seq + 16, "a candidate is decided once its 16 frames are in"
    # a walkthrough that ends just after the revisit begins: finish() decides on what there is
    start = next(e.seq for e in batch.loop_closure_events())
    short = MapBuilder(t)
    short.add_frames(x[: start + 4])
    _, end = short.finish()
    last = end.loop_closure_events()
    assert last and last[0].seq == start and last[0].verify_frames == 4
    assert end.n_frames == start + 4


def test_thresholds_without_verification_fields_load_as_unverified():
    old = {k: v for k, v in thresholds().to_dict().items()
           if k not in ("T_loop_verify", "loop_verify_frames", "loop_verify_hops")}
    t = MapThresholds.from_dict(old)
    assert t.loop_verify_frames == 0
    with pytest.raises(ValueError, match="loop_verify_frames"):
        thresholds(loop_verify_frames=-1)
    with pytest.raises(ValueError, match="T_loop_verify"):
        thresholds(T_loop_verify=2.0)


def test_merge_needs_the_route_around_both_nodes_to_agree():
    rng = np.random.default_rng(4)
    d = rng.standard_normal((10, 64))
    d[6] = d[2] + 0.1 * rng.standard_normal(64)     # 6 looks like 2, but 7, 8 do not look like 3, 4
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    topo = _chain_map(d.astype(np.float32))
    plain = thresholds(T_merge=0.9, loop_min_gap_frames=0, loop_exclude_recent_nodes=1)
    assert merge_near_duplicates(topo, plain).merged == {6: 2}, "the paper's rule merges the look-alike"
    verified = thresholds(T_merge=0.9, loop_min_gap_frames=0, loop_exclude_recent_nodes=1,
                          T_loop_verify=0.6, loop_verify_frames=3, loop_verify_hops=1)
    result = merge_near_duplicates(topo, verified)
    assert result.merged == {} and result.rejected[0][:2] == (6, 2)
    # a real revisit: 6, 7 and 5 look like 2, 3 and 1 -> merged
    d2 = d.copy()
    d2[7] = d[3] + 0.1 * rng.standard_normal(64)
    d2[5] = d[1] + 0.1 * rng.standard_normal(64)
    d2 /= np.linalg.norm(d2, axis=1, keepdims=True)
    result = merge_near_duplicates(_chain_map(d2.astype(np.float32)), verified)
    assert result.merged.get(6) == 2 and not result.rejected


# -- a walkthrough that ends just past its start ------------------------------------------
# frames turn at a constant rate in one plane; nodes are a few frames apart, so a revisit frame
# lies up to half a node spacing from the nearest node but within a frame step of an old frame

def _end_of_walk_thresholds() -> MapThresholds:
    return thresholds(T_add_new_node=0.9, T_loop_closure=0.997, T_merge=0.997, T_add_distance=0.9999,
                      loop_min_gap_frames=20, loop_exclude_recent_nodes=2, T_loop_verify=0.997,
                      loop_verify_frames=12, loop_verify_hops=2)


def _circle_walk(laps: float, step_rad: float = 0.03, offset_rad: float = 0.015) -> np.ndarray:
    """Frames around a full circle and on; the second lap's frames fall between the first's."""
    n = int(round(2 * math.pi / step_rad))
    first = arc_sequence(np.full(n - 1, step_rad))
    more = int(round((laps - 1) * 2 * math.pi / step_rad))
    second = arc_sequence(np.full(more - 1, step_rad), start_rad=n * step_rad + offset_rad)
    return np.concatenate([first, second])


def test_a_walk_ending_just_past_its_start_closes_on_the_walkthroughs_frames():
    t = _end_of_walk_thresholds()
    x = _circle_walk(1.05)                     # ends 0.05 lap past the start
    topo, log = run(x, t)
    loops = log.loop_closure_events()
    assert len(loops) == 1 and loops[0].node_id in (0, 1), [(e.seq, e.node_id) for e in loops]
    e = loops[0]
    assert e.verify_frames < t.loop_verify_frames + 1, "the walk ended before the full window"
    assert e.verify_support >= t.T_loop_verify
    # the same frames judged against the nodes alone fall short of T_loop_verify
    window = x[e.seq:]
    from maps.sequence import check_sequence
    on_nodes = check_sequence(window, topo, e.node_id, eligible=topo.node_ids.tolist(), hops=2,
                              min_support=t.T_loop_verify)
    assert on_nodes.support < t.T_loop_verify <= e.verify_support


def test_a_short_window_that_matches_a_look_alike_stretch_is_still_rejected():
    rng = np.random.default_rng(7)
    route = rng.standard_normal((6, 32)).astype(np.float32)
    route /= np.linalg.norm(route, axis=1, keepdims=True)
    topo = _chain_map(route)
    frames = np.repeat(route, 4, axis=0)                 # 4 frames at each node
    frame_nodes = np.repeat(np.arange(6), 4)
    from maps.sequence import check_sequence_on_frames
    near = frames[8:12] + 0.05 * rng.standard_normal((4, 32)).astype(np.float32)   # frames of node 2
    near /= np.linalg.norm(near, axis=1, keepdims=True)
    kw = dict(frames=frames, frame_nodes=frame_nodes, eligible=range(6), hops=1, min_support=0.9)
    assert check_sequence_on_frames(near, topo, 2, **kw).accepted
    # the same window offered as a revisit of node 4: the better match lies outside its stretch
    wrong = check_sequence_on_frames(near, topo, 4, **kw)
    assert not wrong.accepted and wrong.rival > wrong.support
    with pytest.raises(MapBuildError, match="frame_nodes"):
        check_sequence_on_frames(near, topo, 2, **{**kw, "frame_nodes": frame_nodes[:-1]})


def test_a_revisit_that_never_became_a_candidate_closes_when_the_walk_ends():
    # the second lap passes its node decision half a node spacing from nodes 0 and 1 (below
    # T_loop_closure there) and ends before the next decision; its frames match old frames
    t = _end_of_walk_thresholds()
    step = 0.03
    first = arc_sequence(np.full(200, step))                       # 0 .. 6.0 rad
    second = arc_sequence(np.full(9, step), start_rad=2 * math.pi + 8 * step)
    x = np.concatenate([first, second])
    topo, log = run(x, t)
    assert not log.rejected_loop_events(), "no candidate came up at a node decision"
    loops = log.loop_closure_events()
    assert len(loops) == 1 and loops[0].seq == len(x) - 1 and loops[0].node_id == 0
    assert "ended on its own route" in loops[0].reason
    assert topo.arc(loops[0].prev_node, 0).kind == "loop_closure"
    assert loops[0].verify_support >= t.T_loop_verify > loops[0].verify_rival
    # the paper's unverified rule has no end-of-walk closure
    _, paper = run(x, replace(t, loop_verify_frames=0))
    assert not paper.loop_closure_events()
