"""Metrics of one navigation episode, as the mission defines them, and their summary over trials.

* **Success**: the robot itself declared arrival AND its true position (simulator ground truth)
  is within ``SUCCESS_RADIUS_M`` (1.0 m) of the goal position; success within
  ``TIGHT_RADIUS_M`` (0.5 m) is reported too. Running out of the step budget, failing, being
  aborted (toppled) is never a success.
* **SPL** (Anderson et al. 2018, "On Evaluation of Embodied Navigation Agents"): per episode
  ``S * l / max(p, l)`` with ``S`` success (0/1), ``l`` the shortest route length and ``p`` the
  length actually driven (from true poses); over episodes, the mean.
* Path length driven: the sum of the distances between successive true positions.
* Re-localisations, re-plans, collisions, planned vs visited node sequences, steps, simulated
  time and the wall time per step split into read (render), describe and decide.

Everything here is pure: it takes the :class:`robot.episode.loop.EpisodeOutcome` and the poses the
caller recorded, so it works the same for any source of ground truth.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from typing import Optional, Sequence

import numpy as np

from core.hal import Pose2D
from robot.episode.loop import EpisodeOutcome

#: the mission's success radius around the goal position (m)
SUCCESS_RADIUS_M = 1.0
#: the tighter radius also reported (m)
TIGHT_RADIUS_M = 0.5


def path_length_m(poses: Sequence[Pose2D]) -> float:
    """Sum of the straight-line distances between successive poses (m)."""
    if len(poses) < 2:
        return 0.0
    xy = np.array([[p.x_m, p.y_m] for p in poses], dtype=float)
    return float(np.hypot(*np.diff(xy, axis=0).T).sum())


def spl(success: bool, shortest_m: float, driven_m: float) -> float:
    """Success weighted by path length for one episode: ``S * l / max(p, l)``."""
    if not (math.isfinite(shortest_m) and shortest_m > 0):
        raise ValueError(f"shortest route length must be a positive number of metres, got {shortest_m!r}")
    if not success:
        return 0.0
    return float(shortest_m / max(driven_m, shortest_m))


@dataclass(frozen=True)
class StepTimeSplit:
    """Mean and 95th percentile wall time per control step (ms), by stage."""

    read_ms: float
    describe_ms: float
    decide_ms: float
    tick_ms: float
    total_ms: float
    total_p95_ms: float


@dataclass(frozen=True)
class EpisodeMetrics:
    """Everything reported about one episode. Distances in metres; None where unknown (no
    ground truth, or no route length for SPL)."""

    success: bool                          # arrived AND final distance <= 1.0 m
    success_0_5m: bool                     # arrived AND final distance <= 0.5 m
    arrived: bool                          # the robot declared arrival
    end: str                               # arrived / failed / step_budget / aborted / base_fault
    reason: str
    final_distance_m: Optional[float]      # true position to goal position at the end
    path_length_m: Optional[float]         # driven, from true poses
    shortest_length_m: Optional[float]     # the route's shortest length
    spl: Optional[float]
    steps: int
    sim_time_s: float
    wall_time_s: float
    relocalisations: int
    replans: int
    collisions: Optional[int]
    toppled: Optional[bool]
    goal_node: int
    start_node: Optional[int]
    planned_nodes: tuple[int, ...]         # the first plan
    plans: tuple[tuple[int, ...], ...]     # every plan, re-plans included
    visited_nodes: tuple[int, ...]
    ms_per_step: StepTimeSplit
    thresholds: dict

    def to_dict(self) -> dict:
        out = asdict(self)
        out["planned_nodes"] = list(self.planned_nodes)
        out["plans"] = [list(p) for p in self.plans]
        out["visited_nodes"] = list(self.visited_nodes)
        return out

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)


def time_split(outcome: EpisodeOutcome) -> StepTimeSplit:
    """Mean wall time per step by stage and the 95th percentile of the total (ms)."""
    if not outcome.timings:
        return StepTimeSplit(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    t = np.array([[s.read_ms, s.describe_ms, s.decide_ms, s.tick_ms] for s in outcome.timings])
    mean = t.mean(axis=0)
    total = t.sum(axis=1)
    return StepTimeSplit(*(round(float(v), 3) for v in mean), total_ms=round(float(total.mean()), 3),
                         total_p95_ms=round(float(np.percentile(total, 95)), 3))


def compute_metrics(outcome: EpisodeOutcome, true_poses: Sequence[Pose2D] = (),
                    goal_pose: Optional[Pose2D] = None, shortest_length_m: Optional[float] = None,
                    collisions: Optional[int] = None, toppled: Optional[bool] = None) -> EpisodeMetrics:
    """The metrics of ``outcome``. ``true_poses``: the true pose at every step (start and end
    included), from the simulator; ``goal_pose``: the goal's true position; without them the
    ground-truth metrics are None and success is False (it cannot be verified)."""
    final = true_poses[-1].distance_to(goal_pose) if true_poses and goal_pose is not None else None
    driven = path_length_m(true_poses) if true_poses else None
    success = bool(outcome.arrived and final is not None and final <= SUCCESS_RADIUS_M)
    tight = bool(outcome.arrived and final is not None and final <= TIGHT_RADIUS_M)
    score = spl(success, shortest_length_m, driven or 0.0) if shortest_length_m and driven is not None else None
    return EpisodeMetrics(
        success=success, success_0_5m=tight, arrived=outcome.arrived, end=outcome.end.value,
        reason=outcome.reason,
        final_distance_m=None if final is None else round(final, 4),
        path_length_m=None if driven is None else round(driven, 4),
        shortest_length_m=shortest_length_m, spl=None if score is None else round(score, 4),
        steps=outcome.steps, sim_time_s=round(outcome.sim_time_s, 3),
        wall_time_s=round(outcome.wall_time_s, 3), relocalisations=outcome.relocalisations,
        replans=outcome.replans, collisions=collisions, toppled=toppled, goal_node=outcome.goal_node,
        start_node=outcome.start_node, planned_nodes=outcome.planned_nodes, plans=outcome.plans,
        visited_nodes=outcome.visited_nodes, ms_per_step=time_split(outcome),
        thresholds={k: round(float(v), 4) for k, v in asdict(outcome.thresholds).items()})


def format_summary(m: EpisodeMetrics) -> str:
    """A short human summary (a few lines) of one episode."""
    verdict = "SUCCESS" if m.success else ("ARRIVED (outside 1.0 m)" if m.arrived else "FAILED")
    lines = [f"{verdict}: {m.reason}"]
    if m.final_distance_m is not None:
        spl_text = f", SPL {m.spl:.2f}" if m.spl is not None else ""
        shortest = f" (shortest {m.shortest_length_m:.1f} m)" if m.shortest_length_m else ""
        lines.append(f"  final distance to goal {m.final_distance_m:.2f} m, driven {m.path_length_m:.1f} m"
                     f"{shortest}{spl_text}, collisions {m.collisions}")
    t = m.ms_per_step
    lines.append(f"  {m.steps} steps, {m.sim_time_s:.1f} s simulated, {m.wall_time_s:.1f} s wall; per step "
                 f"{t.total_ms:.0f} ms = read {t.read_ms:.0f} + describe {t.describe_ms:.0f} + decide "
                 f"{t.decide_ms:.1f} + tick {t.tick_ms:.0f}")
    lines.append(f"  nodes: planned {len(m.planned_nodes)} {_nodes(m.planned_nodes)}; visited "
                 f"{len(m.visited_nodes)} {_nodes(m.visited_nodes)}; re-localisations {m.relocalisations}")
    return "\n".join(lines)


def _nodes(nodes: Sequence[int], limit: int = 12) -> str:
    if len(nodes) <= limit:
        return "[" + " ".join(map(str, nodes)) + "]"
    head = " ".join(map(str, nodes[:limit // 2]))
    tail = " ".join(map(str, nodes[-limit // 2:]))
    return f"[{head} ... {tail}]"


@dataclass(frozen=True)
class TrialSummary:
    """Success rate and mean SPL over several episodes of one route."""

    trials: int
    success_rate: float
    success_rate_0_5m: float
    mean_spl: Optional[float]
    mean_final_distance_m: Optional[float]


def summarise(metrics: Sequence[EpisodeMetrics]) -> TrialSummary:
    """SR (1.0 m and 0.5 m), mean SPL (the SPL definition's mean over episodes) and mean final distance."""
    n = len(metrics)
    if n == 0:
        return TrialSummary(0, 0.0, 0.0, None, None)
    spls = [m.spl for m in metrics if m.spl is not None]
    finals = [m.final_distance_m for m in metrics if m.final_distance_m is not None]
    return TrialSummary(trials=n, success_rate=sum(m.success for m in metrics) / n,
                        success_rate_0_5m=sum(m.success_0_5m for m in metrics) / n,
                        mean_spl=float(np.mean(spls)) if len(spls) == n else None,
                        mean_final_distance_m=float(np.mean(finals)) if finals else None)
