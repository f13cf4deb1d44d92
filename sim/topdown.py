"""A top-down picture of a world, drawn from its spec with OpenCV (no PyBullet render).

``render_topdown(spec)`` draws the floor, the walls with their decals (a coloured stripe on the
face: brown doors, blue windows, colourful posters, signs), the props (movable ones outlined in
orange), the walkthrough (with direction arrows and its start), every evaluation route in its
own colour with start and goal markers and its name, a legend and a 1 m scale bar. The returned
:class:`TopDown` keeps the world-to-pixel transform, so later code can draw trajectories, map
nodes and goals on the same picture (``draw_polyline``, ``draw_marker``) and ``save_png`` it.

Colours passed to the drawing helpers are RGB tuples of 0..255 (the image is RGB).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np

from core.atomic import write_bytes
from core.cli import Parser
from sim.appearance import apply_appearance
from sim.geometry import polyline_length_m, prop_footprints, sample_polyline, wall_footprint
from sim.textures import make_texture
from sim.world_spec import DecalSpec, PropSpec, WallSpec, WorldError, WorldSpec
from sim.worlds import load_world

RGB = tuple[int, int, int]

#: route colours, in the order of ``spec.routes.evaluation``
ROUTE_COLORS: tuple[RGB, ...] = ((46, 160, 67), (230, 140, 20), (214, 39, 40), (148, 103, 189),
                                 (23, 190, 207), (188, 189, 34))
WALKTHROUGH_COLOR: RGB = (40, 90, 200)
WALL_COLOR: RGB = (70, 70, 75)
MOVABLE_OUTLINE: RGB = (255, 150, 0)
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_MARGIN_M = 0.8
_LEGEND_W_PX = 270


@dataclass(frozen=True)
class TopDown:
    """An RGB picture of a world and its world-to-pixel transform.

    ``image``: (H, W, 3) uint8, drawn on in place by the helpers. ``px_per_m``: scale.
    ``x_min_m``/``y_max_m``: world coordinates of the top-left corner of the map area
    (pixel column 0, row 0); x grows to the right, y upwards (rows grow downwards).
    """

    image: np.ndarray
    px_per_m: float
    x_min_m: float
    y_max_m: float
    # boxes (x0, y0, x1, y1) of labels already drawn, so later labels move out of their way
    _label_boxes: list = field(default_factory=list, repr=False, compare=False)

    def to_pixel(self, x_m: float, y_m: float) -> tuple[int, int]:
        """(column, row) of the world point (x_m, y_m)."""
        return (int(round((x_m - self.x_min_m) * self.px_per_m)),
                int(round((self.y_max_m - y_m) * self.px_per_m)))

    def to_pixels(self, points: Sequence[Sequence[float]]) -> np.ndarray:
        """(N, 2) int32 array of (column, row) for world points (N, 2)."""
        xy = np.asarray(points, dtype=float).reshape(-1, 2)
        cols = (xy[:, 0] - self.x_min_m) * self.px_per_m
        rows = (self.y_max_m - xy[:, 1]) * self.px_per_m
        return np.round(np.stack([cols, rows], axis=1)).astype(np.int32)

    def draw_polyline(self, points: Sequence[Sequence[float]], color: RGB, thickness: int = 2,
                      arrow_every_m: Optional[float] = None) -> None:
        """Draw a world polyline; with ``arrow_every_m``, arrowheads show its direction."""
        pts = self.to_pixels(points)
        if len(pts) >= 2:
            cv2.polylines(self.image, [pts], False, color, thickness, cv2.LINE_AA)
        if arrow_every_m and len(points) >= 2:
            _draw_arrows(self, points, color, arrow_every_m, thickness)

    def draw_marker(self, x_m: float, y_m: float, color: RGB, label: str = "", shape: str = "circle",
                    yaw_rad: Optional[float] = None, size_px: int = 7) -> None:
        """A filled ``circle``, ``square`` or ``diamond`` at a world point, an optional heading
        arrow (``yaw_rad``) and a text label beside it."""
        c = self.to_pixel(x_m, y_m)
        if yaw_rad is not None:
            tip = (int(round(c[0] + 2.6 * size_px * math.cos(yaw_rad))),
                   int(round(c[1] - 2.6 * size_px * math.sin(yaw_rad))))
            cv2.arrowedLine(self.image, c, tip, (20, 20, 20), 2, cv2.LINE_AA, tipLength=0.4)
        if shape == "square":
            cv2.rectangle(self.image, (c[0] - size_px, c[1] - size_px), (c[0] + size_px, c[1] + size_px), color, -1)
            cv2.rectangle(self.image, (c[0] - size_px, c[1] - size_px), (c[0] + size_px, c[1] + size_px),
                          (20, 20, 20), 1)
        elif shape == "diamond":
            pts = np.array([[c[0], c[1] - size_px], [c[0] + size_px, c[1]], [c[0], c[1] + size_px],
                            [c[0] - size_px, c[1]]], np.int32)
            cv2.fillPoly(self.image, [pts], color, cv2.LINE_AA)
            cv2.polylines(self.image, [pts], True, (20, 20, 20), 1, cv2.LINE_AA)
        else:
            cv2.circle(self.image, c, size_px, color, -1, cv2.LINE_AA)
            cv2.circle(self.image, c, size_px, (20, 20, 20), 1, cv2.LINE_AA)
        if label:
            (tw, th), _ = cv2.getTextSize(label, _FONT, 0.45, 1)
            x0, y0 = c[0] + size_px + 3, c[1] - size_px
            while any(x0 < b[2] and b[0] < x0 + tw and y0 - th < b[3] and b[1] < y0 + 3
                      for b in self._label_boxes):
                y0 += th + 5
            self._label_boxes.append((x0, y0 - th, x0 + tw, y0 + 3))
            _text(self.image, label, (x0, y0), 0.45, (15, 15, 15), outline=True)

    def copy(self) -> "TopDown":
        """A copy with its own image, to draw overlays without touching this one."""
        return TopDown(self.image.copy(), self.px_per_m, self.x_min_m, self.y_max_m, list(self._label_boxes))

    def save_png(self, path: str | Path) -> Path:
        """Write the picture as PNG atomically (creating folders); returns the path."""
        ok, data = cv2.imencode(".png", cv2.cvtColor(self.image, cv2.COLOR_RGB2BGR))
        if not ok:
            raise OSError(f"could not encode {path} as PNG")
        return write_bytes(path, data.tobytes())


def render_topdown(spec: WorldSpec, appearance_seed: int = 0, px_per_m: float = 40.0,
                   show_routes: bool = True) -> TopDown:
    """Draw ``spec`` (props placed as ``appearance_seed`` places them) seen from above."""
    if px_per_m <= 0:
        raise ValueError(f"px_per_m must be > 0, got {px_per_m}")
    world = apply_appearance(spec, appearance_seed)
    (fx, fy), (sx, sy) = world.floor.origin_m, world.floor.size_m
    x_min, y_min = fx - _MARGIN_M, fy - _MARGIN_M
    x_max, y_max = fx + sx + _MARGIN_M, fy + sy + _MARGIN_M
    w_px = int(math.ceil((x_max - x_min) * px_per_m))
    h_px = max(int(math.ceil((y_max - y_min) * px_per_m)), 460)
    image = np.full((h_px, w_px + _LEGEND_W_PX, 3), 255, np.uint8)
    image[:, :w_px] = (205, 205, 205)
    td = TopDown(image, px_per_m, x_min, y_max)
    _draw_floor(td, world)
    for prop in world.props:
        _draw_prop(td, prop)
    for wall in world.walls:
        _draw_wall(td, wall)
    if show_routes:
        _draw_routes(td, world)
    _draw_scale_bar(td, y_min)
    _draw_legend(td, world, appearance_seed, w_px, show_routes)
    return td


# ---------------------------------------------------------------- pieces


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float, color: RGB, outline: bool = False,
          thickness: int = 1) -> None:
    if outline:
        cv2.putText(img, text, org, _FONT, scale, (255, 255, 255), thickness + 3, cv2.LINE_AA)
    cv2.putText(img, text, org, _FONT, scale, color, thickness, cv2.LINE_AA)


def _mean_rgb(texture) -> RGB:
    return tuple(int(v) for v in make_texture(texture).reshape(-1, 3).mean(axis=0))


def _draw_floor(td: TopDown, world: WorldSpec) -> None:
    (fx, fy), (sx, sy) = world.floor.origin_m, world.floor.size_m
    floor_rgb = np.asarray(_mean_rgb(world.floor.texture), float)
    light = tuple(int(v) for v in 0.5 * floor_rgb + 0.5 * 255)
    cv2.rectangle(td.image, td.to_pixel(fx, fy + sy), td.to_pixel(fx + sx, fy), light, -1)
    # a faint 1 m grid with labels every 2 m on the edges, for reading coordinates off the picture
    grid = tuple(int(v * 0.93) for v in light)
    for x in range(int(math.ceil(fx)), int(math.floor(fx + sx)) + 1):
        cv2.line(td.image, td.to_pixel(x, fy), td.to_pixel(x, fy + sy), grid, 1)
        if x % 2 == 0:
            c, r = td.to_pixel(x, fy)
            _text(td.image, str(x), (c - 4, r + 14), 0.35, (90, 90, 90))
    for y in range(int(math.ceil(fy)), int(math.floor(fy + sy)) + 1):
        cv2.line(td.image, td.to_pixel(fx, y), td.to_pixel(fx + sx, y), grid, 1)
        if y % 2 == 0:
            c, r = td.to_pixel(fx, y)
            _text(td.image, str(y), (c - 22, r + 4), 0.35, (90, 90, 90))


def _draw_wall(td: TopDown, wall: WallSpec) -> None:
    cv2.fillPoly(td.image, [td.to_pixels(wall_footprint(wall).corners())], WALL_COLOR, cv2.LINE_AA)
    for decal in wall.decals:
        _draw_decal(td, wall, decal)


def _draw_decal(td: TopDown, wall: WallSpec, decal: DecalSpec) -> None:
    """A stripe on the wall face the decal hangs on, in the decal's mean colour."""
    (x0, y0), (x1, y1) = wall.start, wall.end
    along = np.array([x1 - x0, y1 - y0]) / wall.length_m
    left = np.array([-along[1], along[0]])
    outward = left if decal.side == "left" else -left
    depth = max(0.08, 3.0 / td.px_per_m)
    centre = np.array([x0, y0]) + along * decal.at_m + outward * (wall.thickness_m / 2 + depth / 2)
    half_w = decal.size_m[0] / 2
    corners = [centre - along * half_w - outward * depth / 2, centre + along * half_w - outward * depth / 2,
               centre + along * half_w + outward * depth / 2, centre - along * half_w + outward * depth / 2]
    cv2.fillPoly(td.image, [td.to_pixels(corners)], _mean_rgb(decal.texture), cv2.LINE_AA)


def _draw_prop(td: TopDown, prop: PropSpec) -> None:
    if prop.model is not None:
        colors = [(160, 130, 100)]
    else:
        colors = [tuple(int(255 * c) for c in part.color) if part.texture is None else _mean_rgb(part.texture)
                  for part in prop.parts]
    prints = prop_footprints(prop)
    # larger parts first, so a monitor on a desk stays visible
    order = sorted(range(len(prints)), key=lambda k: -_area(prints[k]))
    outline = MOVABLE_OUTLINE if prop.movable else (40, 40, 40)
    for k in order:
        fp = prints[k]
        pts = td.to_pixels(fp.corners())
        cv2.fillPoly(td.image, [pts], colors[min(k, len(colors) - 1)], cv2.LINE_AA)
        cv2.polylines(td.image, [pts], True, outline, 2 if prop.movable else 1, cv2.LINE_AA)


def _area(fp) -> float:
    if fp.kind == "circle":
        return math.pi * fp.radius_m ** 2
    return 4.0 * fp.half_extents[0] * fp.half_extents[1]


def _draw_arrows(td: TopDown, points: Sequence[Sequence[float]], color: RGB, every_m: float,
                 thickness: int) -> None:
    samples = sample_polyline(points, 0.05)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(samples, axis=0).T))])
    for s in np.arange(every_m / 2, arc[-1] - 0.3, every_m):
        i = int(np.searchsorted(arc, s))
        j = int(np.searchsorted(arc, s + 0.35))
        j = min(j, len(samples) - 1)
        if j <= i:
            continue
        cv2.arrowedLine(td.image, td.to_pixel(*samples[i]), td.to_pixel(*samples[j]), color,
                        max(1, thickness), cv2.LINE_AA, tipLength=0.6)


def _draw_routes(td: TopDown, world: WorldSpec) -> None:
    walk = world.routes.walkthrough
    routes = list(world.routes.evaluation.items())
    # thickest first, so routes sharing a corridor stay visible as nested stripes
    for i, (_, route) in reversed(list(enumerate(routes))):
        color = ROUTE_COLORS[i % len(ROUTE_COLORS)]
        thick = max(5, int(round(td.px_per_m * 0.18))) + 6 * i
        overlay = td.image.copy()
        cv2.polylines(overlay, [td.to_pixels(route.path)], False, color, thick, cv2.LINE_AA)
        cv2.addWeighted(overlay, 0.7, td.image, 0.3, 0, dst=td.image)
    td.draw_polyline(walk, WALKTHROUGH_COLOR, 2, arrow_every_m=2.0)
    yaw0 = math.atan2(walk[1][1] - walk[0][1], walk[1][0] - walk[0][0])
    td.draw_marker(walk[0][0], walk[0][1], WALKTHROUGH_COLOR, "walkthrough start", "circle", yaw0, 8)
    for i, (name, route) in enumerate(routes):
        color = ROUTE_COLORS[i % len(ROUTE_COLORS)]
        td.draw_marker(route.start[0], route.start[1], color, f"{name} start", "circle",
                       math.radians(route.start[2]), 7)
        td.draw_marker(route.goal[0], route.goal[1], color, f"{name} goal", "square",
                       math.radians(route.goal[2]), 7)


def _draw_scale_bar(td: TopDown, y_min: float) -> None:
    x0 = td.x_min_m + 0.25
    y = y_min + 0.3
    a, b = td.to_pixel(x0, y), td.to_pixel(x0 + 1.0, y)
    cv2.line(td.image, a, b, (0, 0, 0), 3)
    for end in (a, b):
        cv2.line(td.image, (end[0], end[1] - 5), (end[0], end[1] + 5), (0, 0, 0), 2)
    _text(td.image, "1 m", (b[0] + 6, b[1] + 5), 0.45, (0, 0, 0))


def _draw_legend(td: TopDown, world: WorldSpec, appearance_seed: int, left: int, show_routes: bool) -> None:
    img = td.image
    x = left + 12
    y = 24
    _text(img, world.name, (x, y), 0.7, (0, 0, 0), thickness=2)
    y += 20
    (sx, sy) = world.floor.size_m
    _text(img, f"{sx:g} x {sy:g} m, appearance seed {appearance_seed}", (x, y), 0.4, (60, 60, 60))
    y += 26

    def row(draw, label: str) -> None:
        nonlocal y
        draw((x + 12, y - 4))
        _text(img, label, (x + 30, y), 0.42, (20, 20, 20))
        y += 20

    if show_routes:
        walk_len = polyline_length_m(world.routes.walkthrough)
        row(lambda c: cv2.arrowedLine(img, (c[0] - 10, c[1]), (c[0] + 10, c[1]), WALKTHROUGH_COLOR, 2,
                                      cv2.LINE_AA, tipLength=0.5), f"walkthrough {walk_len:.1f} m")
        for i, (name, route) in enumerate(world.routes.evaluation.items()):
            color = ROUTE_COLORS[i % len(ROUTE_COLORS)]
            row(lambda c, col=color: cv2.line(img, (c[0] - 10, c[1]), (c[0] + 10, c[1]), col, 6),
                f"{name}: {route.difficulty}, {route.length_m:g} m")
        row(lambda c: cv2.circle(img, c, 6, (120, 120, 120), -1, cv2.LINE_AA), "start (arrow: heading)")
        row(lambda c: cv2.rectangle(img, (c[0] - 6, c[1] - 6), (c[0] + 6, c[1] + 6), (120, 120, 120), -1),
            "goal")
        y += 6
    row(lambda c: cv2.rectangle(img, (c[0] - 10, c[1] - 3), (c[0] + 10, c[1] + 3), WALL_COLOR, -1), "wall")
    for label, rgb in (("door", (143, 107, 77)), ("window", (150, 185, 215)), ("poster / sign", (200, 60, 120))):
        row(lambda c, col=rgb: cv2.rectangle(img, (c[0] - 10, c[1] - 2), (c[0] + 10, c[1] + 2), col, -1),
            f"{label} on a wall")
    row(lambda c: cv2.rectangle(img, (c[0] - 8, c[1] - 6), (c[0] + 8, c[1] + 6), (40, 40, 40), 1), "prop")
    row(lambda c: cv2.rectangle(img, (c[0] - 8, c[1] - 6), (c[0] + 8, c[1] + 6), MOVABLE_OUTLINE, 2),
        "prop the appearance seed may move")


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m sim.topdown WORLD [--seed N] [--px-per-m S] [--out PNG]``: check a world file
    and draw it, the quickest way to see a new world while writing it."""
    parser = Parser(prog="python -m sim.topdown",
                                     description="Check a world YAML and write its top-down picture.")
    parser.add_argument("world", help="a world name in configs/worlds (hospital, office, warehouse, garage) or a "
                                      "path to a YAML file")
    parser.add_argument("--seed", type=int, default=0, help="appearance seed: moves movable props (default 0)")
    parser.add_argument("--px-per-m", type=float, default=40.0, help="scale in pixels per metre (default 40)")
    parser.add_argument("--out", default=None, help="PNG to write (default: topdown_<world>.png here)")
    args = parser.parse_args(argv)
    try:
        spec = load_world(args.world)
    except WorldError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = render_topdown(spec, args.seed, args.px_per_m).save_png(args.out or f"topdown_{spec.name}.png")
    walk = polyline_length_m(spec.routes.walkthrough)
    routes = ", ".join(f"{n} {r.length_m:g} m" for n, r in spec.routes.evaluation.items()) or "no routes"
    print(f"{spec.name}: {len(spec.walls)} walls, {len(spec.props)} props, walkthrough {walk:.1f} m, {routes}")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
