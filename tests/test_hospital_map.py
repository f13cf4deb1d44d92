"""The topological map of the hospital walkthrough, recorded in the real simulator, must be right.

One recording and one descriptor extraction (module-scoped, about a minute each on 2 cores) serve
both threshold modes: calibrated (``configs/default.yaml``: sparsity 0.5) and the explicit
thresholds of the same file. Every check uses the simulator's true poses, which the builder never
sees:

* the loop closes where the route really comes back (matched nodes within 1.5 m);
* no loop closure and no merge joins nodes more than 3 m apart (the hospital's corridors and
  bare-wall corners look alike: single-frame similarity cannot tell them apart, sequence
  verification must);
* nodes spread along the driven path: no stretch without a node longer than 2.5 m, no two nodes
  showing the same view from the same spot.
"""

from __future__ import annotations

import dataclasses
import math

import networkx as nx
import numpy as np
import pytest
import torch

from descriptors.factory import make_descriptor
from maps.pipeline import build_map
from robot.mapping.drive import drive_walkthrough
from robot.mapping.make import vocabulary_frames
from robot.mapping.recording import iter_rgb, read_recording
from robot.settings import load_stack_config
from sim.worlds import load_world

pytestmark = pytest.mark.slow      # maps the hospital walkthrough with the CNN

LOOP_MATCH_M = 1.5          # the issue: matched nodes' true positions within 1.5 m
SPURIOUS_M = 3.0            # no loop closure or merge between nodes farther apart than this
MAX_GAP_M = 2.5             # no stretch of the driven path longer than this without a node
SAME_SPOT_M = 0.2
SAME_VIEW_RAD = math.radians(15.0)


@pytest.fixture(scope="module")
def walkthrough(tmp_path_factory):
    """The hospital walkthrough, recorded once, and its descriptors with the default descriptor."""
    # one thread and small batches: on a shared 2-core machine this is ~4x faster than two
    # threads with batches of 16 (thread spinning, page faults of large activations)
    torch.set_num_threads(1)
    config = load_stack_config()
    out = tmp_path_factory.mktemp("hospital") / "walkthrough"
    drive_walkthrough(load_world("hospital"), config, out, progress=False)
    frames = read_recording(out)
    # batch_size is not part of the descriptor's identity: the features are the default ones
    descriptor = make_descriptor(config.descriptor.backend, **{**config.descriptor.settings, "batch_size": 4})
    # one extraction: the vocabulary is fitted on the features of evenly spaced frames, exactly the
    # frames robot.mapping.make fits it on, instead of extracting them a second time
    features = descriptor.local_features(list(iter_rgb(frames)))
    descriptor.fit_features(np.stack(vocabulary_frames(list(features), config.descriptor.fit_max_frames)))
    x = descriptor.aggregate(features)
    return config, frames, x


def _mode_config(config, mode: str):
    return config.mapping if mode == "calibrated" else dataclasses.replace(config.mapping, calibrated=False)


@pytest.fixture(scope="module", params=["calibrated", "explicit"])
def hospital_map(request, walkthrough):
    config, frames, x = walkthrough
    mapping = _mode_config(config, request.param)
    assert mapping.calibrated is (request.param == "calibrated")
    made = build_map(x, mapping, frame_indices=[f.index for f in frames], stamps_s=[f.stamp_s for f in frames],
                     true_poses=[f.true_pose for f in frames])
    return request.param, made, frames


def _apart_m(topomap, a: int, b: int) -> float:
    return topomap.node(a).true_pose.distance_to(topomap.node(b).true_pose)


def test_the_loop_closes_where_the_route_comes_back(hospital_map):
    mode, made, frames = hospital_map
    raw, log = made.raw_map, made.log
    start = frames[0].true_pose
    assert frames[-1].true_pose.distance_to(start) < 1.0, "the walkthrough ends where it began"
    closures = [(e.prev_node, e.node_id) for e in log.loop_closure_events()]
    closures += list(made.merge.merged.items())
    assert closures, f"{mode}: the walkthrough returns to its start but no loop was closed"
    for a, b in closures:
        apart = _apart_m(raw, a, b)
        assert apart < LOOP_MATCH_M, f"{mode}: loop {a} -> {b} joins places {apart:.1f} m apart"
    # ... at the start: a closure lands on a node near where the walkthrough began
    assert min(raw.node(b).true_pose.distance_to(start) for _, b in closures) < LOOP_MATCH_M
    assert nx.find_cycle(made.topomap.graph), f"{mode}: the map must contain the loop"


def test_no_loop_closure_or_merge_joins_distant_places(hospital_map):
    mode, made, _ = hospital_map
    raw, log = made.raw_map, made.log
    joins = [(e.prev_node, e.node_id, "loop closure") for e in log.loop_closure_events()]
    joins += [(a, b, "merge") for a, b in made.merge.merged.items()]
    for a, b, kind in joins:
        apart = _apart_m(raw, a, b)
        assert apart <= SPURIOUS_M, f"{mode}: {kind} {a} -> {b} joins places {apart:.1f} m apart"
    # the look-alikes are there: verification had candidates to reject, and rejected only far ones
    rejected = log.rejected_loop_events()
    assert rejected, f"{mode}: expected look-alike candidates above T_loop_closure in the hospital"
    for e in rejected:
        assert _apart_m(raw, e.node_id, e.loop_candidate) > LOOP_MATCH_M, (
            f"{mode}: a true revisit ({e.node_id} ~ {e.loop_candidate}) was rejected")
    # every loop-closure arc of the final map joins near places too
    for arc in made.topomap.loop_closures():
        assert _apart_m(made.topomap, arc.src, arc.dst) <= SPURIOUS_M


def test_nodes_spread_along_the_driven_path(hospital_map):
    mode, made, frames = hospital_map
    seq = [e.seq for e in made.log.node_events()]
    step = [frames[i].true_pose.distance_to(frames[i + 1].true_pose) for i in range(len(frames) - 1)]
    along = np.r_[0.0, np.cumsum(step)]
    gaps = np.diff(along[seq])
    assert gaps.max() <= MAX_GAP_M, f"{mode}: {gaps.max():.2f} m of the route without a node"
    assert 0.4 <= gaps.mean() <= 1.5, f"{mode}: mean node spacing {gaps.mean():.2f} m"
    nodes = made.topomap.nodes()
    pose = np.array([[n.true_pose.x_m, n.true_pose.y_m, n.true_pose.yaw_rad] for n in nodes])
    dist = np.linalg.norm(pose[:, None, :2] - pose[None, :, :2], axis=2)
    turn = np.abs(np.angle(np.exp(1j * (pose[:, None, 2] - pose[None, :, 2]))))
    upper = np.triu(np.ones_like(dist, dtype=bool), k=1)
    same_spot = upper & (dist < SAME_SPOT_M)
    # turning in place adds nodes at one spot (the paper's case 2): one after the other while the
    # robot turns at a corner, a few per corner, and never two of the same view
    pairs = list(zip(*np.nonzero(same_spot)))
    ids = [n.node_id for n in nodes]
    assert all(ids[b] == ids[a] + 1 for a, b in pairs), f"{mode}: nodes at one spot that were not added while turning"
    assert (same_spot | same_spot.T).sum(axis=1).max(initial=0) <= 2, f"{mode}: more than 3 nodes at one spot"
    assert not (same_spot & (turn < SAME_VIEW_RAD)).any(), f"{mode}: two nodes show the same view"
