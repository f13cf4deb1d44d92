"""A simulated world as data: floor, walls, props, light and named routes (the schema of the world
YAML files; :func:`sim.worlds.load_world` reads and checks one).

Coordinates: metres in the world frame, x east, y north, z up; yaw in degrees counter-clockwise
from +x (the YAML is written by people), radians everywhere else in the code. Nothing here
imports pybullet. Beside it: :mod:`sim.worlds` (loading), :mod:`sim.world_checks` (what types
alone cannot check), :mod:`sim.geometry` (footprints, clearance, polylines),
:mod:`sim.route_along` (where a route runs along the walkthrough) and :mod:`sim.appearance`
(another light and a few moved props for an appearance seed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Optional

from core.configfile import ConfigError
from sim.textures import TextureSpec

Vec2 = tuple[float, float]
Vec3 = tuple[float, float, float]


class WorldError(ConfigError):
    """A world file is invalid; the message names the file and the field."""


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
    ``movable``: an appearance seed may shift it (up to :data:`sim.appearance.MAX_PROP_SHIFT_M`) and
    turn it (up to :data:`sim.appearance.MAX_PROP_TURN_DEG`).
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
