"""Where the viewer draws the map, and the layout it opens with.

Nodes are drawn at their true poses when the map has them (maps of the simulator), else where a
seeded spring layout of the graph puts them (maps from a video or a real drive keep no
positions): the picture is then the graph's shape, not the building's. The viewer's 2-D views
put +y down, so points are logged as ``(x, -y)``: north is up, as in the project's pictures.
"""

from __future__ import annotations

from typing import Any

import networkx as nx
import numpy as np

from maps.graph import TopoMap

#: entity paths, one place for the loggers, the blueprint and the tests
CAMERA = "camera"
GOAL = "goal"
MAP = "map"
SCORES = "scores"
COMMAND = "command"
TIMING = "timing"
BELIEF = "belief"
NAVIGATOR = "navigator"
MAPPING = "mapping"

#: the timelines: the control tick (or the mapping frame) and the base's clock
TICK = "tick"
FRAME = "frame"
SIM_TIME = "sim_time"


def node_positions(topomap: TopoMap) -> tuple[np.ndarray, bool]:
    """(N, 2) view coordinates of the nodes in ``topomap.node_ids`` order, and whether they are
    true positions (metres) rather than a layout."""
    ids = [int(n) for n in topomap.node_ids]
    poses = [topomap.node(n).true_pose for n in ids]
    if ids and all(p is not None for p in poses):
        return np.array([[p.x_m, -p.y_m] for p in poses], dtype=np.float32), True
    if not ids:
        return np.zeros((0, 2), dtype=np.float32), False
    layout = nx.spring_layout(topomap.graph.to_undirected(as_view=True), seed=0, scale=0.5 * len(ids) ** 0.5)
    return np.array([layout[n] for n in ids], dtype=np.float32), False


def view_xy(x_m: float, y_m: float) -> list[float]:
    """A world point in view coordinates (north up)."""
    return [float(x_m), -float(y_m)]


def arc_strips(topomap: TopoMap, positions: np.ndarray) -> list[np.ndarray]:
    """One 2-point strip per arc of the map (both directions drawn once)."""
    row = {int(n): k for k, n in enumerate(topomap.node_ids)}
    seen, strips = set(), []
    for src, dst in topomap.graph.edges():
        key = (min(src, dst), max(src, dst))
        if key in seen:
            continue
        seen.add(key)
        strips.append(positions[[row[int(src)], row[int(dst)]]])
    return strips


def navigation_blueprint(rr: Any) -> Any:
    """The layout a navigation recording opens with: camera and goal image, the map, the
    scores over time, the navigator's decisions."""
    rrb = rr.blueprint
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(rrb.Spatial2DView(origin=CAMERA, name="camera"),
                         rrb.Spatial2DView(origin=GOAL, name="goal image"),
                         rrb.TextDocumentView(origin=f"{NAVIGATOR}/decision", name="decision")),
            rrb.Spatial2DView(origin=MAP, name="map"),
            rrb.Vertical(rrb.TimeSeriesView(origin=SCORES, name="scores"),
                         rrb.TimeSeriesView(origin=COMMAND, name="command"),
                         rrb.TextLogView(origin=f"{NAVIGATOR}/events", name="events")),
            column_shares=[1.0, 1.4, 1.0]),
        collapse_panels=True)


def mapping_blueprint(rr: Any) -> Any:
    """The layout a mapping recording opens with: the keyframe, the growing map, the scores."""
    rrb = rr.blueprint
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(rrb.Spatial2DView(origin=CAMERA, name="keyframe"),
                         rrb.TextLogView(origin=f"{MAPPING}/events", name="events")),
            rrb.Spatial2DView(origin=MAP, name="map"),
            rrb.TimeSeriesView(origin=SCORES, name="similarity"),
            column_shares=[1.0, 1.4, 1.0]),
        collapse_panels=True)
