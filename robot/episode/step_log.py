"""The per-step log of an episode (JSON lines): the true pose after each step, what the navigator
decided and why, the node the raw view matched best, and the belief over the map (its top nodes
with their mass, the confidence and the entropy); ``python -m robot.bench replay`` and
the harness's diagnosis read it."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from core.atomic import AtomicFile
from core.hal import Pose2D
from robot.episode.loop import StepRecord


def step_log_entry(record: StepRecord, pose: Pose2D, node_ids: np.ndarray) -> dict:
    """One line of the step log: the true pose after the step, what the navigator decided, and
    the node the raw view matched best (``node_ids``: the similarity row's order)."""
    s = record.step
    sims = record.similarities
    best = int(np.argmax(sims))

    def r3(v):
        return None if v is None else round(float(v), 3)
    return {"step": record.index, "x_m": round(pose.x_m, 3), "y_m": round(pose.y_m, 3),
            "yaw_deg": round(math.degrees(pose.yaw_rad), 1), "state": s.state.value, "action": s.action.value,
            "current_node": s.current_node, "target_node": s.target_node,
            "current_score": r3(s.current_score), "target_score": r3(s.target_score),
            "thirds": None if s.thirds is None else [r3(s.thirds.left), r3(s.thirds.middle), r3(s.thirds.right)],
            "vote_scores": None if s.vote is None or s.vote.scores is None else
            [r3(s.vote.scores.left), r3(s.vote.scores.middle), r3(s.vote.scores.right)],
            "best_raw_node": int(node_ids[best]), "best_raw_score": r3(sims[best]),
            "relocalisations": s.relocalisations, "reason": s.reason,
            "belief_top": None if record.belief is None else [[int(n), round(m, 3)] for n, m in record.belief.top],
            "belief_confidence": None if record.belief is None else round(record.belief.confidence, 3),
            "belief_entropy_bits": None if record.belief is None else round(record.belief.entropy_bits, 2)}


class StepLog:
    """The step log (JSON lines), written to a temporary file and moved into place by
    :meth:`close`, whatever the end (so a crash leaves the log of the steps made, never a
    half-written line): :class:`core.atomic.AtomicFile`."""

    def __init__(self, path: str | Path, node_ids: np.ndarray):
        self.node_ids = node_ids
        self._file = AtomicFile(path)

    @property
    def path(self) -> Path:
        return self._file.path

    def write(self, record: StepRecord, pose: Pose2D) -> None:
        self._file.write(json.dumps(step_log_entry(record, pose, self.node_ids)) + "\n")

    def close(self) -> None:
        self._file.commit()
