"""One map being built, in the viewer, on the frame timeline of the drive (or video).

The builder runs after the thresholds were calibrated on the whole walkthrough, so the build is
logged when it is done, each decision at the frame it was taken: scrubbing the timeline shows
the map growing as the builder saw it. Per frame: ``camera/image`` the frame, ``map/robot`` the
true pose (simulator drives), ``scores/to_current_node`` the frame's similarity to the node the
builder stood at. Per decision: ``map/nodes`` and ``map/arcs`` so far, ``map/loops`` the
accepted loop closures, ``map/rejected`` the candidates that failed sequence verification, and
a line in ``mapping/events`` with the scores behind it. At the end ``map/final`` shows the map
after the merge pass.
"""

from __future__ import annotations

from typing import Any, Optional, Sequence

import numpy as np

from core.hal import Pose2D
from maps.pipeline import MapBuild
from robot.viewer import scene

_JPEG_QUALITY = 80


def log_map_build(rr: Any, stream: Any, stamps_s: Sequence[float], images: Sequence[np.ndarray],
                  descriptors: np.ndarray, build: MapBuild,
                  true_poses: Optional[Sequence[Optional[Pose2D]]] = None) -> int:
    """Log the build of ``build`` over its frames (row ``k`` of ``descriptors``, ``images[k]``,
    ``stamps_s[k]``: the frame the builder saw ``k``-th); returns the frames logged."""
    raw = build.raw_map
    ids = [int(n) for n in raw.node_ids]
    layout, _ = scene.node_positions(raw)
    where = {n: layout[k].tolist() for k, n in enumerate(ids)}
    row = {n: k for k, n in enumerate(ids)}
    nodes_desc = raw.descriptors
    log = stream.log
    if true_poses is not None and all(p is not None for p in true_poses):
        log(f"{scene.MAP}/drive", rr.LineStrips2D([[scene.view_xy(p.x_m, p.y_m) for p in true_poses]],
                                                  colors=[(200, 200, 200)], radii=0.02), static=True)
    by_seq: dict[int, list] = {}
    for event in build.log.events:
        by_seq.setdefault(int(event.seq), []).append(event)
    shown: list[int] = []
    arcs: list[list] = []
    loops: list[list] = []
    rejected: list[list] = []
    current: Optional[int] = None
    for k in range(len(images)):
        stream.set_time(scene.FRAME, sequence=k)
        stream.set_time(scene.SIM_TIME, duration=float(stamps_s[k]))
        log(f"{scene.CAMERA}/image", rr.Image(np.ascontiguousarray(images[k])).compress(jpeg_quality=_JPEG_QUALITY))
        if true_poses is not None and true_poses[k] is not None:
            log(f"{scene.MAP}/robot", rr.Points2D([scene.view_xy(true_poses[k].x_m, true_poses[k].y_m)],
                                                  colors=[(20, 20, 20)], radii=0.12))
        for event in by_seq.get(k, ()):
            current = _log_event(rr, log, event, where, shown, arcs, loops, rejected)
        if current is not None and current in row:
            log(f"{scene.SCORES}/to_current_node", rr.Scalars(float(nodes_desc[row[current]] @ descriptors[k])))
    final = build.topomap
    final_ids = [int(n) for n in final.node_ids]
    merged = build.merge.merged if build.merge is not None else {}
    log(f"{scene.MAP}/final", rr.Points2D([where[n] for n in final_ids if n in where], colors=[(0, 160, 80)],
                                          radii=0.18, labels=[str(n) for n in final_ids if n in where]))
    log(f"{scene.MAPPING}/events", rr.TextLog(
        f"map done: {len(final_ids)} nodes after merging {len(merged)} into their neighbours "
        f"({len(ids)} before), {len(loops)} loop closures, {len(rejected)} candidates rejected"))
    return len(images)


def _log_event(rr: Any, log: Any, event, where: dict, shown: list, arcs: list, loops: list,
               rejected: list) -> int:
    """One builder decision; returns the node the builder stands at afterwards."""
    node = int(event.node_id)
    prev = None if event.prev_node is None else int(event.prev_node)
    if event.kind in ("first_node", "node") and node not in shown:
        shown.append(node)
        log(f"{scene.MAP}/nodes", rr.Points2D([where[n] for n in shown if n in where], colors=[(40, 120, 255)],
                                              radii=0.12, labels=[str(n) for n in shown if n in where]))
    if prev is not None and event.new_arc and prev in where and node in where:
        strip = [where[prev], where[node]]
        if event.kind == "loop_closure":
            loops.append(strip)
            log(f"{scene.MAP}/loops", rr.LineStrips2D(loops, colors=[(0, 170, 90)], radii=0.06))
        else:
            arcs.append(strip)
            log(f"{scene.MAP}/arcs", rr.LineStrips2D(arcs, colors=[(150, 150, 150)], radii=0.03))
    if event.kind == "loop_closure":
        text, level = f"loop closure {prev} -> {node}", "INFO"
    elif event.loop_rejected:
        cand = int(event.loop_candidate)
        if cand in where and node in where:
            rejected.append([where[node], where[cand]])
            log(f"{scene.MAP}/rejected", rr.LineStrips2D(rejected, colors=[(230, 30, 60)], radii=0.03))
        text, level = f"node {node} added, loop candidate {cand} rejected", "WARN"
    else:
        text, level = f"{event.kind.replace('_', ' ')} {node}", "INFO"
    if event.reason:
        text += f": {event.reason}"
    elif event.verify_frames:
        text += (f": candidate {event.loop_candidate} at {_r(event.loop_score)}, verified over "
                 f"{event.verify_frames} frames: support {_r(event.verify_support)}, rival {_r(event.verify_rival)}")
    log(f"{scene.MAPPING}/events", rr.TextLog(text, level=level))
    return node


def _r(value: Optional[float]) -> str:
    return "-" if value is None else f"{value:.3f}"
