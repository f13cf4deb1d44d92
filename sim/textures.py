"""Deterministic textures for the simulated worlds, generated from integer seeds.

A :class:`TextureSpec` says what a surface looks like (``kind``, ``seed``, optional base colour
and sign text); :func:`make_texture` turns it into an RGB ``uint8`` array and
:func:`texture_png` writes that array to a PNG file in a cache folder (keyed by a hash of the
spec) for ``pybullet.loadTexture``. Only numpy's seeded generator and OpenCV's deterministic
drawing are used, so the same spec always gives a byte-identical image; two specs that are equal
(for instance every ``door`` with the same seed) give the same picture, which keeps the
look-alike problem of real buildings in the simulated ones.

Kinds:

* ``plain``   one flat colour (painted plaster, glass-less partitions);
* ``noise``   plaster or concrete: soft blotches plus fine grain around the base colour;
* ``poster``  a framed sheet with a title bar, coloured shapes, stripes and text-like lines;
* ``sign``    a coloured plate with a big glyph (room numbers, letters: ``text``);
* ``door``    frame, panel with two recessed fields, a handle and a kick plate;
* ``tiles``   square floor tiles with grout lines and slight per-tile shading;
* ``carpet``  fine fibre noise with a faint regular pattern;
* ``wood``    grain stripes (desk tops, cabinets);
* ``window``  a frame with panes showing sky and a seeded skyline (outside walls).

Images are small (at most 256 px a side) because TinyRenderer's cost grows with texture fetches
and memory, not with detail the 320x240 camera cannot resolve.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Optional

import cv2
import numpy as np

from core.atomic import write_bytes

TextureKind = Literal["plain", "noise", "poster", "sign", "door", "tiles", "carpet", "wood", "window"]
KINDS: tuple[str, ...] = ("plain", "noise", "poster", "sign", "door", "tiles", "carpet", "wood", "window")

#: the generators' own source is part of every cache key, so an edited generator never
#: reuses a PNG of the old look
_SOURCE_HASH = hashlib.sha1(Path(__file__).read_bytes()).hexdigest()[:12]
MAX_SIZE_PX = 256

# (width, height) in pixels when a spec leaves size_px out; decals are taller than wide
_DEFAULT_SIZE = {
    "plain": (16, 16), "noise": (128, 128), "poster": (128, 192), "sign": (128, 96),
    "door": (96, 192), "tiles": (128, 128), "carpet": (128, 128), "wood": (128, 128),
    "window": (192, 128),
}
# base colours (RGB 0..1) when a spec leaves color out
_DEFAULT_COLOR = {
    "plain": (0.85, 0.85, 0.82), "noise": (0.80, 0.79, 0.75), "poster": (0.95, 0.95, 0.92),
    "sign": (0.15, 0.35, 0.65), "door": (0.62, 0.47, 0.32), "tiles": (0.78, 0.78, 0.76),
    "carpet": (0.35, 0.38, 0.45), "wood": (0.60, 0.45, 0.30), "window": (0.88, 0.88, 0.86),
}


@dataclass(frozen=True)
class TextureSpec:
    """What a surface looks like.

    ``kind``: one of :data:`KINDS`. ``seed``: integer seed of everything random in the image.
    ``color``: base colour, RGB in 0..1 (``None``: the kind's default; posters pick their own
    palette from the seed). ``text``: the glyph of a ``sign`` (up to 3 characters, e.g. ``"12"``).
    ``size_px``: [width, height] of the image (``None``: the kind's default), each 8..256.
    ``tile_m``: [width, height] in metres that one copy of the image covers when it is repeated
    over a wall or a floor (ignored on decals and props, which stretch one copy over a face).
    """

    kind: TextureKind = "plain"
    seed: int = 0
    color: Optional[tuple[float, float, float]] = None
    text: str = ""
    size_px: Optional[tuple[int, int]] = None
    tile_m: tuple[float, float] = (2.0, 2.5)

    def __post_init__(self) -> None:
        if self.color is not None and not all(0.0 <= c <= 1.0 for c in self.color):
            raise ValueError(f"color: each channel must be within 0..1, got {list(self.color)}")
        if self.size_px is not None and not all(8 <= s <= MAX_SIZE_PX for s in self.size_px):
            raise ValueError(f"size_px: each side must be 8..{MAX_SIZE_PX} px, got {list(self.size_px)}")
        if not all(t > 0 for t in self.tile_m):
            raise ValueError(f"tile_m: both sides must be > 0 m, got {list(self.tile_m)}")
        if self.seed < 0:
            raise ValueError(f"seed: must be >= 0, got {self.seed}")
        if len(self.text) > 4:
            raise ValueError(f"text: at most 4 characters fit a sign, got {self.text!r}")

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return tuple(self.size_px) if self.size_px is not None else _DEFAULT_SIZE[self.kind]

    @property
    def base_rgb(self) -> np.ndarray:
        """Base colour as float RGB 0..255."""
        return np.asarray(self.color if self.color is not None else _DEFAULT_COLOR[self.kind]) * 255.0

    def key(self) -> str:
        """A short hash naming this image (the tile size does not change the pixels)."""
        text = repr((_SOURCE_HASH, self.kind, self.seed, self.color, self.text, self.size))
        return hashlib.sha1(text.encode("utf-8")).hexdigest()[:16]


def make_texture(spec: TextureSpec) -> np.ndarray:
    """The image of ``spec``: (height, width, 3) uint8 RGB, row 0 at the top. Deterministic."""
    rng = np.random.default_rng([spec.seed, KINDS.index(spec.kind)])
    w, h = spec.size
    img = _GENERATORS[spec.kind](spec, rng, w, h)
    return np.ascontiguousarray(np.clip(img, 0, 255).astype(np.uint8))


def default_cache_dir() -> Path:
    """Where PNGs are written: ``$LIMO_TEXTURE_CACHE`` or a folder in the system temp dir."""
    env = os.environ.get("LIMO_TEXTURE_CACHE")
    return Path(env) if env else Path(tempfile.gettempdir()) / "limo_toponav_textures"


def texture_png(spec: TextureSpec, cache_dir: Optional[Path] = None) -> Path:
    """Path of a PNG holding :func:`make_texture` of ``spec``, written once and then reused."""
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path = folder / f"{spec.kind}_{spec.key()}.png"
    if path.is_file():
        return path
    ok, data = cv2.imencode(".png", cv2.cvtColor(make_texture(spec), cv2.COLOR_RGB2BGR))
    if not ok:
        raise OSError(f"could not encode texture {spec}")
    # atomic: parallel runs may build the same texture at the same time
    return write_bytes(path, data.tobytes())


# ---------------------------------------------------------------- generators


def _value_noise(rng: np.random.Generator, w: int, h: int, cells: int) -> np.ndarray:
    """Smooth noise in -1..1: a coarse random grid upsampled bicubically (tileable edges)."""
    grid = rng.uniform(-1.0, 1.0, size=(cells, cells)).astype(np.float32)
    # wrap one cell so the image tiles seamlessly when repeated over a wall
    grid = np.pad(grid, ((0, 1), (0, 1)), mode="wrap")
    big = cv2.resize(grid, (w + w // cells, h + h // cells), interpolation=cv2.INTER_CUBIC)
    return np.clip(big[:h, :w], -1.0, 1.0)


def _flat(spec: TextureSpec, w: int, h: int) -> np.ndarray:
    return np.broadcast_to(spec.base_rgb, (h, w, 3)).astype(np.float32).copy()


def _plain(spec, rng, w, h):
    return _flat(spec, w, h)


def _noise(spec, rng, w, h):
    img = _flat(spec, w, h)
    blotch = _value_noise(rng, w, h, 4) * 10.0 + _value_noise(rng, w, h, 16) * 5.0
    grain = rng.normal(0.0, 4.0, size=(h, w)).astype(np.float32)
    return img + (blotch + grain)[..., None]


def _tiles(spec, rng, w, h):
    n = 4  # tiles per texture side
    img = _flat(spec, w, h)
    step_x, step_y = w / n, h / n
    for i in range(n):
        for j in range(n):
            shade = rng.uniform(-8.0, 8.0)
            x0, y0 = int(round(i * step_x)), int(round(j * step_y))
            img[y0:int(round((j + 1) * step_y)), x0:int(round((i + 1) * step_x))] += shade
    img += rng.normal(0.0, 2.5, size=(h, w, 1)).astype(np.float32)
    grout = spec.base_rgb * 0.72
    for i in range(n):
        img[:, int(round(i * step_x)):int(round(i * step_x)) + 2] = grout
        img[int(round(i * step_y)):int(round(i * step_y)) + 2, :] = grout
    return img


def _carpet(spec, rng, w, h):
    img = _flat(spec, w, h)
    fibre = rng.normal(0.0, 9.0, size=(h, w)).astype(np.float32)
    fibre = cv2.GaussianBlur(fibre, (3, 3), 0.7)
    yy, xx = np.mgrid[0:h, 0:w]
    period = int(rng.integers(12, 24))
    pattern = ((xx // period + yy // period) % 2).astype(np.float32) * 6.0 - 3.0
    return img + (fibre + pattern + _value_noise(rng, w, h, 4) * 5.0)[..., None]


def _wood(spec, rng, w, h):
    img = _flat(spec, w, h)
    yy = np.arange(h, dtype=np.float32)[:, None]
    warp = _value_noise(rng, w, h, 4) * 6.0
    freq = rng.uniform(0.25, 0.45)
    grain = np.sin((yy + warp) * freq) * 10.0 + rng.normal(0.0, 3.0, size=(h, w)).astype(np.float32)
    return img + grain[..., None]


def _palette(rng: np.random.Generator, n: int) -> list[tuple[int, int, int]]:
    """``n`` saturated colours with well-spread hues (posters must differ from each other)."""
    hues = (rng.uniform(0, 180) + np.arange(n) * 180.0 / n + rng.uniform(-10, 10, n)) % 180
    hsv = np.stack([hues, rng.uniform(140, 255, n), rng.uniform(120, 240, n)], axis=1)
    rgb = cv2.cvtColor(hsv.astype(np.uint8)[None], cv2.COLOR_HSV2RGB)[0]
    return [tuple(int(c) for c in col) for col in rgb]


def _text_lines(img: np.ndarray, rng: np.random.Generator, x0: int, y0: int, x1: int, y1: int,
                color: tuple[int, int, int]) -> None:
    """Rows of small blocks of random width: reads as printed text from a distance."""
    line_h = int(rng.integers(3, 6))
    y = y0
    while y + line_h <= y1:
        x = x0
        while x < x1:
            word = int(rng.integers(4, 18))
            cv2.rectangle(img, (x, y), (min(x + word, x1), y + line_h - 1), color, -1)
            x += word + int(rng.integers(2, 5))
        y += line_h + int(rng.integers(2, 5))


def _poster(spec, rng, w, h):
    """One of three layouts, so posters differ in structure, not only in colour."""
    cols = _palette(rng, 4)
    layout = int(rng.integers(0, 3))
    paper = tuple(int(c) for c in spec.base_rgb) if layout != 2 else cols[3]
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = paper
    bar_h = int(h * rng.uniform(0.12, 0.2))
    if layout == 0:  # title bar, picture of stripes and shapes, text below
        top, bottom = 8 + bar_h, int(h * rng.uniform(0.55, 0.7))
        cv2.rectangle(img, (4, 4), (w - 5, 4 + bar_h), cols[0], -1)
        _text_lines(img, rng, 10, 8, w - 10, bar_h, (250, 250, 250))
        n = int(rng.integers(3, 7))
        for k in range(n):
            x = int(4 + k * (w - 8) / n)
            cv2.rectangle(img, (x, top), (int(x + (w - 8) / (2 * n)), bottom), cols[1 + k % 3], -1)
        _shapes(img, rng, cols, top, bottom)
        _text_lines(img, rng, 10, bottom + 6, w - 10, h - 10, (60, 60, 60))
    elif layout == 1:  # big picture on top, title and text at the bottom
        bottom = int(h * rng.uniform(0.5, 0.65))
        yy = np.linspace(0.0, 1.0, bottom - 4)[:, None, None]
        grad = (1 - yy) * np.array(cols[1], float) + yy * np.array(cols[2], float)
        img[4:bottom, 4:w - 4] = grad.astype(np.uint8)
        _shapes(img, rng, cols, 4, bottom)
        cv2.rectangle(img, (4, bottom + 4), (w - 5, bottom + 4 + bar_h // 2), cols[0], -1)
        _text_lines(img, rng, 10, bottom + 10 + bar_h // 2, w - 10, h - 10, (50, 50, 50))
    else:  # coloured sheet with big horizontal bands of text
        y = 8
        while y < h - 16:
            band = int(rng.integers(10, 28))
            cv2.rectangle(img, (8, y), (w - 9, min(y + band, h - 9)), cols[int(rng.integers(0, 3))], -1)
            _text_lines(img, rng, 12, y + 3, w - 12, min(y + band, h - 9) - 2, (250, 250, 250))
            y += band + int(rng.integers(4, 14))
    # thin dark frame, drawn last so shapes never cover it
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), (40, 40, 40), max(2, w // 40))
    return img.astype(np.float32)


def _shapes(img: np.ndarray, rng: np.random.Generator, cols, top: int, bottom: int) -> None:
    """A few circles and triangles, clipped to the rows ``top..bottom``."""
    h, w = img.shape[:2]
    layer = img[top:bottom].copy()
    for _ in range(int(rng.integers(2, 5))):
        c = cols[int(rng.integers(1, 4))]
        cx, cy = int(rng.integers(10, w - 10)), int(rng.integers(0, max(1, bottom - top)))
        r = int(rng.integers(w // 10, w // 4))
        if rng.random() < 0.5:
            cv2.circle(layer, (cx, cy), r, c, -1, lineType=cv2.LINE_AA)
        else:
            pts = np.array([[cx, cy - r], [cx - r, cy + r], [cx + r, cy + r]], np.int32)
            cv2.fillPoly(layer, [pts], c, lineType=cv2.LINE_AA)
    img[top:bottom, 4:w - 4] = layer[:, 4:w - 4]


def _sign(spec, rng, w, h):
    plate = tuple(int(c) for c in spec.base_rgb)
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = plate
    light = sum(plate) > 3 * 140
    ink = (25, 25, 25) if light else (245, 245, 245)
    border = max(2, min(w, h) // 16)
    cv2.rectangle(img, (border, border), (w - 1 - border, h - 1 - border), ink, max(1, border // 2))
    text = spec.text or "ABCDEFGHJKLMNPRSTUVWXYZ"[int(rng.integers(0, 23))]
    if not text.strip():
        return img.astype(np.float32)  # only spaces: a blank framed plate (a whiteboard)
    thickness = max(2, min(w, h) // 14)
    font = cv2.FONT_HERSHEY_SIMPLEX
    # largest scale that fits 70% of the plate
    (tw, th), _ = cv2.getTextSize(text, font, 1.0, thickness)
    scale = min(0.7 * w / tw, 0.6 * h / th)
    (tw, th), _ = cv2.getTextSize(text, font, scale, thickness)
    origin = ((w - tw) // 2, (h + th) // 2)
    cv2.putText(img, text, origin, font, scale, ink, thickness, lineType=cv2.LINE_AA)
    return img.astype(np.float32)


def _door(spec, rng, w, h):
    panel = spec.base_rgb
    frame = np.clip(panel * 0.55, 0, 255)
    img = _flat(spec, w, h)
    img += rng.normal(0.0, 2.0, size=(h, w, 1)).astype(np.float32)
    f = max(3, w // 12)
    img[:f, :] = frame
    img[:, :f] = frame
    img[:, w - f:] = frame
    out = np.clip(img, 0, 255).astype(np.uint8)
    dark = tuple(int(c) for c in np.clip(panel * 0.8, 0, 255))
    # two recessed fields
    m = f + max(3, w // 10)
    cv2.rectangle(out, (m, f + m), (w - 1 - m, int(h * 0.45)), dark, 2)
    cv2.rectangle(out, (m, int(h * 0.52)), (w - 1 - m, h - 1 - int(h * 0.12)), dark, 2)
    # kick plate and handle
    cv2.rectangle(out, (f, h - int(h * 0.08)), (w - 1 - f, h - 1), (150, 150, 155), -1)
    hx, hy = w - f - max(4, w // 8), int(h * 0.5)
    cv2.rectangle(out, (hx - max(6, w // 8), hy - 2), (hx, hy + 2), (200, 200, 205), -1)
    return out.astype(np.float32)


def _window(spec, rng, w, h):
    """Frame colour from ``color``; sky gradient and a skyline of random blocks behind panes."""
    frame = spec.base_rgb
    yy = np.linspace(0.0, 1.0, h)[:, None, None]
    top, horizon = np.array([120.0, 165.0, 215.0]), np.array([205.0, 222.0, 235.0])
    img = ((1 - yy) * top + yy * horizon) * np.ones((1, w, 1))
    x = 0
    while x < w:
        bw = int(rng.integers(w // 10, w // 4))
        bh = int(rng.uniform(0.2, 0.6) * h)
        shade = rng.uniform(120.0, 175.0)
        img[h - bh:, x:x + bw] = (shade, shade * 0.97, shade * 0.95)
        x += bw + int(rng.integers(0, w // 12 + 1))
    f = max(3, min(w, h) // 16)
    img[:f], img[-f:], img[:, :f], img[:, -f:] = frame, frame, frame, frame
    img[:, w // 2 - f // 2:w // 2 + f // 2 + 1] = frame
    img[h // 2 - f // 2:h // 2 + f // 2 + 1, :] = frame
    return img.astype(np.float32)


_GENERATORS = {
    "plain": _plain, "noise": _noise, "poster": _poster, "sign": _sign, "door": _door,
    "tiles": _tiles, "carpet": _carpet, "wood": _wood, "window": _window,
}
