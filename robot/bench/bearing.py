"""``python -m robot.bench bearing MAP``: what the target view's bearing says beside and turned off
mapped places, measured on rendered views.

    python -m robot.bench bearing runs/paper/maps/office-s0.5 --nodes 15,21 --appearances 1,2

For each chosen node it places the simulated robot ``--before`` metres before the node along the
node's heading (where the robot is while the node is its target), renders the view there
``--lateral`` metres left and right of the mapped line facing along it, and on the line turned
``--turn`` degrees either way, under each ``--appearances`` seed (the map: seed 0), and prints the
shift between each view's column profile and the node's (:func:`descriptors.columns.column_shift`)
in columns of the profile: positive asks to turn left. The steering by bearing
(``navigation.bearing``) nulls this shift, so the table says how large a heading or lateral error
it sees and with which sign; the summary gives the mean shift per 10 deg and per metre beside
the line, over the rows.

The map must keep column profiles (made since 2026-12-07) and name its world (a map of a
simulator drive; ``--world`` names it for another). Exit status: 0 done, 2 bad input (the
file, option or value named).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from core.cli import non_negative_float, positive_float


class BearingBenchError(ValueError):
    """Bad input to the bearing table (names the map, option or value)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("map", type=Path, help="a map folder with column profiles (e.g. RUN/maps/office-s0.5)")
    parser.add_argument("--nodes", default=None,
                        help="comma-separated node ids (default: four spread along the map)")
    parser.add_argument("--appearances", default="1,2",
                        help="comma-separated appearance seeds to render under (default 1,2; the map: 0)")
    parser.add_argument("--before", type=non_negative_float, default=0.6,
                        help="metres before the node along its heading (default 0.6)")
    parser.add_argument("--lateral", type=positive_float, default=0.5,
                        help="metres left and right of the mapped line (default 0.5)")
    parser.add_argument("--turn", type=positive_float, default=10.0,
                        help="degrees turned either way on the line (default 10)")
    parser.add_argument("--world", default=None, help="the world to render (default: the one the map names)")
    parser.add_argument("--config", type=Path, default=None,
                        help="stack configuration (YAML): its descriptor and sim sections "
                             "(default configs/default.yaml)")
    parser.add_argument("--json", type=Path, default=None, help="also write the table as JSON here")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


@dataclass(frozen=True)
class Row:
    """The shifts (in columns) at one node under one appearance."""

    node: int
    appearance: int
    lateral: tuple[float, float, float]     # right of the line, on it, left of it; facing along it
    turned: tuple[float, float, float]      # turned right, straight, turned left; on the line
    score: float                            # mean profile agreement at the best shift, over the five views

    def heading_per_10deg(self, turn_deg: float) -> float:
        """Shift per 10 deg turned right (the sign that asks to turn back left)."""
        return (self.turned[0] - self.turned[2]) / 2.0 / turn_deg * 10.0

    def lateral_per_m(self, lateral_m: float) -> float:
        """Shift per metre right of the line (positive: it asks to turn back left)."""
        return (self.lateral[0] - self.lateral[2]) / 2.0 / lateral_m


def parse_ids(option: str, text: str) -> list[int]:
    """Comma-separated non-negative integers; raises :class:`BearingBenchError` naming ``option``."""
    try:
        values = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise BearingBenchError(f"{option} {text!r}: expected comma-separated integers") from None
    if not values or any(v < 0 for v in values):
        raise BearingBenchError(f"{option} {text!r}: expected comma-separated integers >= 0")
    return values


def default_nodes(node_ids: Sequence[int], count: int = 4) -> list[int]:
    """``count`` nodes spread evenly along the map, the first and last left out (a drive's ends)."""
    ids = [int(n) for n in node_ids]
    if len(ids) <= count:
        return ids
    picks = np.linspace(0, len(ids) - 1, count + 2)[1:-1]
    return sorted({ids[int(round(p))] for p in picks})


def probe_poses(x: float, y: float, yaw: float, before_m: float, lateral_m: float, turn_deg: float):
    """The five poses probed for a node at ``(x, y, yaw)``: ``(beside, turned)``, each right,
    centre, left, as ``(x, y, yaw)`` tuples (the centre is the same pose in both)."""
    bx, by = x - before_m * math.cos(yaw), y - before_m * math.sin(yaw)
    left = (-math.sin(yaw), math.cos(yaw))
    beside = tuple((bx + s * lateral_m * left[0], by + s * lateral_m * left[1], yaw) for s in (-1, 0, 1))
    turn = math.radians(turn_deg)
    turned = tuple((bx, by, yaw + s * turn) for s in (-1, 0, 1))
    return beside, turned


def measure(loaded, descriptor, render, nodes: Sequence[int], appearances: Sequence[int], before_m: float,
            lateral_m: float, turn_deg: float, progress: bool = True) -> list[Row]:
    """One :class:`Row` per node and appearance. ``render(appearance, (x, y, yaw)) -> rgb``."""
    from tqdm import tqdm

    from descriptors.columns import column_shift

    row_of = {int(n): k for k, n in enumerate(loaded.topomap.node_ids.tolist())}
    columns = np.asarray(loaded.columns, dtype=np.float32)
    width = columns.shape[1]
    rows = []
    bar = tqdm(total=len(nodes) * len(appearances) * 5, desc="rendering views", unit="view",
               disable=not progress, leave=False)
    try:
        for appearance in appearances:
            for node in nodes:
                pose = loaded.topomap.node(node).true_pose
                beside, turned = probe_poses(pose.x_m, pose.y_m, pose.yaw_rad, before_m, lateral_m, turn_deg)
                shifts, scores = {}, []
                for p in (*beside, turned[0], turned[2]):
                    _, view = descriptor.describe_with_columns([render(appearance, p)])
                    bearing, score = column_shift(view[0], columns[row_of[node]])
                    shifts[p] = bearing * width
                    scores.append(score)
                    bar.update(1)
                rows.append(Row(node=node, appearance=appearance,
                                lateral=tuple(shifts[p] for p in beside),
                                turned=(shifts[turned[0]], shifts[beside[1]], shifts[turned[2]]),
                                score=float(np.mean(scores))))
    finally:
        bar.close()
    return rows


def format_table(rows: Sequence[Row], world: str, before_m: float, lateral_m: float, turn_deg: float,
                 width: int) -> str:
    """The table in Markdown and its summary line."""
    lines = [f"| place ({before_m:g} m before it) | beside the line -{lateral_m:g} / 0 / +{lateral_m:g} m, "
             f"facing along it | on the line, turned -{turn_deg:g} / 0 / +{turn_deg:g} deg | agreement |",
             "|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {world} node {r.node}, appearance {r.appearance} | "
                     + " / ".join(f"{v:+.2f}" for v in r.lateral) + " | "
                     + " / ".join(f"{v:+.2f}" for v in r.turned) + f" | {r.score:.2f} |")
    heading = float(np.mean([r.heading_per_10deg(turn_deg) for r in rows]))
    lateral = float(np.mean([r.lateral_per_m(lateral_m) for r in rows]))
    lines += ["", f"Shifts in columns of {width} (right of the line and turned right are negative: a positive "
              f"shift asks to turn left). Mean over the rows: {heading:.2f} columns per 10 deg turned, "
              f"{lateral:.2f} per metre beside the line (both counted towards the line)."]
    return "\n".join(lines)


def _sim_renderer(config, spec):
    """``(render(appearance, (x, y, yaw)) -> rgb, close())``: one simulator per appearance, the
    robot teleported to each pose."""
    from core.hal import Pose2D
    from sim.hal import SimLimo

    bases: dict = {}

    def render(appearance: int, pose) -> np.ndarray:
        base = bases.get(appearance)
        if base is None:
            base = bases[appearance] = SimLimo(config.sim, start=Pose2D(*pose), world=spec, appearance_seed=appearance)
            base.connect()
        base.ground_truth.teleport(Pose2D(*pose))
        return base.read().rgb

    def close() -> None:
        for base in bases.values():
            base.close()
    return render, close


def main(args: argparse.Namespace) -> int:
    from core.atomic import write_json
    from core.cli import UsageError, check_output_file, existing_folder
    from core.configfile import ConfigError
    from maps.graph import MapError
    from maps.store import load_map
    from robot.episode.setup import attach_descriptor
    from descriptors.factory import make_descriptor
    from robot.settings import load_stack_config
    from sim.world_spec import WorldError
    from sim.worlds import load_world

    try:
        check_output_file("--json", args.json)
        existing_folder("map", args.map, "map folder")
        if args.config is not None and not args.config.is_file():
            raise BearingBenchError(f"--config {args.config}: no such file")
        appearances = parse_ids("--appearances", args.appearances)
        config = load_stack_config(args.config)
        loaded = load_map(args.map)
        if loaded.columns is None:
            raise BearingBenchError(f"{args.map}: the map keeps no column profiles (made before 2026-12-07, or "
                                    f"with a descriptor that gives none); rebuild it from its recording")
        ids = set(int(n) for n in loaded.topomap.node_ids.tolist())
        nodes = parse_ids("--nodes", args.nodes) if args.nodes is not None else default_nodes(sorted(ids))
        unknown = [n for n in nodes if n not in ids]
        if unknown:
            raise BearingBenchError(f"--nodes: {args.map} has no node {', '.join(map(str, unknown))} "
                                    f"(it has {min(ids)}..{max(ids)})")
        world = args.world or loaded.extra.get("world")
        if not world:
            raise BearingBenchError(f"{args.map}: the map names no world (made from a video?); pass --world")
        spec = load_world(world)
        descriptor = attach_descriptor(loaded, make_descriptor(config.descriptor.backend, **config.descriptor.settings))
    except (BearingBenchError, UsageError, ConfigError, MapError, WorldError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    render, close = _sim_renderer(config, spec)
    try:
        rows = measure(loaded, descriptor, render, nodes, appearances, args.before, args.lateral, args.turn,
                       progress=not args.quiet)
    finally:
        close()
    width = int(loaded.columns.shape[1])
    print(format_table(rows, spec.name, args.before, args.lateral, args.turn, width))
    if args.json is not None:
        write_json(args.json, {"map": str(args.map), "world": spec.name, "before_m": args.before,
                               "lateral_m": args.lateral, "turn_deg": args.turn, "columns": width,
                               "rows": [vars(r) | {"lateral": list(r.lateral), "turned": list(r.turned)}
                                        for r in rows]})
        print(f"\nwrote {args.json}")
    return 0
