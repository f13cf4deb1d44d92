"""Exploration drives in the simulator that collect the learned baseline's training data.

Following SPTM's exploration data, with a ground-truth expert as the paper's baseline used:
every episode starts near the walkthrough at a random place, with a random lateral offset (up
to ``start_offset_m``) and yaw offset (up to ``start_yaw_deg``), in a free spot (at least
``min_clearance_m`` from walls and props). Each control tick the robot's camera frame is
recorded with up to ``max_targets`` map nodes ahead of it and the expert's label for each
(:mod:`robot.baseline.expert`); then the robot drives the expert's action towards one of those
targets, or, with probability ``epsilon``, a random action held for a few ticks, so the data
holds the drifts the expert then recovers from. An episode ends after ``steps_per_episode``
ticks, on a collision, on toppling, or when the robot is more than ``max_off_track_m`` from the
walkthrough. Episodes are spread over ``appearances`` appearance seeds (light, moved props),
none of them the map's own, so the classifier does not learn one lighting.

Deterministic for a seed: the simulator is, and every random draw comes from one generator
seeded with ``seed``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from tqdm import tqdm

from controllers.actions import Action, action_velocity
from controllers.config import ActionSpeeds
from core.angles import wrap_angle
from core.hal import Pose2D
from core.validate import check_at_least, check_count, check_range
from maps.store import LoadedMap
from robot.baseline.expert import CLASSES, ExpertConfig, ExpertError, NodeTargets, expert_action
from robot.baseline.features import FeatureSettings, ImageFeatures, as_thumbnail
from robot.baseline.track import WalkthroughTrack
from sim.appearance import apply_appearance
from sim.config import SimConfig
from sim.geometry import clearance_m
from sim.hal import SimLimo
from sim.world_spec import WorldSpec

#: appearance seeds of the exploration drives start here (map drives use 0, evaluation trials small numbers)
APPEARANCE_BASE = 1000


class ExplorationError(ValueError):
    """Bad exploration settings, or a world where no start can be placed."""


@dataclass(frozen=True)
class ExplorationConfig:
    """How many exploration drives, how long, and how much randomness."""

    episodes: int = 64                 # exploration drives (many short ones: starts are the main variety)
    steps_per_episode: int = 50        # control ticks per drive at most (5 s at 10 Hz, about 1 m)
    epsilon: float = 0.1               # chance per tick of starting a random action (~30% of ticks random)
    random_hold_min: int = 2           # a random action is held this many ticks at least ...
    random_hold_max: int = 6           # ... and at most (one tick of turning is only 3 deg)
    start_offset_m: float = 0.35       # largest lateral start offset from the walkthrough (m)
    start_yaw_deg: float = 40.0        # largest start yaw offset from the walkthrough heading (deg)
    min_clearance_m: float = 0.3       # a start is this far from walls and props at least (m)
    max_off_track_m: float = 1.0       # the drive ends when the robot is farther from the walkthrough (m)
    appearances: int = 4               # appearance seeds the drives are spread over
    expert: ExpertConfig = field(default_factory=ExpertConfig)

    def __post_init__(self) -> None:
        for name in ("episodes", "steps_per_episode", "random_hold_min", "random_hold_max", "appearances"):
            check_count(f"exploration {name}", getattr(self, name), 1, error=ExplorationError)
        if self.random_hold_max < self.random_hold_min:
            raise ExplorationError(f"exploration random_hold_max ({self.random_hold_max}) < random_hold_min "
                                   f"({self.random_hold_min})")
        check_range("exploration epsilon", self.epsilon, 0.0, 1.0, error=ExplorationError)
        for name in ("start_offset_m", "start_yaw_deg", "min_clearance_m", "max_off_track_m"):
            check_at_least(f"exploration {name}", getattr(self, name), 0.0, error=ExplorationError)


@dataclass(frozen=True)
class ExpertData:
    """What the exploration drives collected.

    Frames (rows of ``frame_features``) and samples (a frame paired with one target node and the
    expert's label for it; a frame has up to ``max_targets`` samples). ``sample_label`` indexes
    :data:`robot.baseline.expert.CLASSES`.
    """

    frame_features: np.ndarray        # (F, D) float32, ImageFeatures of the frame made a thumbnail
    frame_episode: np.ndarray         # (F,) int32, the drive each frame belongs to
    frame_pose: np.ndarray            # (F, 3) float64, true x_m, y_m, yaw_rad (for checks and pictures)
    sample_frame: np.ndarray          # (S,) int64, row of frame_features
    sample_node: np.ndarray           # (S,) int64, the target node id
    sample_label: np.ndarray          # (S,) int64, index into CLASSES
    feature_settings: FeatureSettings
    appearance_seeds: tuple[int, ...]
    episodes: int

    @property
    def n_frames(self) -> int:
        return int(self.frame_features.shape[0])

    @property
    def n_samples(self) -> int:
        return int(self.sample_label.shape[0])

    def class_counts(self, mask: Optional[np.ndarray] = None) -> dict[str, int]:
        """Samples per class (action name -> count), of all samples or those in ``mask``."""
        labels = self.sample_label if mask is None else self.sample_label[mask]
        return {a.value: int(np.sum(labels == k)) for k, a in enumerate(CLASSES)}

    def validation_mask(self, every: int = 5) -> np.ndarray:
        """Samples held out for validation: those of every ``every``-th drive (drives, not frames,
        so that near-identical neighbouring frames never sit on both sides)."""
        episode = self.frame_episode[self.sample_frame]
        return (episode % every) == every - 1


def appearance_seeds(seed: int, count: int) -> tuple[int, ...]:
    """The exploration's appearance seeds for ``seed`` (never 0, the map's own appearance)."""
    return tuple(APPEARANCE_BASE + 100 * int(seed) + k for k in range(count))


def _start_pose(track: WalkthroughTrack, spec: WorldSpec, config: ExplorationConfig,
                rng: np.random.Generator) -> Pose2D:
    """A random free start near the walkthrough; falls back to a point on the walkthrough."""
    for attempt in range(50):
        s = rng.uniform(0.0, track.length_m)
        x, y = track.point_at(s)
        heading = track.heading_at(s)
        offset = rng.uniform(-config.start_offset_m, config.start_offset_m) if attempt < 40 else 0.0
        x, y = x - offset * math.sin(heading), y + offset * math.cos(heading)
        yaw = heading + math.radians(rng.uniform(-config.start_yaw_deg, config.start_yaw_deg))
        if clearance_m(spec, [(x, y)])[0][0] >= config.min_clearance_m:
            return Pose2D(x, y, wrap_angle(yaw))
    raise ExplorationError(f"world {spec.name!r}: found no start {config.min_clearance_m} m clear of walls "
                           "and props near the walkthrough in 50 tries")


class _Recorder:
    """Collects one drive's thumbnails and samples; describes the thumbnails in one batch."""

    def __init__(self) -> None:
        self.thumbs: list[np.ndarray] = []
        self.poses: list[tuple[float, float, float]] = []
        self.samples: list[tuple[int, int, int]] = []   # (frame within drive, node, label)

    def add(self, rgb: np.ndarray, pose: Pose2D, targets: list[int], labels: list[Action]) -> None:
        k = len(self.thumbs)
        self.thumbs.append(as_thumbnail(rgb))
        self.poses.append((pose.x_m, pose.y_m, pose.yaw_rad))
        self.samples.extend((k, node, CLASSES.index(label)) for node, label in zip(targets, labels))


def _drive(base: SimLimo, start: Pose2D, targets: NodeTargets, config: ExplorationConfig, speeds: ActionSpeeds,
           rng: np.random.Generator, bar: tqdm) -> _Recorder:
    """One exploration drive from ``start``; see the module docstring."""
    truth = base.ground_truth
    truth.teleport(start)
    base.apply(action_velocity(Action.NONE, speeds))
    collisions = truth.collision_count()
    rec = _Recorder()
    random_action, hold = Action.FORWARD, 0
    for step in range(config.steps_per_episode):
        pose = truth.true_pose()
        _, off_track = targets.track.project(pose.x_m, pose.y_m)
        ahead = targets.ahead(pose, config.expert) if off_track <= config.max_off_track_m else []
        if not ahead:
            bar.update(config.steps_per_episode - step)
            break
        labels = [expert_action(pose, targets.poses[n], config.expert) for n in ahead]
        rec.add(base.read().rgb, pose, ahead, labels)
        if hold == 0 and rng.random() < config.epsilon:
            random_action = CLASSES[int(rng.integers(len(CLASSES)))]
            hold = int(rng.integers(config.random_hold_min, config.random_hold_max + 1))
        if hold > 0:
            action, hold = random_action, hold - 1
        else:
            action = labels[int(rng.integers(len(labels)))]
        base.apply(action_velocity(action, speeds))
        base.tick()
        bar.update(1)
        if truth.toppled() or truth.collision_count() > collisions:
            bar.update(config.steps_per_episode - step - 1)
            break
    base.apply(action_velocity(Action.NONE, speeds))
    return rec


def collect_expert_data(world: WorldSpec, loaded_map: LoadedMap, features: ImageFeatures, *,
                        config: ExplorationConfig = ExplorationConfig(), seed: int = 0,
                        sim_config: SimConfig = SimConfig(), speeds: ActionSpeeds = ActionSpeeds(),
                        progress: bool = True) -> ExpertData:
    """Drive ``config.episodes`` exploration drives in ``world`` against ``loaded_map`` (a map of
    that world with true poses) and return the frames' features and the expert's samples.

    Raises :class:`ExpertError` for a map without true poses, :class:`ExplorationError` for bad
    settings or a world without a free start.
    """
    if not sim_config.camera_enabled:
        raise ExplorationError("exploration needs the camera: SimConfig.camera_enabled is false")
    targets = NodeTargets(loaded_map.topomap, WalkthroughTrack(world.routes.walkthrough), f"map {loaded_map.path}")
    rng = np.random.default_rng([int(seed), 0xB05E])
    seeds = appearance_seeds(seed, min(config.appearances, config.episodes))
    feats, episode_of, poses, s_frame, s_node, s_label = [], [], [], [], [], []
    n_frames = 0
    bar = tqdm(total=config.episodes * config.steps_per_episode, unit="step", desc="exploring",
               disable=not progress, leave=False)
    try:
        for k, appearance in enumerate(seeds):
            episodes = range(k * config.episodes // len(seeds), (k + 1) * config.episodes // len(seeds))
            spec = apply_appearance(world, appearance)      # props moved: starts must be clear of them
            starts = [_start_pose(targets.track, spec, config, rng) for _ in episodes]
            with SimLimo(sim_config, start=starts[0], world=world, appearance_seed=appearance) as base:
                for episode, start in zip(episodes, starts):
                    rec = _drive(base, start, targets, config, speeds, rng, bar)
                    if not rec.thumbs:
                        continue
                    feats.append(features(rec.thumbs))
                    episode_of.append(np.full(len(rec.thumbs), episode, dtype=np.int32))
                    poses.append(np.asarray(rec.poses, dtype=np.float64))
                    for frame, node, label in rec.samples:
                        s_frame.append(n_frames + frame)
                        s_node.append(node)
                        s_label.append(label)
                    n_frames += len(rec.thumbs)
    finally:
        bar.close()
    if not feats:
        raise ExplorationError(f"world {world.name!r}: the exploration drives recorded no frame")
    return ExpertData(
        frame_features=np.concatenate(feats).astype(np.float32), frame_episode=np.concatenate(episode_of),
        frame_pose=np.concatenate(poses), sample_frame=np.asarray(s_frame, dtype=np.int64),
        sample_node=np.asarray(s_node, dtype=np.int64), sample_label=np.asarray(s_label, dtype=np.int64),
        feature_settings=features.settings, appearance_seeds=seeds, episodes=config.episodes)


__all__ = ["APPEARANCE_BASE", "ExpertData", "ExplorationConfig", "ExplorationError", "ExpertError",
           "appearance_seeds", "collect_expert_data"]
