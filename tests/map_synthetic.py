"""Small deterministic descriptor sequences for the map tests (no images, no network).

* :func:`arc_sequence` -- unit vectors turning at known angular steps in one plane, so the
  similarity of frames ``i`` and ``j`` is exactly ``cos(angle_i - angle_j)``;
* :func:`landmark_route` -- a robot driving a square loop among random landmarks: a frame's
  descriptor mixes the landmark vectors it sees, weighted by distance and by bearing relative
  to the heading, so driving makes similarity decay gradually, turning in place makes it decay
  fast, and coming back to a place at the same heading gives back the same descriptor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from core.hal import Pose2D


def arc_sequence(steps_rad: np.ndarray, dim: int = 8, start_rad: float = 0.0) -> np.ndarray:
    """(len(steps)+1, dim) unit vectors; frame 0 at ``start_rad``, frame i+1 turned by steps[i]."""
    angles = start_rad + np.concatenate([[0.0], np.cumsum(steps_rad)])
    out = np.zeros((angles.size, dim), dtype=np.float32)
    out[:, 0] = np.cos(angles)
    out[:, 1] = np.sin(angles)
    return out


@dataclass(frozen=True)
class Route:
    descriptors: np.ndarray      # (N, D) float32, L2-normalised
    poses: list                  # N Pose2D
    stamps_s: np.ndarray         # (N,)
    moving: np.ndarray           # (N,) bool: the robot moved (drove or turned) into this frame


def _square_poses(side_m: float, step_m: float, turn_step_rad: float, overlap_m: float,
                  stand_frames: int) -> tuple[list[Pose2D], list[bool]]:
    poses, moving = [Pose2D(0.0, 0.0, 0.0)], [False]
    x, y, yaw = 0.0, 0.0, 0.0

    def drive(length_m: float, stand_at: float | None = None) -> None:
        nonlocal x, y
        n = int(round(length_m / step_m))
        for k in range(n):
            x += step_m * math.cos(yaw)
            y += step_m * math.sin(yaw)
            poses.append(Pose2D(x, y, yaw))
            moving.append(True)
            if stand_at is not None and k == int(n * stand_at):
                for _ in range(stand_frames):
                    poses.append(Pose2D(x, y, yaw))
                    moving.append(False)

    def turn_left() -> None:
        nonlocal yaw
        n = int(round((math.pi / 2) / turn_step_rad))
        for _ in range(n):
            yaw += (math.pi / 2) / n
            poses.append(Pose2D(x, y, yaw))
            moving.append(True)

    for side in range(4):
        drive(side_m, stand_at=0.5 if side == 1 and stand_frames else None)
        turn_left()
    drive(overlap_m)
    return poses, moving


def landmark_route(seed: int = 0, dim: int = 256, side_m: float = 8.0, step_m: float = 0.05,
                   turn_step_rad: float = math.radians(5.0), overlap_m: float = 3.0,
                   stand_frames: int = 40, noise: float = 0.02, n_landmarks: int = 160,
                   sigma_m: float = 1.5, kappa: float = 3.0, dt_s: float = 0.1) -> Route:
    """A square loop, driven counter-clockwise from (0, 0) facing +x, then ``overlap_m`` again."""
    rng = np.random.default_rng(seed)
    poses, moving = _square_poses(side_m, step_m, turn_step_rad, overlap_m, stand_frames)
    # landmarks scattered in a band on both sides of the square's edges
    t = rng.uniform(0.0, 4.0 * side_m, n_landmarks)
    offset = rng.choice([-1.0, 1.0], n_landmarks) * rng.uniform(0.8, 2.5, n_landmarks)
    side = (t // side_m).astype(int)
    along = t - side * side_m
    corners = np.array([[0, 0], [side_m, 0], [side_m, side_m], [0, side_m]], dtype=float)
    dirs = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], dtype=float)
    normals = np.stack([-dirs[:, 1], dirs[:, 0]], axis=1)
    lm = corners[side] + dirs[side] * along[:, None] + normals[side] * offset[:, None]
    vectors = rng.standard_normal((n_landmarks, dim))
    p = np.array([[q.x_m, q.y_m, q.yaw_rad] for q in poses])
    dx = lm[None, :, 0] - p[:, None, 0]
    dy = lm[None, :, 1] - p[:, None, 1]
    dist2 = dx ** 2 + dy ** 2
    bearing = np.arctan2(dy, dx) - p[:, None, 2]
    w = np.exp(-dist2 / (2 * sigma_m ** 2)) * np.exp(kappa * (np.cos(bearing) - 1.0))
    desc = w @ vectors
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    desc += noise * rng.standard_normal(desc.shape) / math.sqrt(dim)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    stamps = np.arange(len(poses)) * dt_s
    return Route(descriptors=desc.astype(np.float32), poses=poses, stamps_s=stamps,
                 moving=np.asarray(moving))


def place_route(places: list[int], frames_per_leg: int = 8, dim: int = 64, seed: int = 0,
                twins: dict[int, tuple[int, float]] | None = None) -> np.ndarray:
    """A drive through numbered places: each place has a random unit vector, and the frames of
    each leg blend the vectors of its two ends, so similarity decays smoothly as the robot
    drives on. Repeating a place number is a true revisit (the same frames again);
    ``twins[p] = (q, a)`` makes place ``p`` a look-alike of place ``q`` (cosine ``a``) with
    different places around it. Returns (frames, dim) float32, L2-normalised."""
    rng = np.random.default_rng(seed)
    vec = {}
    for p in sorted(set(places)):
        v = rng.standard_normal(dim)
        vec[p] = v / np.linalg.norm(v)
    for p, (q, a) in (twins or {}).items():
        fresh = vec[p] - (vec[p] @ vec[q]) * vec[q]
        fresh /= np.linalg.norm(fresh)
        vec[p] = a * vec[q] + math.sqrt(1.0 - a * a) * fresh
    frames = []
    for p, q in zip(places, places[1:]):
        for k in range(frames_per_leg):
            t = k / frames_per_leg
            frames.append((1.0 - t) * vec[p] + t * vec[q])
    frames.append(vec[places[-1]])
    out = np.asarray(frames)
    return (out / np.linalg.norm(out, axis=1, keepdims=True)).astype(np.float32)
