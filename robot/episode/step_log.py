"""The per-step log of an episode (JSON lines): the true pose after each step, what the navigator
decided and why (``odometry``: "driving on" while the views match nothing and the supervisor
drives on by odometry, "reached" at a node it confirmed so), the node the raw view matched
best, and the belief over the map (its top nodes with their mass, the confidence, the entropy
and the direction at the mode relative to the route); ``python -m robot.bench replay`` and
the harness's diagnosis read it.

Beside it, :func:`views_path` (``X.views.npz`` for ``X.steps.jsonl``) holds what the robot
itself saw at each step: the view's similarity to every node (float16) and the odometry pose.
With it a belief filter of other settings runs over the episode offline in seconds, without
the simulator (``python -m robot.bench belief``): the filter does not steer, so the views are
the same whatever its settings."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from core.atomic import AtomicFile, write_bytes
from core.hal import Pose2D
from robot.episode.loop import StepRecord


def step_log_entry(record: StepRecord, pose: Pose2D, node_ids: np.ndarray, collisions: int | None = None) -> dict:
    """One line of the step log: the true pose after the step, the simulator's collision count
    since the episode began (None where no simulator counts), what the navigator decided, and
    the node the raw view matched best (``node_ids``: the similarity row's order)."""
    s = record.step
    sims = record.similarities
    best = int(np.argmax(sims))

    def r3(v):
        return None if v is None else round(float(v), 3)
    return {"step": record.index, "x_m": round(pose.x_m, 3), "y_m": round(pose.y_m, 3),
            "yaw_deg": round(math.degrees(pose.yaw_rad), 1), "collisions": collisions, "state": s.state.value, "action": s.action.value,
            "current_node": s.current_node, "target_node": s.target_node,
            "current_score": r3(s.current_score), "target_score": r3(s.target_score),
            "thirds": None if s.thirds is None else [r3(s.thirds.left), r3(s.thirds.middle), r3(s.thirds.right)],
            "vote_scores": None if s.vote is None or s.vote.scores is None else
            [r3(s.vote.scores.left), r3(s.vote.scores.middle), r3(s.vote.scores.right)],
            "best_raw_node": int(node_ids[best]), "best_raw_score": r3(sims[best]),
            "relocalisations": s.relocalisations, "reason": s.reason,
            "odometry": None if s.supervisor is None else
            "reached" if s.supervisor.by_odometry else "driving on" if s.supervisor.driving_on else None,
            "goal_image_score": r3(record.goal_score),
            "goal_image_filtered": None if s.supervisor is None else r3(s.supervisor.goal_image_score),
            "belief_top": None if record.belief is None else [[int(n), round(m, 3)] for n, m in record.belief.top],
            "belief_confidence": None if record.belief is None else round(record.belief.confidence, 3),
            "belief_entropy_bits": None if record.belief is None else round(record.belief.entropy_bits, 2),
            "belief_facing_deg": None if record.belief is None else record.belief.facing_deg}


def views_path(step_log: str | Path) -> Path:
    """The views beside a step log: ``X.views.npz`` for ``X.steps.jsonl`` (else ``<name>.views.npz``)."""
    step_log = Path(step_log)
    stem = step_log.name[:-len(".steps.jsonl")] if step_log.name.endswith(".steps.jsonl") else step_log.name
    return step_log.with_name(stem + ".views.npz")


class Views(NamedTuple):
    """What the robot saw at each step (row ``k`` of every array: step ``k``)."""

    node_ids: np.ndarray        # (N,) the similarity columns' node ids
    similarities: np.ndarray    # (T, N) float32 (stored as float16)
    odometry: np.ndarray        # (T, 3) x_m, y_m, yaw_rad; NaN where the base gave no odometry


class ViewsError(ValueError):
    """A views file that cannot be read or does not hold views."""


def read_views(path: str | Path) -> Views:
    """The views of :func:`views_path`; raises :class:`ViewsError` naming the file."""
    try:
        with np.load(path) as z:
            views = Views(z["node_ids"], z["similarities"].astype(np.float32), z["odometry"].astype(float))
    except (OSError, ValueError, KeyError) as exc:
        raise ViewsError(f"{path}: cannot read the views ({exc})") from None
    if views.similarities.ndim != 2 or views.similarities.shape[1] != views.node_ids.size \
            or views.odometry.shape != (views.similarities.shape[0], 3):
        raise ViewsError(f"{path}: the arrays do not fit together (similarities {views.similarities.shape}, "
                         f"{views.node_ids.size} node ids, odometry {views.odometry.shape})")
    return views


class StepLog:
    """The step log (JSON lines), written to a temporary file and moved into place by
    :meth:`close`, whatever the end (so a crash leaves the log of the steps made, never a
    half-written line): :class:`core.atomic.AtomicFile`; the views beside it
    (:func:`views_path`) are written at :meth:`close`, atomically."""

    def __init__(self, path: str | Path, node_ids: np.ndarray):
        self.node_ids = node_ids
        self._file = AtomicFile(path)
        self._rows: list[np.ndarray] = []
        self._odometry: list[tuple[float, float, float]] = []

    @property
    def path(self) -> Path:
        return self._file.path

    def write(self, record: StepRecord, pose: Pose2D, collisions: int | None = None) -> None:
        self._file.write(json.dumps(step_log_entry(record, pose, self.node_ids, collisions)) + "\n")
        self._rows.append(np.asarray(record.similarities, dtype=np.float16))
        o = record.frame.odometry
        self._odometry.append((math.nan,) * 3 if o is None else (o.x_m, o.y_m, o.yaw_rad))

    def close(self) -> None:
        path = self._file.commit()
        n = len(self.node_ids)
        buffer = io.BytesIO()
        np.savez_compressed(buffer, node_ids=np.asarray(self.node_ids),
                            similarities=np.asarray(self._rows, dtype=np.float16).reshape(-1, n),
                            odometry=np.asarray(self._odometry, dtype=float).reshape(-1, 3))
        write_bytes(views_path(path), buffer.getvalue())
