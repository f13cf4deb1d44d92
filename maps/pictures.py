"""Map pictures (PNG, matplotlib's Agg canvas; no pyplot, no global backend change).

* :func:`draw_map_picture` -- the graph: arcs with arrows (loop closures in red, merged arcs in
  orange), node ids, and node thumbnails. With true poses the nodes sit at their true positions,
  over a top-down world picture when one is given with its world-to-pixel function; without
  poses they sit on a ring in the order they were created, so the route reads clockwise from the
  top and a loop closure is a chord across it.
* :func:`draw_similarity_picture` -- why nodes were added: the walkthrough's frame-by-frame
  similarity matrix with the keyframes on the diagonal and loop closures marked, then the
  similarity to the current node against ``T_add_new_node`` (and the loop candidates' scores
  against ``T_loop_closure``), then the frame-to-frame change against ``T_add_distance``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable, Mapping, Optional

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.offsetbox import AnnotationBbox, OffsetImage
from matplotlib.patches import FancyArrowPatch
from matplotlib import patheffects

from maps.builder import BuildLog
from maps.calibration import SimilaritySample
from maps.graph import MapError, TopoMap

ARC_STYLE = {
    "sequential": {"color": "#4a4a4a", "lw": 1.3, "ls": "-", "label": "driven arc"},
    "loop_closure": {"color": "#d62728", "lw": 3.0, "ls": "-", "label": "loop closure"},
    "merged": {"color": "#ff7f0e", "lw": 2.2, "ls": "--", "label": "merged (optimisation)"},
}
WorldToPixel = Callable[[float, float], tuple[float, float]]


def _save(fig: Figure, out_path: str | Path, dpi: int) -> Path:
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(out, dpi=dpi, format="png")
    return out


def _positions(topomap: TopoMap, background: Optional[np.ndarray],
               world_to_pixel: Optional[WorldToPixel]) -> tuple[dict[int, np.ndarray], str]:
    """Node id -> (x, y) in plot coordinates, and the layout's name."""
    nodes = topomap.nodes()
    if topomap.has_true_poses:
        if background is not None:
            if world_to_pixel is None:
                raise MapError("a background picture needs its world_to_pixel function")
            return {n.node_id: np.asarray(world_to_pixel(n.true_pose.x_m, n.true_pose.y_m), dtype=float)
                    for n in nodes}, "pixels"
        return {n.node_id: np.array([n.true_pose.x_m, n.true_pose.y_m]) for n in nodes}, "metres"
    count = len(nodes)
    pos = {}
    for k, n in enumerate(nodes):
        a = math.pi / 2 - 2 * math.pi * k / max(count, 1)
        pos[n.node_id] = np.array([math.cos(a), math.sin(a)])
    return pos, "ring"


def _thumbnail_nodes(topomap: TopoMap, max_thumbnails: int) -> list[int]:
    """All nodes when few; else the ends of loop-closure and merged arcs (up to a third of the
    budget) plus nodes evenly spaced in creation order."""
    ids = topomap.node_ids.tolist()
    if len(ids) <= max_thumbnails:
        return ids
    special = sorted({e for a in topomap.arcs() if a.kind != "sequential" for e in (a.src, a.dst)})
    special = special[: max_thumbnails // 3]
    even = np.linspace(0, len(ids) - 1, max(1, max_thumbnails - len(special))).round().astype(int)
    return sorted(set(special) | {ids[k] for k in even})


def draw_map_picture(topomap: TopoMap, out_path: str | Path, *,
                     thumbnail: Optional[Callable[[int], Optional[np.ndarray]]] = None,
                     background: Optional[np.ndarray] = None, world_to_pixel: Optional[WorldToPixel] = None,
                     title: str = "", max_thumbnails: int = 36, dpi: int = 110) -> Path:
    """Write the map picture to ``out_path`` (PNG) and return the path.

    ``thumbnail(node_id)`` returns an RGB uint8 image or ``None`` (e.g. ``LoadedMap.thumbnail``).
    ``background``: RGB top-down world picture; ``world_to_pixel(x_m, y_m) -> (col, row)`` maps
    world metres to its pixels. Both are used only when every node has a true pose.
    """
    if len(topomap) == 0:
        raise MapError("cannot draw an empty map")
    pos, layout = _positions(topomap, background, world_to_pixel)
    fig = Figure(figsize=(12, 10))
    ax = fig.add_subplot(1, 1, 1)
    xy = np.array(list(pos.values()))
    span = float(np.ptp(xy, axis=0).max()) or 1.0
    if layout == "pixels":
        ax.imshow(background, zorder=0)
        ax.set_axis_off()
    elif layout == "metres":
        ax.set_aspect("equal")
        ax.grid(True, alpha=0.3)
        ax.set_xlabel("x [m] (true positions from the simulator)")
        ax.set_ylabel("y [m]")
    else:
        ax.set_aspect("equal")
        ax.set_axis_off()
        ax.text(0.5, 0.5, "no true positions:\nnodes in creation order,\nclockwise from the top",
                transform=ax.transAxes, ha="center", va="center", fontsize=11, color="#777777")

    # a white outline keeps arcs and labels readable over a busy world picture
    halo = [patheffects.withStroke(linewidth=3.5, foreground="white")] if layout == "pixels" else None
    _draw_headings(ax, topomap, pos, layout, world_to_pixel, span)
    pairs = {(a.src, a.dst) for a in topomap.arcs()}
    for arc in sorted(topomap.arcs(), key=lambda a: a.kind != "sequential"):
        style = ARC_STYLE[arc.kind]
        bend = 0.2 if (arc.dst, arc.src) in pairs else (0.12 if arc.kind != "sequential" else 0.0)
        ax.add_patch(FancyArrowPatch(pos[arc.src], pos[arc.dst], arrowstyle="-|>", mutation_scale=14,
                                     color=style["color"], lw=style["lw"], ls=style["ls"],
                                     shrinkA=6, shrinkB=6, connectionstyle=f"arc3,rad={bend}", zorder=2,
                                     path_effects=halo))
    special = {e for a in topomap.arcs() if a.kind != "sequential" for e in (a.src, a.dst)}
    ids = topomap.node_ids.tolist()
    ax.scatter(xy[:, 0], xy[:, 1], s=40, c="white", edgecolors="#1f3b73", linewidths=1.5, zorder=3)
    if special:
        sp = np.array([pos[i] for i in sorted(special)])
        ax.scatter(sp[:, 0], sp[:, 1], s=110, facecolors="none", edgecolors="#d62728", linewidths=2, zorder=3)
    label_every = max(1, len(ids) // 60)
    for k, i in enumerate(ids):
        if k % label_every == 0 or i in special:
            ax.annotate(str(i), pos[i], xytext=(4, 4), textcoords="offset points", fontsize=8,
                        color="#1f3b73", zorder=4, fontweight="bold",
                        path_effects=[patheffects.withStroke(linewidth=2.5, foreground="white")])

    if thumbnail is not None:
        centre = xy.mean(axis=0)
        flip = -1.0 if layout == "pixels" else 1.0      # image rows grow downwards
        for i in _thumbnail_nodes(topomap, max_thumbnails):
            img = thumbnail(i)
            if img is None:
                continue
            d = pos[i] - centre
            d = d / (np.linalg.norm(d) or 1.0)
            box = AnnotationBbox(OffsetImage(img, zoom=0.33), pos[i], xybox=(52 * d[0], 52 * d[1] * flip),
                                 boxcoords="offset points", pad=0.15, zorder=5,
                                 bboxprops={"edgecolor": "#d62728" if i in special else "#1f3b73", "lw": 1.2},
                                 arrowprops={"arrowstyle": "-", "color": "#1f3b73", "lw": 0.6})
            ax.add_artist(box)
    if layout == "pixels":
        # room around the world picture for the thumbnails of nodes near its border
        h, w = background.shape[:2]
        pad = 0.12 * max(h, w)
        ax.set_xlim(min(-pad, xy[:, 0].min() - pad), max(w + pad, xy[:, 0].max() + pad))
        ax.set_ylim(max(h + pad, xy[:, 1].max() + pad), min(-pad, xy[:, 1].min() - pad))
    else:
        margin = 0.18 * span + (0.35 if layout == "ring" else 0.0)
        lo, hi = xy.min(axis=0) - margin, xy.max(axis=0) + margin
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])

    kinds = {a.kind for a in topomap.arcs()}
    handles = [Line2D([], [], color=ARC_STYLE[k]["color"], lw=ARC_STYLE[k]["lw"], ls=ARC_STYLE[k]["ls"],
                      label=ARC_STYLE[k]["label"]) for k in ARC_STYLE if k in kinds]
    handles.append(Line2D([], [], marker="o", ls="", mfc="white", mec="#1f3b73", label="node (id)"))
    if layout != "ring":
        handles.append(Line2D([], [], color="#2ca02c", lw=2, label="heading of the node's image"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=10, frameon=False)
    n_loops = sum(1 for a in topomap.arcs() if a.kind == "loop_closure")
    n_merged = sum(1 for a in topomap.arcs() if a.kind == "merged")
    heading = f"{title} - " if title else ""
    ax.set_title(f"{heading}{len(topomap)} nodes, {topomap.n_arcs} arcs, {n_loops} loop closures, "
                 f"{n_merged} merged arcs", fontsize=12)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    return _save(fig, out_path, dpi)


def _draw_headings(ax, topomap: TopoMap, pos: dict, layout: str,
                   world_to_pixel: Optional[WorldToPixel], span: float) -> None:
    """A short green tick from each node in the direction its image faces (poses only)."""
    if layout == "ring":
        return
    for node in topomap.nodes():
        p = node.true_pose
        c, s = math.cos(p.yaw_rad), math.sin(p.yaw_rad)
        if layout == "pixels":
            ahead = np.asarray(world_to_pixel(p.x_m + c, p.y_m + s), dtype=float) - pos[node.node_id]
            c, s = ahead / (np.linalg.norm(ahead) or 1.0)
        tip = pos[node.node_id] + 0.035 * span * np.array([c, s])
        ax.plot([pos[node.node_id][0], tip[0]], [pos[node.node_id][1], tip[1]], color="#2ca02c",
                lw=2.2, zorder=3.5, solid_capstyle="round")


def draw_similarity_picture(similarity: SimilaritySample, log: BuildLog, out_path: str | Path, *,
                            merged: Optional[Mapping[int, int]] = None, title: str = "",
                            dpi: int = 110) -> Path:
    """Write the "why these nodes" picture to ``out_path`` (PNG) and return the path.

    ``similarity``: :func:`maps.calibration.similarity_sample` of the walkthrough's descriptors
    (frame positions in the fed sequence). ``log``: the builder's log. ``merged``: the
    optimisation pass's removed -> kept node ids, marked as orange diamonds.
    """
    seq = np.asarray(similarity.seq)
    mat = np.asarray(similarity.matrix, dtype=np.float32)
    if mat.shape != (seq.size, seq.size) or seq.size == 0:
        raise MapError(f"similarity matrix {mat.shape} does not match its {seq.size} frames")
    t = log.thresholds
    node_seq = {e.node_id: e.seq for e in log.node_events()}
    fig = Figure(figsize=(11, 14))
    gs = fig.add_gridspec(3, 2, height_ratios=[3.2, 1.4, 1.0], width_ratios=[40, 1], hspace=0.22, wspace=0.03)
    ax_m = fig.add_subplot(gs[0, 0])
    ax_s = fig.add_subplot(gs[1, 0], sharex=ax_m)
    ax_d = fig.add_subplot(gs[2, 0], sharex=ax_m)
    half = (seq[1] - seq[0]) / 2 if seq.size > 1 else 0.5
    extent = (seq[0] - half, seq[-1] + half, seq[-1] + half, seq[0] - half)
    vmin = float(np.quantile(mat, 0.01))
    im = ax_m.imshow(mat, extent=extent, cmap="magma", vmin=vmin, vmax=1.0, aspect="auto",
                     interpolation="nearest")
    fig.colorbar(im, cax=fig.add_subplot(gs[0, 1]), label="cosine similarity")
    ks = np.array(sorted(node_seq.values()))
    ax_m.scatter(ks, ks, s=28, c="#2ca02c", edgecolors="white", linewidths=0.8, zorder=3, label="node keyframe")
    loops = log.loop_closure_events()
    if loops:
        lx = np.array([e.seq for e in loops])
        ly = np.array([node_seq.get(e.node_id, np.nan) for e in loops])
        ax_m.scatter(np.r_[lx, ly], np.r_[ly, lx], s=90, marker="X", c="#00e5ff", edgecolors="black",
                     linewidths=0.8, zorder=4, label="loop closure (frame, matched node)")
    if merged:
        pts = [(node_seq[a], node_seq[b]) for a, b in merged.items() if a in node_seq and b in node_seq]
        if pts:
            mx, my = np.array(pts).T
            ax_m.scatter(np.r_[mx, my], np.r_[my, mx], s=70, marker="D", c="#ff7f0e", edgecolors="black",
                         linewidths=0.8, zorder=4, label="merged nodes")
    ax_m.set_ylabel("frame (position in walkthrough)")
    ax_m.legend(loc="lower left", fontsize=9, framealpha=0.9)
    ax_m.tick_params(labelbottom=False)
    heading = f"{title} - " if title else ""
    ax_m.set_title(f"{heading}{log.n_frames} frames, {len(log.node_events())} nodes added, "
                   f"{len(loops)} loop closures", fontsize=12)

    frames = np.arange(log.n_frames)
    ax_s.plot(frames, log.sim_to_node, color="#1f77b4", lw=1.0, label="similarity to current node")
    ax_s.axhline(t.T_add_new_node, color="#1f77b4", ls="--", lw=1.2, label=f"T_add_new_node {t.T_add_new_node:.3f}")
    ax_s.axhline(t.T_loop_closure, color="#d62728", ls="--", lw=1.2, label=f"T_loop_closure {t.T_loop_closure:.3f}")
    for e in log.events:
        if e.kind == "node":
            ax_s.axvline(e.seq, color="#2ca02c", lw=0.7, alpha=0.7)
        elif e.kind == "loop_closure":
            ax_s.axvline(e.seq, color="#d62728", lw=1.5, alpha=0.9)
    cand = [(e.seq, e.loop_score, e.kind == "loop_closure") for e in log.events if e.loop_score is not None]
    if cand:
        cx, cy, hit = (np.array(v) for v in zip(*cand))
        ax_s.scatter(cx[~hit], cy[~hit], s=18, facecolors="none", edgecolors="#d62728",
                     label="best loop candidate (rejected)", zorder=3)
        if hit.any():
            ax_s.scatter(cx[hit], cy[hit], s=40, c="#d62728", label="loop closure accepted", zorder=3)
    finite = log.sim_to_node[np.isfinite(log.sim_to_node)]
    lo = min(float(finite.min()) if finite.size else 0.0, t.T_add_new_node, t.T_loop_closure) - 0.05
    ax_s.set_ylim(lo, 1.02)
    ax_s.set_ylabel("similarity")
    ax_s.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), fontsize=8, ncol=3, frameon=False)
    ax_s.tick_params(labelbottom=False)
    ax_s.text(0.995, 0.04, "green lines: nodes added, red: loop closures", transform=ax_s.transAxes,
              ha="right", fontsize=8, color="#555555")

    change = np.clip(1.0 - log.sim_to_prev.astype(np.float64), 1e-6, None)
    counted = change > 1.0 - t.T_add_distance
    ax_d.scatter(frames[counted], change[counted], s=4, c="#9467bd", label="counted as motion (M_distance + 1)")
    ax_d.scatter(frames[~counted], change[~counted], s=4, c="#bbbbbb", label="still (not counted)")
    ax_d.axhline(max(1.0 - t.T_add_distance, 1e-6), color="#9467bd", ls="--", lw=1.2,
                 label=f"1 - T_add_distance ({1 - t.T_add_distance:.2e})")
    ax_d.set_yscale("log")
    ax_d.set_ylabel("1 - sim(frame, previous)")
    ax_d.set_xlabel("frame (position in walkthrough)")
    ax_d.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), fontsize=8, ncol=3, frameon=False, markerscale=3)
    fig.subplots_adjust(left=0.08, right=0.93, top=0.96, bottom=0.05)
    return _save(fig, out_path, dpi)
