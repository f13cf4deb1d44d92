"""Map pictures (PNG, matplotlib's Agg canvas; no pyplot, no global backend change).

* :func:`draw_map_picture` -- the graph: arcs with arrows (loop closures in red, merged arcs in
  orange, rejected look-alikes dotted purple), node ids, and a strip of node thumbnails below.
  With true poses the nodes sit at their true positions, with a tick where their image faces,
  over a faded top-down world picture (cropped to the route) when one is given with its
  world-to-pixel function; without poses they sit on a ring in the order they were created, so
  the route reads clockwise from the top and a loop closure is a chord across it.
* :func:`draw_similarity_picture` -- why nodes were added: the walkthrough's frame-by-frame
  similarity matrix with the keyframes on the diagonal and loop closures marked, then the
  similarity to the current node against ``T_add_new_node`` (and the loop candidates' scores
  against ``T_loop_closure``, with the sequence-verification support of those above it, accepted
  in red and rejected look-alikes in purple), then the frame-to-frame change against
  ``T_add_distance``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable, Mapping, Optional, Sequence

import numpy as np
from matplotlib import patheffects
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import FancyArrowPatch

from core.atomic import save_figure
from maps.builder import BuildLog
from maps.calibration import SimilaritySample
from maps.graph import MapError, TopoMap

ARC_STYLE = {
    "sequential": {"color": "#4a4a4a", "lw": 1.3, "ls": "-", "label": "driven arc"},
    "loop_closure": {"color": "#d62728", "lw": 3.0, "ls": "-", "label": "loop closure"},
    "merged": {"color": "#ff7f0e", "lw": 2.2, "ls": "--", "label": "merged (optimisation)"},
}
WorldToPixel = Callable[[float, float], tuple[float, float]]
NODE_COLOR = "#1f3b73"
BACKGROUND_FADE = 0.45          # share of white blended into the world picture
HEADING_COLOR = "#2ca02c"
REJECTED_COLOR = "#9467bd"      # purple: far from the loop-closure red, so "no red" still means "no loop"


def _save(fig: Figure, out_path: str | Path, dpi: int) -> Path:
    FigureCanvasAgg(fig)
    return save_figure(fig, out_path, dpi=dpi)


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
    if max_thumbnails <= 0:
        return []
    if len(ids) <= max_thumbnails:
        return ids
    special = sorted({e for a in topomap.arcs() if a.kind != "sequential" for e in (a.src, a.dst)})
    special = special[: max_thumbnails // 3]
    even = np.linspace(0, len(ids) - 1, max(1, max_thumbnails - len(special))).round().astype(int)
    picked = sorted(set(special) | {ids[k] for k in even})
    return picked[:max_thumbnails]


def _view_box(xy: np.ndarray, layout: str, background: Optional[np.ndarray]) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) of the part of the plane to show: the nodes with a margin, and on a world
    picture at most the picture (its legend panel and empty floor are left out when no node is
    near them, so the world is drawn large)."""
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    if layout == "ring":
        return -1.3, 1.3, -1.3, 1.3
    span = float(max(hi - lo)) or 1.0
    pad = 0.06 * span
    if layout == "pixels":
        h, w = background.shape[:2]
        pad = max(pad, 0.03 * max(h, w))
        return max(0.0, lo[0] - pad), min(float(w), hi[0] + pad), max(0.0, lo[1] - pad), min(float(h), hi[1] + pad)
    pad = max(pad, 0.5)
    return lo[0] - pad, hi[0] + pad, lo[1] - pad, hi[1] + pad


def draw_map_picture(topomap: TopoMap, out_path: str | Path, *,
                     thumbnail: Optional[Callable[[int], Optional[np.ndarray]]] = None,
                     background: Optional[np.ndarray] = None, world_to_pixel: Optional[WorldToPixel] = None,
                     title: str = "", max_thumbnails: int = 12,
                     rejected_loops: Sequence[tuple[int, int]] = (), dpi: int = 110) -> Path:
    """Write the map picture to ``out_path`` (PNG) and return the path.

    The map fills the picture: nodes as dots with their ids and (with true poses) a tick in the
    direction their image faces, arcs with arrows, loop closures thick red with ringed ends,
    merged arcs dashed orange, and ``rejected_loops`` (node, candidate) pairs, the look-alikes
    that sequence verification turned down, dotted purple. A strip below shows up to
    ``max_thumbnails`` node images (loop-closure ends first, then evenly spaced nodes), each
    labelled with its node id, which is boxed on the map.

    ``thumbnail(node_id)`` returns an RGB uint8 image or ``None`` (e.g. ``LoadedMap.thumbnail``).
    ``background``: RGB top-down world picture; ``world_to_pixel(x_m, y_m) -> (col, row)`` maps
    world metres to its pixels. Both are used only when every node has a true pose; the picture
    is cropped to the nodes with a margin.
    """
    if len(topomap) == 0:
        raise MapError("cannot draw an empty map")
    pos, layout = _positions(topomap, background, world_to_pixel)
    ids = topomap.node_ids.tolist()
    xy = np.array([pos[i] for i in ids])
    x0, x1, y0, y1 = _view_box(xy, layout, background)
    span = max(x1 - x0, y1 - y0)
    thumbs: list[tuple[int, np.ndarray]] = []
    if thumbnail is not None:
        for i in _thumbnail_nodes(topomap, max_thumbnails):
            img = thumbnail(i)
            if img is not None:
                thumbs.append((i, np.asarray(img)))

    width_in = 14.0
    map_h_in = float(np.clip(width_in * (y1 - y0) / max(x1 - x0, 1e-9), 5.0, 11.0))
    strip_h_in = 1.9 if thumbs else 0.0
    fig = Figure(figsize=(width_in, map_h_in + strip_h_in + 1.0))
    gs = fig.add_gridspec(2 if thumbs else 1, max(1, len(thumbs)),
                          height_ratios=[map_h_in, strip_h_in] if thumbs else [1.0], hspace=0.08, wspace=0.06)
    ax = fig.add_subplot(gs[0, :])
    if layout == "pixels":
        # faded, so the map's own marks stand out against the world's route bands and labels
        faded = (BACKGROUND_FADE * 255 + (1.0 - BACKGROUND_FADE) * np.asarray(background, dtype=np.float32))
        ax.imshow(faded.astype(np.uint8), zorder=0, interpolation="antialiased")
        ax.set_axis_off()
    elif layout == "metres":
        ax.grid(True, alpha=0.3)
        ax.set_xlabel("x [m] (true positions from the simulator)")
        ax.set_ylabel("y [m]")
    else:
        ax.set_axis_off()
        ax.text(0.5, 0.5, "no true positions:\nnodes in creation order,\nclockwise from the top",
                transform=ax.transAxes, ha="center", va="center", fontsize=11, color="#777777")
    ax.set_aspect("equal")

    # a white outline keeps arcs and labels readable over a busy world picture
    halo = [patheffects.withStroke(linewidth=3.0, foreground="white")] if layout == "pixels" else None
    text_halo = [patheffects.withStroke(linewidth=2.5, foreground="white")]
    _draw_headings(ax, topomap, pos, layout, world_to_pixel, span)
    for a, b in rejected_loops:
        if a in pos and b in pos:
            ax.plot([pos[a][0], pos[b][0]], [pos[a][1], pos[b][1]], color=REJECTED_COLOR, lw=1.4, ls=":",
                    zorder=1.5)
    pairs = {(a.src, a.dst) for a in topomap.arcs()}
    for arc in sorted(topomap.arcs(), key=lambda a: a.kind != "sequential"):
        style = ARC_STYLE[arc.kind]
        bend = 0.2 if (arc.dst, arc.src) in pairs else (0.12 if arc.kind != "sequential" else 0.0)
        ax.add_patch(FancyArrowPatch(pos[arc.src], pos[arc.dst], arrowstyle="-|>", mutation_scale=11,
                                     color=style["color"], lw=style["lw"], ls=style["ls"],
                                     shrinkA=4, shrinkB=4, connectionstyle=f"arc3,rad={bend}", zorder=2,
                                     path_effects=halo))
    special = {e for a in topomap.arcs() if a.kind != "sequential" for e in (a.src, a.dst)}
    ax.scatter(xy[:, 0], xy[:, 1], s=26, c=NODE_COLOR, edgecolors="white", linewidths=0.9, zorder=3)
    if special:
        sp = np.array([pos[i] for i in sorted(special)])
        ax.scatter(sp[:, 0], sp[:, 1], s=150, facecolors="none", edgecolors=ARC_STYLE["loop_closure"]["color"],
                   linewidths=2.2, zorder=3)
    shown = {i for i, _ in thumbs}
    label_every = max(1, math.ceil(len(ids) / 45))
    for k, i in enumerate(ids):
        if i in shown:
            ax.annotate(str(i), pos[i], xytext=(5, 5), textcoords="offset points", fontsize=9, fontweight="bold",
                        color="white", zorder=5,
                        bbox={"boxstyle": "round,pad=0.2", "fc": _thumb_edge(i, special), "ec": "none"})
        elif k % label_every == 0 or i in special:
            ax.annotate(str(i), pos[i], xytext=(4, 4), textcoords="offset points", fontsize=8,
                        color=NODE_COLOR, zorder=4, fontweight="bold", path_effects=text_halo)
    ax.set_xlim(x0, x1)
    if layout == "pixels":
        ax.set_ylim(y1, y0)          # image rows grow downwards
    else:
        ax.set_ylim(y0, y1)

    for k, (i, img) in enumerate(thumbs):
        tax = fig.add_subplot(gs[1, k])
        tax.imshow(img)
        tax.set_xticks([])
        tax.set_yticks([])
        for side in tax.spines.values():
            side.set_edgecolor(_thumb_edge(i, special))
            side.set_linewidth(2.5)
        tax.set_title(f"node {i}", fontsize=9, color=_thumb_edge(i, special), fontweight="bold", pad=3)

    kinds = {a.kind for a in topomap.arcs()}
    handles = [Line2D([], [], color=ARC_STYLE[k]["color"], lw=ARC_STYLE[k]["lw"], ls=ARC_STYLE[k]["ls"],
                      label=ARC_STYLE[k]["label"]) for k in ARC_STYLE if k in kinds]
    if rejected_loops:
        handles.append(Line2D([], [], color=REJECTED_COLOR, lw=1.4, ls=":",
                              label="look-alike rejected by verification"))
    handles.append(Line2D([], [], marker="o", ls="", mfc=NODE_COLOR, mec="white", label="node (id)"))
    if layout != "ring":
        handles.append(Line2D([], [], color=HEADING_COLOR, lw=2, label="heading of the node's image"))
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=10, frameon=False)
    n_loops = sum(1 for a in topomap.arcs() if a.kind == "loop_closure")
    n_merged = sum(1 for a in topomap.arcs() if a.kind == "merged")
    heading = f"{title} - " if title else ""
    ax.set_title(f"{heading}{len(topomap)} nodes, {topomap.n_arcs} arcs, {n_loops} loop closures, "
                 f"{n_merged} merged arcs", fontsize=12)
    fig.subplots_adjust(left=0.02 if layout != "metres" else 0.06, right=0.98, top=0.96,
                        bottom=0.5 / (map_h_in + strip_h_in + 1.0) + 0.01)
    return _save(fig, out_path, dpi)


def _thumb_edge(node: int, special: set) -> str:
    return ARC_STYLE["loop_closure"]["color"] if node in special else NODE_COLOR


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
        tip = pos[node.node_id] + 0.022 * span * np.array([c, s])
        ax.plot([pos[node.node_id][0], tip[0]], [pos[node.node_id][1], tip[1]], color=HEADING_COLOR,
                lw=2.0, zorder=3.5, solid_capstyle="round")


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
    rejected = [e for e in log.rejected_loop_events() if e.loop_candidate in node_seq]
    if rejected:
        rx = np.array([e.seq for e in rejected])
        ry = np.array([node_seq[e.loop_candidate] for e in rejected])
        ax_m.scatter(np.r_[rx, ry], np.r_[ry, rx], s=80, marker="X", c=REJECTED_COLOR, edgecolors="white",
                     linewidths=0.8, zorder=4, label="look-alike rejected by sequence verification")
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
    if t.loop_verify_frames > 0:
        ax_s.axhline(t.T_loop_verify, color=REJECTED_COLOR, ls=":", lw=1.2,
                     label=f"T_loop_verify {t.T_loop_verify:.3f} (mean over {t.loop_verify_frames + 1} frames)")
    below = [(e.seq, e.loop_score) for e in log.events
             if e.loop_score is not None and e.kind != "loop_closure" and not e.loop_rejected]
    if below:
        bx, by = np.array(below).T
        ax_s.scatter(bx, by, s=16, facecolors="none", edgecolors="#d62728",
                     label="best earlier node (below T_loop_closure)", zorder=3)
    for events, colour, label in ((log.loop_closure_events(), "#d62728", "loop closure accepted"),
                                  (log.rejected_loop_events(), REJECTED_COLOR, "candidate rejected by verification")):
        if not events:
            continue
        ex = np.array([e.seq for e in events])
        ax_s.scatter(ex, [e.loop_score for e in events], s=46, marker="o" if colour != REJECTED_COLOR else "X",
                     c=colour, label=f"{label} (score)", zorder=4)
        sup = [(e.seq, e.verify_support) for e in events if e.verify_support is not None]
        if sup:
            sx, sy = np.array(sup).T
            ax_s.scatter(sx, sy, s=40, marker="v", c=colour, edgecolors="black", linewidths=0.5, zorder=4,
                         label=f"{label} (verification support)")
    finite = log.sim_to_node[np.isfinite(log.sim_to_node)]
    supports = [e.verify_support for e in log.events if e.verify_support is not None]
    lo = min([float(finite.min()) if finite.size else 0.0, t.T_add_new_node, t.T_loop_closure] + supports) - 0.05
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
