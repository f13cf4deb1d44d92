"""Batch mapping of a recorded walkthrough: thresholds (calibrated or explicit), the incremental
builder over every frame, then the optimisation pass (:func:`build_map`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from core.hal import Pose2D
from maps.builder import BuildLog, MapBuilder
from maps.calibration import Calibration, calibrate
from maps.config import MappingConfig, MapThresholds
from maps.graph import TopoMap
from maps.optimise import MergeResult, merge_near_duplicates


@dataclass(frozen=True)
class MapBuild:
    """What :func:`build_map` made. ``calibration`` is ``None`` for explicit thresholds;
    ``merge`` is ``None`` when the optimisation pass was skipped. ``topomap`` is the final
    (optimised) map; ``raw_map`` the builder's map before merging."""

    topomap: TopoMap
    raw_map: TopoMap
    log: BuildLog
    thresholds: MapThresholds
    calibration: Optional[Calibration] = None
    merge: Optional[MergeResult] = None
    warnings: tuple[str, ...] = field(default_factory=tuple)

    def summary(self) -> dict:
        """JSON-able numbers for a person (and ``summary.json``): frames, nodes, loop closures,
        merges, and metres when the walkthrough had true poses."""
        out = self.log.summary()
        lengths = [a.length_m for a in self.topomap.arcs() if a.kind == "sequential" and a.length_m is not None]
        out.update({
            "nodes": len(self.topomap), "nodes_before_merge": len(self.raw_map), "arcs": self.topomap.n_arcs,
            "merged_nodes": {str(k): v for k, v in self.merge.merged.items()} if self.merge is not None else {},
            "merges_rejected": [list(r) for r in self.merge.rejected] if self.merge is not None else [],
            "mean_arc_length_m": float(np.mean(lengths)) if lengths else None,
            "calibrated": self.calibration is not None, "warnings": list(self.warnings),
        })
        return out


def build_map(descriptors: np.ndarray, config: MappingConfig, *,
              frame_indices: Optional[Sequence[int]] = None, stamps_s: Optional[Sequence[float]] = None,
              true_poses: Optional[Sequence[Pose2D]] = None, optimise: bool = True,
              progress: bool = False) -> MapBuild:
    """Batch mapping of a recorded walkthrough: thresholds (calibrated or explicit), the
    builder over every frame, then the merge pass with ``T_merge`` (verified on the
    walkthrough's frames)."""
    x = np.asarray(descriptors, dtype=np.float32)
    calibration = None
    if config.calibrated:
        calibration = calibrate(x, config)
        thresholds = calibration.thresholds
    else:
        thresholds = config.explicit_thresholds()
    builder = MapBuilder(thresholds, dim=x.shape[1] if x.ndim == 2 else None)
    builder.add_frames(x, frame_indices, stamps_s, true_poses, progress=progress)
    raw, log = builder.finish()
    merge = None
    if optimise:
        keyframe_seq = {e.node_id: e.seq for e in log.node_events()}
        merge = merge_near_duplicates(raw, thresholds, frames=x, keyframe_seq=keyframe_seq)
    final = merge.topomap if merge is not None else raw
    warnings = tuple(calibration.warnings) if calibration is not None else ()
    return MapBuild(topomap=final, raw_map=raw, log=log, thresholds=thresholds,
                    calibration=calibration, merge=merge, warnings=warnings)
