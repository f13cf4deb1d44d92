"""MapThresholds from the walkthrough itself, instead of hand-tuning (the paper's main limitation).

:func:`calibrate` looks at the descriptors of every frame of a walkthrough (in order) and
measures three things:

* the **decay curve** ``s(k)``: the median similarity of frames ``k`` apart, for
  ``k = 1..max_lag``. ``s(1)`` (``s_top``) is how alike consecutive frames are;
* the **unrelated level** ``s_floor``: the median similarity of frames at least ``max_lag``
  apart, and from it the **decay gap**: the first lag where ``s(k)`` has fallen to within 10 % of
  the way from ``s_floor`` to ``s_top``. Frames closer than the gap are "neighbours";
* the **non-neighbour distribution**: similarities of frame pairs at least the gap apart, on an
  evenly spaced sample of frames. Its high quantile is how alike two different places can look.

and sets:

* ``T_add_new_node = s_top - f * (s_top - s_floor)`` with ``f = 0.1 + 0.8 * sparsity``: a new
  node when the similarity has decayed a fraction ``f`` of the way to the unrelated level. The
  lag where ``s(k)`` crosses it is the expected spacing in frames;
* ``T_interval = max(1, round(INTERVAL_FRACTION * expected spacing))``: a turn may add nodes
  faster than driving does, but not in a burst;
* ``T_add_distance = 1 - d``, ``d = min(max(1.5 * d05, 0.25 * d50), 0.75 * d50)`` where ``d05``
  and ``d50`` are quantiles of the frame-to-frame dissimilarity ``1 - sim(i, i-1)``: a frame
  counts as motion when it changed clearly more than the quietest 5 % of frames (the noise of a
  still camera, or the slowest motion when the robot never stops), and always when it changed
  three quarters of a median step; never when it changed less than a quarter of one;
* the **spurious level** ``q``: the ``SPURIOUS_QUANTILE`` (0.999) quantile of the non-neighbour
  similarities: how alike two different places of this walkthrough can look. It is a high
  quantile, not the maximum, because the non-neighbour pairs include the walkthrough's real
  revisits (the loop itself), which are the most alike of all; the 0.99 quantile is too low
  (look-alike corridors and bare-wall corners score above it);
* ``T_loop_closure = max(q, revisit)``, ``revisit = s(spacing / 2)``: a candidate must look more
  alike than different places do, and at least as alike as the walkthrough's own frames half a
  node spacing apart, because the loop check happens when the frame is a node spacing away from
  the last node, and a true revisit is then at most half a spacing from some old node
  (``REVISIT_FRACTION`` scales this floor between ``T_add_new_node`` (0) and ``revisit`` (1));
* ``T_loop_verify = revisit`` (at least ``T_add_new_node``, at most ``T_loop_closure``): on a real
  revisit no frame is farther than half a spacing from a node of the old route, so the frames
  after the candidate keep matching the tracked stretch of route at least this well on average;
* ``loop_verify_frames = decay gap``: the frames it takes the view to become unrelated to where
  it was. Two look-alike places (corners with bare walls, say) stay alike while the robot turns
  in front of them; by the time the view has changed completely the routes have parted;
* ``T_merge = max(q, T_add_new_node)`` (at most ``T_loop_closure``): the lower, after-the-fact loop
  threshold for revisits the builder missed, but never below the spurious level (two places
  that different places can match as well are not duplicates) nor below ``T_add_new_node`` (two
  nodes less alike than a node spacing are not duplicates); every merge is also sequence-verified;
* ``loop_min_gap_frames = decay gap``.

Higher ``sparsity`` lowers ``T_add_new_node`` and raises ``T_interval``, so the map gets sparser
monotonically. All statistics used are returned for the map file.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np

from maps.config import MappingConfig, MapThresholds
from maps.graph import MapError

#: the quantile of the frames' best look-alike similarity taken as the spurious level
LOOK_ALIKE_QUANTILE = 0.5
#: T_loop_closure is at least this fraction of the way from T_add_new_node to the revisit level
REVISIT_FRACTION = 1.0
#: the node interval as a fraction of the expected frames between nodes
INTERVAL_FRACTION = 0.25
#: the decay gap: where s(k) is within this fraction of the range above the unrelated level
GAP_FRACTION = 0.1
#: fewer frames than this cannot give statistics
MIN_FRAMES = 20


class CalibrationError(MapError):
    """The walkthrough cannot be calibrated (too short, no motion, no contrast)."""


@dataclass(frozen=True)
class SimilaritySample:
    """Frame-by-frame similarity of an evenly spaced sample of a walkthrough.

    ``seq`` (M,) are the sampled frames' positions in the fed sequence, ``matrix`` (M, M) float16
    their pairwise similarities. Small enough to keep in a map folder for its pictures.
    """

    seq: np.ndarray
    matrix: np.ndarray


@dataclass(frozen=True)
class Calibration:
    """Calibrated thresholds plus the statistics (JSON-able) and warnings behind them."""

    thresholds: MapThresholds
    stats: dict
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        return {"thresholds": self.thresholds.to_dict(), "stats": self.stats, "warnings": list(self.warnings)}


def _as_descriptors(descriptors: np.ndarray) -> np.ndarray:
    x = np.asarray(descriptors, dtype=np.float32)
    if x.ndim != 2:
        raise CalibrationError(f"descriptors must be (N, D), got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise CalibrationError("descriptors have NaN or infinite values")
    return x


def similarity_sample(descriptors: np.ndarray, max_frames: int = 600) -> SimilaritySample:
    """Pairwise similarity of at most ``max_frames`` evenly spaced frames (one BLAS call)."""
    x = _as_descriptors(descriptors)
    n = x.shape[0]
    if n == 0:
        raise CalibrationError("no frames to compare")
    seq = np.unique(np.linspace(0, n - 1, min(n, max_frames)).round().astype(np.int64))
    sub = x[seq]
    return SimilaritySample(seq=seq, matrix=(sub @ sub.T).astype(np.float16))


def lag_similarities(descriptors: np.ndarray, max_lag: int, block: int = 256) -> np.ndarray:
    """(N, max_lag) similarities ``sim(i, i + k)`` for ``k = 1..max_lag`` (NaN past the end).

    Computed block by block with matrix products, so the cost is about
    ``N * (block + max_lag) * D`` multiply-adds and memory stays at ``N * max_lag`` floats.
    """
    x = _as_descriptors(descriptors)
    n = x.shape[0]
    out = np.full((n, max_lag), np.nan, dtype=np.float32)
    lags = np.arange(max_lag)
    for a in range(0, n - 1, block):
        rows = x[a:a + block]
        cols = x[a + 1:min(n, a + block + max_lag)]
        g = rows @ cols.T                                   # g[r, c] = sim(a + r, a + 1 + c)
        idx = np.arange(rows.shape[0])[:, None] + lags[None, :]
        valid = idx < g.shape[1]
        picked = np.take_along_axis(g, np.minimum(idx, g.shape[1] - 1), axis=1)
        out[a:a + rows.shape[0]] = np.where(valid, picked, np.nan)
    return out


def node_decay_fraction(sparsity: float) -> float:
    """How far (0..1) the similarity decays from ``s_top`` towards ``s_floor`` before a new node:
    ``0.1 + 0.8 * sparsity``."""
    return 0.1 + 0.8 * float(sparsity)


def node_level_at(stats: Mapping, sparsity: float) -> Optional[float]:
    """``T_add_new_node`` that the calibration ``stats`` (``Calibration.stats``) give at another
    ``sparsity``: the similarity of two consecutive nodes had the map been built at that spacing.
    ``None`` when the stats lack ``s_top`` or ``s_floor`` (older maps)."""
    try:
        s_top, s_floor = float(stats["s_top"]), float(stats["s_floor"])
    except (KeyError, TypeError, ValueError):
        return None
    return s_top - node_decay_fraction(sparsity) * (s_top - s_floor)


def _first_lag_below(curve: np.ndarray, level: float) -> int | None:
    """The first lag k (1-based) with curve[k-1] < level, or None."""
    hits = np.nonzero(curve < level)[0]
    return int(hits[0]) + 1 if hits.size else None


def calibrate(descriptors: np.ndarray, config: MappingConfig, *, max_lag: int = 300,
              max_sample_frames: int = 1500) -> Calibration:
    """Derive :class:`MapThresholds` from a walkthrough's (N, D) descriptors (see module docstring).

    ``config`` gives ``sparsity``, ``loop_exclude_recent_nodes`` and ``loop_verify_hops``.
    Deterministic (no random sampling). Raises :class:`CalibrationError` when the walkthrough is
    too short or shows no motion.
    """
    x = _as_descriptors(descriptors)
    n = x.shape[0]
    if n < MIN_FRAMES:
        raise CalibrationError(f"calibration needs at least {MIN_FRAMES} frames, the walkthrough has {n}")
    warnings: list[str] = []
    lag_cap = max(2, min(max_lag, n // 2))
    lag = lag_similarities(x, lag_cap)
    curve = np.nanmedian(lag, axis=0)
    consecutive = lag[:-1, 0]
    s_top = float(curve[0])

    sample = similarity_sample(x, max_sample_frames)
    dseq = np.abs(sample.seq[:, None] - sample.seq[None, :])
    upper = np.triu(np.ones_like(dseq, dtype=bool), k=1)
    sims = sample.matrix.astype(np.float32)
    far = sims[upper & (dseq >= lag_cap)]
    if far.size < 10:
        far = sims[upper & (dseq >= max(1, lag_cap // 2))]
    s_floor = float(np.median(far))
    contrast = s_top - s_floor
    if contrast < 0.02:
        raise CalibrationError(
            f"consecutive frames (median similarity {s_top:.3f}) are hardly more alike than unrelated "
            f"frames ({s_floor:.3f}): the walkthrough shows no motion or the descriptor cannot see it")

    gap = _first_lag_below(curve, s_floor + GAP_FRACTION * contrast)
    if gap is None:
        gap = lag_cap
        warnings.append(f"similarity was still decaying at lag {lag_cap} frames: the walkthrough is short "
                        f"for its frame rate; loop_min_gap_frames set to {lag_cap}")
    near_mask = upper & (dseq >= gap)
    non_neighbour = sims[near_mask]
    f = node_decay_fraction(config.sparsity)
    t_add = s_top - f * contrast
    # each frame's best look-alike: its most similar frame at least the gap away
    far_enough = dseq >= gap
    has_far = far_enough.any(axis=1)
    look_alike = np.where(far_enough, sims, -np.inf).max(axis=1)[has_far]
    q = float(np.quantile(look_alike, LOOK_ALIKE_QUANTILE)) if look_alike.size else float(np.max(non_neighbour))

    spacing = _first_lag_below(curve, t_add)
    if spacing is None:
        spacing = lag_cap
        warnings.append(f"similarity never fell below T_add_new_node {t_add:.3f} within {lag_cap} frames; "
                        f"expect very sparse nodes")
    t_interval = max(1, int(round(INTERVAL_FRACTION * spacing)))

    d = 1.0 - consecutive.astype(np.float64)
    d05, d50, d75 = (float(v) for v in np.quantile(d, [0.05, 0.5, 0.75]))
    if d50 <= 1e-7:
        raise CalibrationError("half of the consecutive frames are identical: the walkthrough "
                               "does not move enough to measure a motion step")
    d_thr = min(max(1.5 * d05, 0.25 * d50), 0.75 * d50)
    t_add_distance = 1.0 - d_thr

    revisit_level = float(curve[max(0, spacing // 2 - 1)])
    t_loop = max(q, t_add + REVISIT_FRACTION * max(0.0, revisit_level - t_add))
    t_verify = min(max(revisit_level, t_add, q), t_loop)
    t_merge = t_verify
    if q > revisit_level:
        warnings.append(f"T_loop_closure {t_loop:.3f} (the spurious level) is above the similarity of frames half "
                        f"a node apart ({revisit_level:.3f}): loop closures will need near-exact revisits")

    thresholds = MapThresholds(
        T_add_new_node=float(np.clip(t_add, -1.0, 1.0)), T_interval=t_interval,
        T_add_distance=float(np.clip(t_add_distance, -1.0, 1.0)),
        T_loop_closure=float(np.clip(t_loop, -1.0, 1.0)), T_merge=float(np.clip(t_merge, -1.0, 1.0)),
        loop_min_gap_frames=int(gap), loop_exclude_recent_nodes=config.loop_exclude_recent_nodes,
        T_loop_verify=float(np.clip(t_verify, -1.0, 1.0)), loop_verify_frames=int(gap),
        loop_verify_hops=config.loop_verify_hops)
    curve_points = np.unique(np.geomspace(1, lag_cap, num=min(lag_cap, 40)).round().astype(int))
    stats = {
        "n_frames": n, "sparsity": config.sparsity, "node_decay_fraction": f,
        "max_lag": lag_cap, "s_top": s_top, "s_floor": s_floor, "decay_gap_frames": int(gap),
        "expected_frames_per_node": int(spacing),
        "decay_curve": [[int(k), float(curve[k - 1])] for k in curve_points],
        "non_neighbour": {"pairs": int(non_neighbour.size), "sample_frames": int(sample.seq.size),
                          "q50": float(np.median(non_neighbour)),
                          "q90": float(np.quantile(non_neighbour, 0.9)),
                          "q99": float(np.quantile(non_neighbour, 0.99)),
                          "q99.9": float(np.quantile(non_neighbour, 0.999)),
                          "look_alike_q50": float(np.median(look_alike)) if look_alike.size else None,
                          "look_alike_q90": float(np.quantile(look_alike, 0.9)) if look_alike.size else None,
                          "spurious_level": q,
                          "max": float(non_neighbour.max())},
        "frame_step_dissimilarity": {"q05": d05, "q50": d50, "q75": d75, "moving_threshold": d_thr},
        "revisit_level": revisit_level,
        "constants": {"LOOK_ALIKE_QUANTILE": LOOK_ALIKE_QUANTILE, "REVISIT_FRACTION": REVISIT_FRACTION,
                      "INTERVAL_FRACTION": INTERVAL_FRACTION,
                      "GAP_FRACTION": GAP_FRACTION},
    }
    return Calibration(thresholds=thresholds, stats=stats, warnings=tuple(warnings))
