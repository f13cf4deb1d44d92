"""A simulated world as data: floor, walls, props, light and named routes, read from YAML.

``load_world("hospital")`` reads ``configs/worlds/hospital.yaml`` (any other path works too)
with :func:`robot.configfile.load_config`, then :func:`check_world` checks what types alone
cannot: wall segments are not degenerate, decals fit their walls, props have a model or parts,
the walkthrough comes back to its start, every evaluation route's ``length_m`` agrees with its
polyline and every route lies along the walkthrough, driven the same way. Every error is a
:class:`WorldError` naming the file and the field, e.g.
``configs/worlds/x.yaml: walls[3].height_m: expected a number, got 'high'``.

Coordinates: metres in the world frame, x east, y north, z up; yaw in degrees counter-clockwise
from +x (the YAML is written by people), radians everywhere else in the code.

The module also holds the pure geometry the rest of the simulator and the tests need
(:func:`footprints`, :func:`clearance_m`, :func:`sample_polyline`, :func:`follow_walkthrough`)
and :func:`apply_appearance`, which turns a spec and an ``appearance_seed`` into the spec of the
same world under other light with a few props moved. Nothing here imports pybullet.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Optional, Sequence

import numpy as np

from robot.configfile import ConfigError, load_config
from sim.textures import TextureSpec

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]

#: repository root: the parent of the ``sim`` package
REPO_ROOT = Path(__file__).resolve().parent.parent
WORLDS_DIR = REPO_ROOT / "configs" / "worlds"

#: the walkthrough must end this close to its start, so the mapping run can close the loop
WALKTHROUGH_CLOSE_M = 1.0
#: an evaluation route's length_m may differ this much (fraction) from its polyline
ROUTE_LENGTH_TOLERANCE = 0.10
#: any route point this close to a wall or prop is an error (the Limo's half diagonal is 0.19 m)
MIN_PATH_CLEARANCE_M = 0.25
#: a route point must be this close to the walkthrough to count as "along it"
ALONG_TOLERANCE_M = 0.30
#: start/goal yaw and the walkthrough heading there may differ this much
HEADING_TOLERANCE_DEG = 35.0
#: largest shift and turn that an appearance seed gives a movable prop
MAX_PROP_SHIFT_M = 0.20
MAX_PROP_TURN_DEG = 20.0


class WorldError(ConfigError):
    """A world file is invalid; the message names the file and the field."""


# ---------------------------------------------------------------- the schema


@dataclass(frozen=True, kw_only=True)
class FloorSpec:
    """The floor rectangle ``origin_m`` (south-west corner) + ``size_m`` (x, y), and an optional ceiling."""

    size_m: Vec2
    origin_m: Vec2 = (0.0, 0.0)
    texture: TextureSpec = TextureSpec(kind="tiles", tile_m=(2.0, 2.0))
    #: height of a flat ceiling over the whole floor; ``None``: none (white background above walls)
    ceiling_height_m: Optional[float] = None
    ceiling_texture: TextureSpec = TextureSpec(kind="plain", color=(0.93, 0.93, 0.9))


@dataclass(frozen=True, kw_only=True)
class DecalSpec:
    """A flat picture on one face of a wall (poster, sign, door, window, board).

    ``at_m``: distance along the wall from its ``start`` to the decal's centre. ``side``: the face
    on the left or right, looking from ``start`` to ``end``. ``size_m``: width and height.
    ``bottom_m``: height of its lower edge above the floor. One copy of the texture covers it.
    """

    texture: TextureSpec
    at_m: float
    side: Literal["left", "right"]
    size_m: Vec2
    bottom_m: float = 0.0
    name: str = ""


@dataclass(frozen=True, kw_only=True)
class WallSpec:
    """A straight wall on the segment ``start``-``end`` (its centre line).

    The box extends ``thickness_m / 2`` beyond both ends, so two walls that share an end point
    close the corner. The texture repeats every ``texture.tile_m`` metres along the wall.
    """

    start: Vec2
    end: Vec2
    height_m: float = 2.5
    thickness_m: float = 0.15
    texture: TextureSpec = TextureSpec(kind="noise")
    decals: tuple[DecalSpec, ...] = ()

    @property
    def length_m(self) -> float:
        return math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])


@dataclass(frozen=True, kw_only=True)
class PartSpec:
    """One primitive of a prop, in the prop's frame.

    ``size_m``: box x, y, z extents; cylinder diameter, diameter, height; sphere diameter x3.
    ``offset_m``: x, y of the part's centre and z of its bottom, relative to the prop pose
    (a part standing on the floor has z 0). ``color``: RGB 0..1; ``texture`` (optional) is
    stretched over each face.
    """

    shape: Literal["box", "cylinder", "sphere"]
    size_m: Vec3
    offset_m: Vec3 = (0.0, 0.0, 0.0)
    color: Vec3 = (0.6, 0.6, 0.6)
    texture: Optional[TextureSpec] = None


@dataclass(frozen=True, kw_only=True)
class PropSpec:
    """Furniture or an obstacle: a pybullet_data ``model`` or a list of primitive ``parts``.

    ``pose``: x_m, y_m, yaw_deg. ``model``: a path inside pybullet_data (``table/table.urdf``)
    loaded with ``scale``; it needs ``footprint_m`` (x, y extent after scaling, in the prop
    frame), which also becomes an invisible collision block so the Limo cannot drive under it.
    ``movable``: an appearance seed may shift it (up to :data:`MAX_PROP_SHIFT_M`) and turn it
    (up to :data:`MAX_PROP_TURN_DEG`).
    """

    name: str
    pose: Vec3
    model: Optional[str] = None
    scale: float = 1.0
    footprint_m: Optional[Vec2] = None
    parts: tuple[PartSpec, ...] = ()
    movable: bool = False


@dataclass(frozen=True, kw_only=True)
class LightSpec:
    """TinyRenderer's single light. ``direction`` points from the scene toward the light."""

    direction: Vec3 = (0.4, 0.3, 1.0)
    color: Vec3 = (1.0, 1.0, 1.0)
    ambient: float = 0.6
    diffuse: float = 0.4
    specular: float = 0.05
    shadow: bool = False


@dataclass(frozen=True, kw_only=True)
class EvaluationRouteSpec:
    """A navigation task: drive from ``start`` to ``goal`` (x_m, y_m, yaw_deg).

    ``waypoints``: the corners of the shortest drivable route between them (start and goal
    excluded); ``length_m`` its length (within 10% of the polyline). ``difficulty`` grades the
    turns and obstacles.
    """

    start: Vec3
    goal: Vec3
    length_m: float
    difficulty: Literal["easy", "moderate", "hard"]
    description: str
    waypoints: tuple[Vec2, ...] = ()

    @property
    def path(self) -> tuple[Vec2, ...]:
        """The route polyline: start, waypoints, goal (x, y in metres)."""
        return ((self.start[0], self.start[1]), *self.waypoints, (self.goal[0], self.goal[1]))


@dataclass(frozen=True, kw_only=True)
class RoutesSpec:
    """``walkthrough``: waypoints of the mapping drive, ending where it started (a loop).
    ``evaluation``: navigation tasks by name, each along the walkthrough in its direction."""

    walkthrough: tuple[Vec2, ...]
    evaluation: dict[str, EvaluationRouteSpec] = field(default_factory=dict)


@dataclass(frozen=True, kw_only=True)
class WorldSpec:
    """One world. See the README section "Writing a world" for every field."""

    name: str
    description: str = ""
    floor: FloorSpec
    walls: tuple[WallSpec, ...]
    props: tuple[PropSpec, ...] = ()
    light: LightSpec = LightSpec()
    routes: RoutesSpec


# ---------------------------------------------------------------- loading


def available_worlds(directory: Path = WORLDS_DIR) -> list[str]:
    """Names of the worlds shipped in ``configs/worlds``."""
    return sorted(p.stem for p in Path(directory).glob("*.yaml"))


def resolve_world_path(name_or_path: str | Path) -> Path:
    """A bare name means ``configs/worlds/NAME.yaml``; anything else is a path."""
    text = str(name_or_path)
    if "/" not in text and "\\" not in text and not text.endswith((".yaml", ".yml")):
        path = WORLDS_DIR / f"{text}.yaml"
        if not path.is_file():
            known = ", ".join(available_worlds()) or "none"
            raise WorldError(str(path), "", f"no world named {text!r} (available: {known})")
        return path
    return Path(name_or_path)


def load_world(name_or_path: str | Path) -> WorldSpec:
    """Read and check a world: a bare name (``hospital``) or a path to a YAML file."""
    path = resolve_world_path(name_or_path)
    try:
        spec = load_config(WorldSpec, path)
    except WorldError:
        raise
    except ConfigError as exc:
        raise WorldError(exc.source, exc.field, exc.problem) from None
    check_world(spec, str(path))
    return spec


def check_world(spec: WorldSpec, source: str = "<world>") -> None:
    """Raise :class:`WorldError` (naming ``source`` and the field) on the first problem."""
    for field_path, problem in _problems(spec):
        raise WorldError(source, field_path, problem)


# ---------------------------------------------------------------- geometry


def polyline_length_m(points: Sequence[Sequence[float]]) -> float:
    """Sum of the segment lengths of a polyline (metres)."""
    pts = np.asarray(points, dtype=float)
    if len(pts) < 2:
        return 0.0
    return float(np.hypot(*np.diff(pts, axis=0).T).sum())


def sample_polyline(points: Sequence[Sequence[float]], step_m: float = 0.05) -> np.ndarray:
    """Points every ``step_m`` along a polyline, both ends and every corner included: (N, 2)."""
    pts = np.asarray(points, dtype=float)
    out = [pts[:1]]
    for a, b in zip(pts[:-1], pts[1:]):
        n = max(1, int(math.ceil(math.hypot(*(b - a)) / step_m)))
        t = np.arange(1, n + 1)[:, None] / n
        out.append(a + t * (b - a))
    return np.concatenate(out)


@dataclass(frozen=True)
class Footprint:
    """The floor area an obstacle blocks: a rotated rectangle or a circle (metres, radians)."""

    owner: str            # "walls[3]", "props[2] bench_1"
    kind: Literal["rect", "circle"]
    center: Vec2
    half_extents: Vec2 = (0.0, 0.0)
    yaw_rad: float = 0.0
    radius_m: float = 0.0

    def distance_m(self, xy: np.ndarray) -> np.ndarray:
        """Signed distance from points (N, 2) to this footprint (negative inside)."""
        d = np.asarray(xy, dtype=float) - np.asarray(self.center)
        if self.kind == "circle":
            return np.hypot(d[:, 0], d[:, 1]) - self.radius_m
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        local = np.abs(np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1))
        q = local - np.asarray(self.half_extents)
        outside = np.hypot(np.maximum(q[:, 0], 0.0), np.maximum(q[:, 1], 0.0))
        inside = np.minimum(np.maximum(q[:, 0], q[:, 1]), 0.0)
        return outside + inside

    def corners(self) -> np.ndarray:
        """The 4 corners (rect) or 24 points on the circle, counter-clockwise: (K, 2)."""
        if self.kind == "circle":
            a = np.linspace(0.0, 2.0 * math.pi, 24, endpoint=False)
            return np.asarray(self.center) + self.radius_m * np.stack([np.cos(a), np.sin(a)], axis=1)
        hx, hy = self.half_extents
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return local @ np.array([[c, s], [-s, c]]) + np.asarray(self.center)


def wall_footprint(wall: WallSpec, owner: str = "wall") -> Footprint:
    """The wall box seen from above (its ends extend by half the thickness)."""
    (x0, y0), (x1, y1) = wall.start, wall.end
    return Footprint(owner, "rect", ((x0 + x1) / 2, (y0 + y1) / 2),
                     (wall.length_m / 2 + wall.thickness_m / 2, wall.thickness_m / 2),
                     math.atan2(y1 - y0, x1 - x0))


def prop_footprints(prop: PropSpec, owner: str = "prop") -> list[Footprint]:
    """What a prop blocks on the floor: its model footprint or one footprint per part."""
    x, y, yaw_deg = prop.pose
    yaw = math.radians(yaw_deg)
    c, s = math.cos(yaw), math.sin(yaw)
    if prop.model is not None:
        fx, fy = prop.footprint_m or (0.0, 0.0)
        return [Footprint(owner, "rect", (x, y), (fx / 2, fy / 2), yaw)]
    out = []
    for part in prop.parts:
        ox, oy, _ = part.offset_m
        center = (x + c * ox - s * oy, y + s * ox + c * oy)
        if part.shape == "box":
            out.append(Footprint(owner, "rect", center, (part.size_m[0] / 2, part.size_m[1] / 2), yaw))
        else:
            out.append(Footprint(owner, "circle", center, radius_m=part.size_m[0] / 2))
    return out


def footprints(spec: WorldSpec) -> list[Footprint]:
    """Every wall and prop footprint of a world."""
    out = [wall_footprint(w, f"walls[{i}]") for i, w in enumerate(spec.walls)]
    for i, prop in enumerate(spec.props):
        out.extend(prop_footprints(prop, f"props[{i}] {prop.name}"))
    return out


def clearance_m(spec: WorldSpec, points: Sequence[Sequence[float]]) -> tuple[np.ndarray, list[str]]:
    """Distance (m) from each point to the nearest wall or prop surface, and that obstacle's name."""
    xy = np.asarray(points, dtype=float).reshape(-1, 2)
    prints = footprints(spec)
    if not prints:
        return np.full(len(xy), np.inf), ["" for _ in range(len(xy))]
    dist = np.stack([fp.distance_m(xy) for fp in prints], axis=0)
    nearest = np.argmin(dist, axis=0)
    return dist[nearest, np.arange(len(xy))], [prints[k].owner for k in nearest]


def _headings(samples: np.ndarray) -> np.ndarray:
    """Direction of travel at each sample (radians); the last copies the one before."""
    d = np.diff(samples, axis=0)
    h = np.arctan2(d[:, 1], d[:, 0])
    return np.concatenate([h, h[-1:]])


def _angle_diff(a: float, b: float) -> float:
    return abs((a - b + math.pi) % (2.0 * math.pi) - math.pi)


def _cyclic_samples(walkthrough: Sequence[Vec2], step_m: float) -> np.ndarray:
    """Samples of the walkthrough; a closed one continues into a second lap from where it ended.

    The mapping run closes the loop where it ends, so a route may run over the seam (from
    the last metres of the walkthrough into its first ones).
    """
    walk = sample_polyline(walkthrough, step_m)
    gap = float(np.hypot(*(walk[-1] - walk[0])))
    if gap > WALKTHROUGH_CLOSE_M:
        return walk
    head = int(math.ceil((gap + 1.0) / step_m)) + 1
    join = int(np.argmin(np.hypot(*(walk[:head] - walk[-1]).T)))
    return np.concatenate([walk, walk[join + 1:]])


@dataclass(frozen=True)
class AlongWalkthrough:
    """Where a route runs along the walkthrough: arc lengths (m) of its start and goal on the
    (possibly second-lap) walkthrough and the walkthrough's heading (rad) at both."""

    s_start_m: float
    s_goal_m: float
    heading_start_rad: float
    heading_goal_rad: float


def follow_walkthrough(walkthrough: Sequence[Vec2], path: Sequence[Vec2], start_yaw_rad: float,
                       step_m: float = 0.05, tol_m: float = ALONG_TOLERANCE_M) -> Optional[AlongWalkthrough]:
    """Where ``path`` runs along ``walkthrough`` in the walkthrough's direction, or ``None``.

    The first stretch that starts at the path's start with a heading within
    :data:`HEADING_TOLERANCE_DEG` of ``start_yaw_rad`` and then stays within ``tol_m`` of every
    path point in order, moving forward only (at most 1 m + 2 tol per 5 cm step). A closed
    walkthrough is followed over its seam into a second lap.
    """
    walk = _cyclic_samples(walkthrough, step_m)
    heads = _headings(walk)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(walk, axis=0).T))])
    route = sample_polyline(path, step_m)
    d0 = np.hypot(*(walk - route[0]).T)
    tol_h = math.radians(HEADING_TOLERANCE_DEG)
    ok0 = (d0 <= tol_m) & np.array([_angle_diff(h, start_yaw_rad) <= tol_h for h in heads])
    window = int(math.ceil((1.0 + 2 * tol_m) / step_m))
    tried_until = -1
    for i0 in np.flatnonzero(ok0):
        if i0 <= tried_until:
            continue  # one attempt per pass of the walkthrough through the start
        run_end = i0
        while run_end + 1 < len(walk) and ok0[run_end + 1]:
            run_end += 1
        tried_until = run_end
        start = i0 + int(np.argmin(d0[i0:run_end + 1]))
        j = start
        for point in route[1:]:
            hi = min(len(walk), j + window)
            dist = np.hypot(*(walk[j:hi] - point).T)
            if dist.size == 0 or dist.min() > tol_m:
                break
            j = j + int(np.argmin(dist))
        else:
            return AlongWalkthrough(float(arc[start]), float(arc[j]), float(heads[start]), float(heads[j]))
    return None


# ---------------------------------------------------------------- appearance


def apply_appearance(spec: WorldSpec, appearance_seed: int) -> WorldSpec:
    """The same world under another appearance: light jittered, about half the movable props moved.

    Seed 0 returns ``spec`` unchanged. Other seeds are deterministic: the light direction turns
    by up to 60 deg in azimuth with an elevation of 30..75 deg, its colour gets a warm or cool
    tint of up to 10%, the ambient/diffuse coefficients move by up to 0.12 and the specular one
    by up to 0.05; ceil(n/2) of the n movable props shift by 0.05..MAX_PROP_SHIFT_M and turn by
    up to MAX_PROP_TURN_DEG. Walls, decals and routes never change.
    """
    if appearance_seed < 0:
        raise ValueError(f"appearance_seed must be >= 0, got {appearance_seed}")
    if appearance_seed == 0:
        return spec
    rng = np.random.default_rng([appearance_seed, 0x5EED])
    return dataclasses.replace(spec, light=_jitter_light(spec.light, rng), props=_move_props(spec.props, rng))


def _jitter_light(light: LightSpec, rng: np.random.Generator) -> LightSpec:
    d = np.asarray(light.direction, dtype=float)
    azimuth = math.atan2(d[1], d[0]) + math.radians(rng.uniform(-60.0, 60.0))
    elevation = math.radians(rng.uniform(30.0, 75.0))
    direction = (math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                 math.sin(elevation))
    tint = rng.uniform(-1.0, 1.0)
    gain = rng.uniform(0.92, 1.0)
    color = np.clip(np.asarray(light.color) * gain * (1.0 + 0.1 * np.array([tint, 0.0, -tint])), 0.0, 1.0)
    return dataclasses.replace(
        light,
        direction=tuple(round(v, 6) for v in direction),
        color=tuple(float(round(v, 6)) for v in color),
        ambient=float(np.clip(light.ambient + rng.uniform(-0.12, 0.12), 0.25, 0.95)),
        diffuse=float(np.clip(light.diffuse + rng.uniform(-0.12, 0.12), 0.1, 0.8)),
        specular=float(np.clip(light.specular + rng.uniform(-0.05, 0.05), 0.0, 0.3)),
    )


def _move_props(props: tuple[PropSpec, ...], rng: np.random.Generator) -> tuple[PropSpec, ...]:
    movable = [i for i, p in enumerate(props) if p.movable]
    if not movable:
        return props
    chosen = set(rng.choice(movable, size=(len(movable) + 1) // 2, replace=False).tolist())
    out = list(props)
    for i in sorted(chosen):
        x, y, yaw = props[i].pose
        r = rng.uniform(0.05, MAX_PROP_SHIFT_M)
        a = rng.uniform(0.0, 2.0 * math.pi)
        turn = rng.uniform(-MAX_PROP_TURN_DEG, MAX_PROP_TURN_DEG)
        out[i] = dataclasses.replace(props[i], pose=(x + r * math.cos(a), y + r * math.sin(a), yaw + turn))
    return tuple(out)


# ---------------------------------------------------------------- checks


def _problems(spec: WorldSpec):
    """Yield (field path, problem) pairs, most basic first."""
    if not spec.name.strip():
        yield "name", "must not be empty"
    yield from _floor_problems(spec.floor)
    for i, wall in enumerate(spec.walls):
        yield from _wall_problems(wall, f"walls[{i}]", spec.floor)
    names: set[str] = set()
    for i, prop in enumerate(spec.props):
        if prop.name in names:
            yield f"props[{i}].name", f"{prop.name!r} is used by an earlier prop; names must be unique"
        names.add(prop.name)
        yield from _prop_problems(prop, f"props[{i}]", spec.floor)
    yield from _light_problems(spec.light)
    yield from _route_problems(spec)


def _inside_floor(floor: FloorSpec, xy: Sequence[float], margin: float = 0.5) -> bool:
    (x0, y0), (sx, sy) = floor.origin_m, floor.size_m
    return x0 - margin <= xy[0] <= x0 + sx + margin and y0 - margin <= xy[1] <= y0 + sy + margin


def _floor_problems(floor: FloorSpec):
    if not all(s > 0 for s in floor.size_m):
        yield "floor.size_m", f"both sides must be > 0 m, got {list(floor.size_m)}"
    if floor.ceiling_height_m is not None and floor.ceiling_height_m <= 0.5:
        yield "floor.ceiling_height_m", f"must be > 0.5 m (above the camera), got {floor.ceiling_height_m}"


def _wall_problems(wall: WallSpec, where: str, floor: FloorSpec):
    if wall.length_m < 0.05:
        yield where, f"start {list(wall.start)} and end {list(wall.end)} are less than 5 cm apart"
        return
    if wall.height_m <= 0:
        yield f"{where}.height_m", f"must be > 0 m, got {wall.height_m}"
    if not 0 < wall.thickness_m <= 1.0:
        yield f"{where}.thickness_m", f"must be within (0, 1] m, got {wall.thickness_m}"
    for end in ("start", "end"):
        if not _inside_floor(floor, getattr(wall, end)):
            yield f"{where}.{end}", f"{list(getattr(wall, end))} lies outside the floor"
    half_t = wall.thickness_m / 2
    for j, decal in enumerate(wall.decals):
        at = f"{where}.decals[{j}]"
        w, h = decal.size_m
        if w <= 0 or h <= 0:
            yield f"{at}.size_m", f"both sides must be > 0 m, got {list(decal.size_m)}"
        elif decal.at_m - w / 2 < -half_t - 1e-6 or decal.at_m + w / 2 > wall.length_m + half_t + 1e-6:
            yield f"{at}.at_m", (f"a {w} m wide decal centred at {decal.at_m} m does not fit on a "
                                 f"{wall.length_m:.2f} m wall")
        elif decal.bottom_m < 0 or decal.bottom_m + h > wall.height_m + 1e-6:
            yield f"{at}.bottom_m", (f"a {h} m high decal from {decal.bottom_m} m does not fit on a "
                                     f"{wall.height_m} m high wall")


def _prop_problems(prop: PropSpec, where: str, floor: FloorSpec):
    if not prop.name.strip():
        yield f"{where}.name", "must not be empty"
    if (prop.model is None) == (not prop.parts):
        yield where, "give either model (a pybullet_data path) or parts (primitives), not both or neither"
        return
    if not _inside_floor(floor, prop.pose[:2]):
        yield f"{where}.pose", f"{list(prop.pose[:2])} lies outside the floor"
    if prop.model is not None:
        import pybullet_data  # data files only; no physics import here

        if not (Path(pybullet_data.getDataPath()) / prop.model).is_file():
            yield f"{where}.model", f"{prop.model!r} is not a file in pybullet_data"
        if prop.scale <= 0:
            yield f"{where}.scale", f"must be > 0, got {prop.scale}"
        if prop.footprint_m is None:
            yield f"{where}.footprint_m", "a model prop needs its footprint [x, y] in metres"
        elif not all(v > 0 for v in prop.footprint_m):
            yield f"{where}.footprint_m", f"both sides must be > 0 m, got {list(prop.footprint_m)}"
        return
    for k, part in enumerate(prop.parts):
        at = f"{where}.parts[{k}]"
        sx, sy, sz = part.size_m
        if not (sx > 0 and sy > 0 and sz > 0):
            yield f"{at}.size_m", f"all sizes must be > 0 m, got {list(part.size_m)}"
        elif part.shape == "cylinder" and abs(sx - sy) > 1e-9:
            yield f"{at}.size_m", f"a cylinder needs equal x and y (its diameter), got {list(part.size_m)}"
        elif part.shape == "sphere" and not (abs(sx - sy) < 1e-9 and abs(sx - sz) < 1e-9):
            yield f"{at}.size_m", f"a sphere needs three equal sizes (its diameter), got {list(part.size_m)}"
        if not all(0.0 <= c <= 1.0 for c in part.color):
            yield f"{at}.color", f"each channel must be within 0..1, got {list(part.color)}"
        if part.offset_m[2] < 0:
            yield f"{at}.offset_m", f"z (the part's bottom) must be >= 0, got {part.offset_m[2]}"


def _light_problems(light: LightSpec):
    if float(np.linalg.norm(light.direction)) < 1e-6:
        yield "light.direction", "must not be the zero vector"
    if not all(0.0 <= c <= 1.0 for c in light.color):
        yield "light.color", f"each channel must be within 0..1, got {list(light.color)}"
    for name in ("ambient", "diffuse", "specular"):
        if not 0.0 <= getattr(light, name) <= 1.0:
            yield f"light.{name}", f"must be within 0..1, got {getattr(light, name)}"


def _route_problems(spec: WorldSpec):
    walk = spec.routes.walkthrough
    if len(walk) < 3:
        yield "routes.walkthrough", f"needs at least 3 waypoints, got {len(walk)}"
        return
    gap = math.hypot(walk[-1][0] - walk[0][0], walk[-1][1] - walk[0][1])
    if gap > WALKTHROUGH_CLOSE_M:
        yield "routes.walkthrough", (f"ends {gap:.2f} m from its start {list(walk[0])}; it must come back "
                                     f"within {WALKTHROUGH_CLOSE_M} m so the mapping run can close the loop")
    yield from _clearance_problems(spec, walk, "routes.walkthrough")
    for name, route in spec.routes.evaluation.items():
        where = f"routes.evaluation.{name}"
        poly = polyline_length_m(route.path)
        if poly < 0.5:
            yield where, f"start and goal are only {poly:.2f} m apart"
            continue
        if abs(route.length_m - poly) > ROUTE_LENGTH_TOLERANCE * poly:
            yield f"{where}.length_m", (f"{route.length_m} m disagrees with the waypoint polyline "
                                        f"({poly:.2f} m) by more than {ROUTE_LENGTH_TOLERANCE:.0%}")
        yield from _clearance_problems(spec, route.path, where)
        yield from _direction_problems(route, where)
        yield from _along_problems(walk, route, where)


def _clearance_problems(spec: WorldSpec, path: Sequence[Vec2], where: str):
    samples = sample_polyline(path, 0.05)
    dist, owner = clearance_m(spec, samples)
    k = int(np.argmin(dist))
    if dist[k] < MIN_PATH_CLEARANCE_M:
        x, y = samples[k]
        yield where, (f"passes {dist[k]:.2f} m from {owner[k]} at ({x:.2f}, {y:.2f}); routes need at least "
                      f"{MIN_PATH_CLEARANCE_M} m clearance for the Limo")


def _direction_problems(route: EvaluationRouteSpec, where: str):
    path = route.path
    first = math.atan2(path[1][1] - path[0][1], path[1][0] - path[0][0])
    last = math.atan2(path[-1][1] - path[-2][1], path[-1][0] - path[-2][0])
    tol = math.radians(HEADING_TOLERANCE_DEG)
    if _angle_diff(math.radians(route.start[2]), first) > tol:
        yield f"{where}.start", (f"yaw {route.start[2]} deg does not face along the first leg "
                                 f"({math.degrees(first):.0f} deg)")
    if _angle_diff(math.radians(route.goal[2]), last) > tol:
        yield f"{where}.goal", (f"yaw {route.goal[2]} deg does not face along the last leg "
                                f"({math.degrees(last):.0f} deg)")


def _along_problems(walk: Sequence[Vec2], route: EvaluationRouteSpec, where: str):
    found = follow_walkthrough(walk, route.path, math.radians(route.start[2]))
    if found is None:
        yield where, (f"does not lie along the walkthrough in its direction of travel (every point within "
                      f"{ALONG_TOLERANCE_M} m, same heading); the map is a directed graph of what was driven")
        return
    if _angle_diff(math.radians(route.goal[2]), found.heading_goal_rad) > math.radians(HEADING_TOLERANCE_DEG):
        yield f"{where}.goal", (f"yaw {route.goal[2]} deg differs from the walkthrough heading there "
                                f"({math.degrees(found.heading_goal_rad):.0f} deg)")
