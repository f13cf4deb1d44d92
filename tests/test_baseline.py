"""The SPTM-style learned action baseline: expert labels, exploration data, training, the head
file, the policy in a closed-loop episode, and the bench command.

Everything runs on the tiny test world: one walkthrough drive, mapped with the tiny stand-in
place descriptor (the place descriptor is not what is tested here; the baseline's own features
are the real EfficientNet-Lite0 with the packaged weights), then real exploration drives in
PyBullet.
"""

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from controllers.actions import Action
from core.hal import Pose2D
from descriptors.factory import make_descriptor
from maps.store import load_map
from robot.baseline import BaselineFileError, SptmPolicy, load_baseline
from robot.baseline.expert import CLASSES, ExpertConfig, NodeTargets, expert_action, heading_error_rad
from robot.baseline.exploration import ExplorationConfig, collect_expert_data
from robot.baseline.features import FeatureSettings, ImageFeatures, as_thumbnail, node_features
from robot.baseline.fit import TrainConfig, train_head
from robot.baseline.head import load_head, save_head
from robot.baseline.track import WalkthroughTrack
from robot.episode.sim import EpisodeOutputs, SimEpisode, run_sim_navigation
from robot.mapping.make import build_map_from_frames
from robot.mapping.sources import RecordingSource
from robot.settings import load_stack_config
from sim.worlds import load_world

TINY = Path(__file__).parent / "data" / "tiny_world.yaml"
pytestmark = pytest.mark.slow      # expert drives in PyBullet and training


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    """One torch thread, as the harness's workers train and run it (restored afterwards)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def world():
    return load_world(TINY)


@pytest.fixture(scope="module")
def tiny_map(tmp_path_factory, world, tiny_mapping_run):
    """The session's drive of the tiny world (conftest) mapped with the tiny stand-in descriptor."""
    out = tmp_path_factory.mktemp("baseline")
    config = load_stack_config()
    source = RecordingSource(tiny_mapping_run)
    build_map_from_frames(source, make_descriptor("tiny"), config.mapping, out / "map", total=len(source),
                          progress=False, extra={"world": world.name})
    return load_map(out / "map")


@pytest.fixture(scope="module")
def features():
    return ImageFeatures(FeatureSettings())


@pytest.fixture(scope="module")
def expert_data(world, tiny_map, features):
    """Short drives from many random starts under one appearance (not the map's): in the tiny room
    a moved box changes most of the view, too much for a few hundred samples to generalise over."""
    config = ExplorationConfig(episodes=24, steps_per_episode=15, appearances=1)
    return collect_expert_data(world, tiny_map, features, config=config, seed=1, progress=False)


@pytest.fixture(scope="module")
def trained(expert_data, tiny_map, features):
    ids = [int(n) for n in tiny_map.topomap.node_ids.tolist()]
    return train_head(expert_data, ids, node_features(tiny_map, features, ids),
                      config=TrainConfig(validation_every=3), seed=0)


# -- the expert -------------------------------------------------------------------------------
def test_expert_labels_follow_the_heading_error():
    target = Pose2D(3.0, 1.0, 0.0)                                   # 1 m ahead along +x
    assert expert_action(Pose2D(2.0, 1.0, 0.0), target) is Action.FORWARD
    # turned left of the path: the target is to its right, and the other way round
    assert expert_action(Pose2D(2.0, 1.0, math.radians(40)), target) is Action.RIGHT
    assert expert_action(Pose2D(2.0, 1.0, math.radians(-40)), target) is Action.LEFT
    # facing along the path but 0.5 m to its right: the target is up and to the left
    assert expert_action(Pose2D(2.2, 0.5, 0.0), target) is Action.LEFT
    assert expert_action(Pose2D(2.2, 1.5, 0.0), target) is Action.RIGHT
    # just inside / outside the forward tolerance
    tol = ExpertConfig().forward_tolerance_deg
    assert expert_action(Pose2D(2.0, 1.0, math.radians(tol - 1)), target) is Action.FORWARD
    assert expert_action(Pose2D(2.0, 1.0, math.radians(tol + 1)), target) is Action.RIGHT
    # standing on the target: its own heading decides (the node looked north: turn left)
    assert heading_error_rad(Pose2D(3.0, 1.05, 0.0), Pose2D(3.0, 1.0, math.pi / 2)) == pytest.approx(math.pi / 2)
    assert expert_action(Pose2D(3.0, 1.05, 0.0), Pose2D(3.0, 1.0, math.pi / 2)) is Action.LEFT


def test_track_is_a_loop_measured_along_the_walkthrough(world):
    track = WalkthroughTrack(world.routes.walkthrough)
    assert track.loop_m == pytest.approx(12.0, abs=0.06)
    s, off = track.project(3.0, 1.2)
    assert s == pytest.approx(2.0, abs=0.06) and off == pytest.approx(0.2, abs=0.01)
    # across the seam: the start lies just ahead of a point at the end of the loop
    s_end, _ = track.project(1.0, 1.4)
    assert track.ahead_m(s_end, 0.5) == pytest.approx(0.9, abs=0.1)
    assert track.ahead_m(0.5, s_end) == pytest.approx(-0.9, abs=0.1)
    assert track.heading_at(1.0) == pytest.approx(0.0) and track.heading_at(5.0) == pytest.approx(math.pi / 2)


def test_targets_lie_a_bit_ahead_along_the_walkthrough_also_over_the_seam(world, tiny_map):
    targets = NodeTargets(tiny_map.topomap, WalkthroughTrack(world.routes.walkthrough))
    config = ExpertConfig()
    for pose in (Pose2D(2.0, 1.0, 0.0), Pose2D(5.0, 2.0, math.pi / 2), Pose2D(1.0, 1.5, -math.pi / 2)):
        ahead = targets.ahead(pose, config)
        assert 1 <= len(ahead) <= config.max_targets
        s, _ = targets.track.project(pose.x_m, pose.y_m)
        for node in ahead:
            p = tiny_map.topomap.node(node).true_pose
            gap = targets.track.ahead_m(s, targets.track.project(p.x_m, p.y_m)[0])
            assert config.target_min_m - 0.06 <= gap <= config.target_max_m + 0.06
    # at the end of the loop (west side, driving south) the targets are the first nodes of the map
    seam = targets.ahead(Pose2D(1.0, 1.5, -math.pi / 2), config)
    assert all(tiny_map.topomap.node(n).true_pose.y_m < 1.4 for n in seam)


def test_a_map_without_true_poses_is_refused(tiny_map):
    from maps.graph import TopoMap
    from robot.baseline.expert import ExpertError

    bare = TopoMap(dim=4)
    bare.add_node(np.array([1, 0, 0, 0], np.float32), keyframe_index=0, stamp_s=0.0)
    with pytest.raises(ExpertError, match="true pose"):
        NodeTargets(bare, WalkthroughTrack([[0, 0], [1, 0], [1, 1], [0, 0]]), "map X")


# -- exploration data -------------------------------------------------------------------------
def test_exploration_data_is_deterministic_for_a_seed(world, tiny_map, features):
    config = ExplorationConfig(episodes=2, steps_per_episode=8, appearances=2)
    a = collect_expert_data(world, tiny_map, features, config=config, seed=7, progress=False)
    b = collect_expert_data(world, tiny_map, features, config=config, seed=7, progress=False)
    for name in ("frame_features", "frame_episode", "frame_pose", "sample_frame", "sample_node", "sample_label"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.n_frames >= 4 and a.frame_features.shape[1] == FeatureSettings().dim
    assert set(a.frame_episode.tolist()) == {0, 1}
    c = collect_expert_data(world, tiny_map, features, config=config, seed=8, progress=False)
    assert not np.allclose(a.frame_pose[0], c.frame_pose[0])          # another seed starts elsewhere


def test_exploration_labels_are_the_experts_and_hold_every_class(expert_data, tiny_map):
    data = expert_data
    counts = data.class_counts()
    assert set(counts) == {"left", "forward", "right"} and all(v > 10 for v in counts.values()), counts
    assert data.n_samples >= data.n_frames
    for k in range(0, data.n_samples, 7):
        x, y, yaw = data.frame_pose[data.sample_frame[k]]
        node_pose = tiny_map.topomap.node(int(data.sample_node[k])).true_pose
        assert CLASSES[data.sample_label[k]] is expert_action(Pose2D(x, y, yaw), node_pose)
    # the drives stray from the walkthrough (random starts and actions), so recoveries are in the data
    track = WalkthroughTrack(load_world(TINY).routes.walkthrough)
    offsets = [track.project(x, y)[1] for x, y, _ in data.frame_pose]
    assert max(offsets) > 0.2


def test_features_of_a_frame_match_those_of_its_thumbnail(tiny_map, features):
    """A camera frame and the same frame stored as a node thumbnail give the same features."""
    node = int(tiny_map.topomap.node_ids[3])
    thumb = tiny_map.thumbnail(node)
    assert as_thumbnail(thumb).shape == (120, 160, 3)
    f = features([thumb, as_thumbnail(thumb)])
    assert f.shape == (2, FeatureSettings().dim)
    assert float(f[0] @ f[1]) / FeatureSettings().columns > 0.98
    strips = f[0].reshape(FeatureSettings().columns, -1)
    assert np.allclose(np.linalg.norm(strips, axis=1), 1.0, atol=1e-5)


# -- training and the head file ---------------------------------------------------------------
def test_training_beats_the_majority_class_on_held_out_drives(trained):
    stats = trained.stats
    val = stats["validation"]
    assert val is not None and val["samples"] > 30
    assert val["accuracy"] > val["majority_rate"] + 0.05, val
    assert stats["train"]["accuracy"] > val["majority_rate"]
    assert set(val["per_class"]) == {"left", "forward", "right"}


def test_training_is_deterministic_for_a_seed(expert_data, tiny_map, features, trained):
    ids = [int(n) for n in tiny_map.topomap.node_ids.tolist()]
    again = train_head(expert_data, ids, node_features(tiny_map, features, ids),
                       config=TrainConfig(validation_every=3), seed=0)
    for key, value in trained.model.state_dict().items():
        assert torch.equal(value, again.model.state_dict()[key]), key


def test_save_and_load_round_trip_exactly(trained, expert_data, tmp_path):
    path = save_head(tmp_path / "sub" / "head.pt", trained)
    loaded = load_baseline(path)
    assert loaded.feature_settings == trained.feature_settings and loaded.classes == CLASSES
    assert loaded.stats == trained.stats
    for key, value in trained.model.state_dict().items():
        assert torch.equal(value, loaded.model.state_dict()[key]), key
    current = expert_data.frame_features[:20]
    target = expert_data.frame_features[5:25]
    assert loaded.predict(current, target) == trained.predict(current, target)
    assert not list(path.parent.glob(".*tmp*"))                    # no temporary file left behind


def test_bad_head_files_raise_errors_naming_the_file(trained, tmp_path):
    missing = tmp_path / "missing.pt"
    with pytest.raises(BaselineFileError, match="missing.pt: no such file"):
        load_baseline(missing)
    good = save_head(tmp_path / "good.pt", trained)
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(BaselineFileError, match="truncated.pt: cannot read it"):
        load_baseline(truncated)
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"this is not a torch file\n" * 10)
    with pytest.raises(BaselineFileError, match="garbage.pt"):
        load_baseline(garbage)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(BaselineFileError, match="foreign.pt: not a trained-head file"):
        load_baseline(foreign)
    with pytest.raises(BaselineFileError, match="good.pt: trained on features"):
        load_head(good, expect_features=FeatureSettings(block=13))
    tampered = torch.load(good, weights_only=True)
    tampered["state_dict"]["net.0.weight"] = tampered["state_dict"]["net.0.weight"][:, :10]
    torch.save(tampered, tmp_path / "tampered.pt")
    with pytest.raises(BaselineFileError, match="tampered.pt: weights do not fit"):
        load_baseline(tmp_path / "tampered.pt")


# -- the policy in a closed-loop episode --------------------------------------------------------
class _CountingPolicy:
    """The real policy, counting the actions it chose (to see that the navigator used it)."""

    def __init__(self, policy):
        self.policy, self.name, self.chosen = policy, policy.name, []

    def for_frame(self, rgb):
        choose = self.policy.for_frame(rgb)

        def counted(node):
            action = choose(node)
            self.chosen.append(action)
            return action
        return counted


def test_sptm_policy_drives_an_episode_in_the_simulator(trained, tiny_map, features):
    policy = SptmPolicy(trained, tiny_map, features=features)
    assert policy.name == "sptm" and policy.node_features.shape == (len(tiny_map.topomap), features.settings.dim)
    counting = _CountingPolicy(policy)
    gx, gy, _ = load_world(TINY).routes.evaluation["short"].goal
    goal = min(tiny_map.topomap.nodes(), key=lambda n: math.hypot(n.true_pose.x_m - gx, n.true_pose.y_m - gy))
    result = run_sim_navigation(SimEpisode(TINY, tiny_map.path, goal=goal.node_id, start="short", max_steps=50),
                                make_descriptor("tiny"), outputs=EpisodeOutputs(progress=False),
                                loaded_map=tiny_map, action_policy=counting)
    assert result.setup["method"] == "sptm"
    assert result.outcome.steps > 5
    assert counting.chosen and set(counting.chosen) <= set(CLASSES)
    assert result.metrics.path_length_m > 0.1                      # the policy's actions moved the robot


def test_policy_refuses_a_node_the_map_does_not_have(trained, tiny_map, features):
    from maps.graph import MapError

    choose = SptmPolicy(trained, tiny_map, features=features).for_frame(tiny_map.thumbnail(0))
    assert choose(int(tiny_map.topomap.node_ids[1])) in CLASSES
    with pytest.raises(MapError, match="node 9999"):
        choose(9999)


# -- the bench command ----------------------------------------------------------------------------
def _bench(*args):
    from robot.bench.__main__ import main

    return main(["baseline", *args])


def test_bench_baseline_trains_saves_and_reports(tiny_map, tmp_path, capsys):
    out = tmp_path / "head.pt"
    rc = _bench("--map", str(tiny_map.path), "--world", str(TINY), "--episodes", "5", "--steps", "10",
                "--epochs", "3", "--seed", "2", "--out", str(out), "--quiet")
    printed = capsys.readouterr().out
    assert rc == 0, printed
    assert "5 drives in tiny" in printed and "validation" in printed and "wall time" in printed
    head = load_baseline(out)
    assert head.stats["drives"] == 5 and head.stats["seed"] == 2 and head.stats["validation"]["samples"] > 0
    assert f"saved -> {out}" in printed


def test_bench_baseline_bad_inputs_exit_2_naming_them(tiny_map, tmp_path, capsys):
    missing = tmp_path / "no_map"
    assert _bench("--map", str(missing), "--world", str(TINY), "--quiet") == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "Traceback" not in err
    # a map of the tiny world cannot teach the expert about the hospital
    assert _bench("--map", str(tiny_map.path), "--world", "hospital", "--quiet") == 2
    err = capsys.readouterr().err
    assert "built in world 'tiny', not 'hospital'" in err
    assert _bench("--map", str(tiny_map.path), "--world", str(TINY), "--episodes", "0", "--quiet") == 2
    assert "episodes" in capsys.readouterr().err
