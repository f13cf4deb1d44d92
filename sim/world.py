"""Build a :class:`~sim.world_spec.WorldSpec` in a PyBullet client.

``build_world(client_id, spec, appearance_seed)`` creates every body of the world in the given
client (always passing ``physicsClientId``) and returns a :class:`BuiltWorld` with the body ids by
role and the light as keyword arguments for ``p.getCameraImage``. The appearance seed goes
through :func:`sim.appearance.apply_appearance` first (seed 0: the world as written).

How things are made, for TinyRenderer's sake (its cost grows with triangles and covered pixels):

* walls and the floor are one static body each: a collision box plus a visual mesh whose UV
  coordinates repeat the texture every ``tile_m`` metres (TinyRenderer wraps UVs), so a 20 m
  wall keeps the plaster grain of a 2 m one without being cut into many boxes;
* decals (posters, signs, doors) are single textured quads 4 mm in front of the wall face, one
  copy of the texture stretched over them, visual only; identical texture specs share one
  loaded texture, so identical doors are pixel-identical;
* prop parts are primitives joined by fixed links into one static multibody; a pybullet_data
  model gets an invisible collision block of its footprint, so the Limo cannot drive under it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import pybullet_data

from sim.appearance import apply_appearance
from sim.bullet import p
from sim.textures import TextureSpec, texture_png
from sim.world_spec import DecalSpec, LightSpec, PartSpec, PropSpec, WallSpec, WorldSpec

# decals float this far in front of the wall so the depth test never lets the wall win
_DECAL_GAP_M = 0.004
# height of the invisible block under a model prop: above the Limo's 0.25 m, below table tops
_BLOCKER_HEIGHT_M = 0.4
_FLOOR_THICKNESS_M = 0.1


@dataclass(frozen=True)
class BuiltWorld:
    """The bodies of a built world, by role, and its light.

    ``floor_ids``: what the wheels stand on. ``wall_ids``, ``prop_ids`` (one visible body per
    ``spec.props`` entry, same order): static obstacles. ``obstacle_ids``: every body the robot
    can collide with (walls, props and the invisible blocks under model props).
    ``scenery_ids``: visual-only bodies (decals, ceiling). ``spec``: the world as built, after the
    appearance seed moved props and changed the light.
    """

    spec: WorldSpec
    appearance_seed: int
    floor_ids: tuple[int, ...]
    wall_ids: tuple[int, ...]
    prop_ids: tuple[int, ...]
    obstacle_ids: tuple[int, ...]
    scenery_ids: tuple[int, ...]
    light: LightSpec

    @property
    def render_light(self) -> dict:
        """Keyword arguments for ``p.getCameraImage`` (a fresh dict on every call)."""
        return render_light_kwargs(self.light)

    @property
    def body_count(self) -> int:
        return len(self.floor_ids) + len(self.obstacle_ids) + len(self.scenery_ids)


def render_light_kwargs(light: LightSpec) -> dict:
    """A :class:`LightSpec` as ``p.getCameraImage`` keyword arguments."""
    return {
        "lightDirection": [float(v) for v in light.direction],
        "lightColor": [float(v) for v in light.color],
        "lightAmbientCoeff": float(light.ambient),
        "lightDiffuseCoeff": float(light.diffuse),
        "lightSpecularCoeff": float(light.specular),
        "shadow": 1 if light.shadow else 0,
    }


def build_world(client_id: int, spec: WorldSpec, appearance_seed: int = 0,
                texture_dir: Optional[Path] = None) -> BuiltWorld:
    """Create every body of ``spec`` (under ``appearance_seed``) in client ``client_id``.

    Deterministic: the same spec and seed in a fresh client give the same body ids and poses.
    ``texture_dir``: where texture PNGs are cached (default: :func:`sim.textures.default_cache_dir`).
    """
    world = apply_appearance(spec, appearance_seed)
    textures = _TextureLoader(client_id, texture_dir)
    # TinyRenderer draws bodies in creation order and skips shading of pixels that fail the
    # depth test, so what covers others goes first: props, decals (in front of their walls),
    # walls, and the big floor and ceiling last
    prop_ids, blockers = [], []
    for prop in world.props:
        body, blocker = _make_prop(client_id, prop, textures)
        prop_ids.append(body)
        if blocker is not None:
            blockers.append(blocker)
    scenery = [_make_decal(client_id, wall, d, textures) for wall in world.walls for d in wall.decals]
    wall_ids = [_make_wall(client_id, wall, textures) for wall in world.walls]
    floor_ids = (_make_floor(client_id, world, textures),)
    if world.floor.ceiling_height_m is not None:
        scenery.append(_make_ceiling(client_id, world, textures))
    return BuiltWorld(
        spec=world, appearance_seed=appearance_seed, floor_ids=floor_ids, wall_ids=tuple(wall_ids),
        prop_ids=tuple(prop_ids), obstacle_ids=tuple(wall_ids) + tuple(prop_ids) + tuple(blockers),
        scenery_ids=tuple(scenery), light=world.light)


class _TextureLoader:
    """Loads each distinct texture once per client (equal specs share one texture id)."""

    def __init__(self, client_id: int, cache_dir: Optional[Path]):
        self._client = client_id
        self._dir = cache_dir
        self._ids: dict[str, int] = {}

    def __call__(self, spec: TextureSpec) -> int:
        key = spec.key()
        if key not in self._ids:
            path = texture_png(spec, self._dir)
            tex = p.loadTexture(str(path), physicsClientId=self._client)
            if tex < 0:
                raise RuntimeError(f"pybullet could not load texture {path}")
            self._ids[key] = tex
        return self._ids[key]


# ---------------------------------------------------------------- meshes


def _quad(corners: np.ndarray, uvs: np.ndarray, normal: np.ndarray):
    """Two triangles, counter-clockwise seen from the side ``normal`` points to."""
    return corners.tolist(), uvs.tolist(), [normal.tolist()] * 4, [0, 1, 2, 0, 2, 3]


def _face_uv(corners: np.ndarray, normal: np.ndarray, tile_w: float, tile_h: float, z0: float) -> np.ndarray:
    """UVs that repeat every tile and read left-to-right seen from outside the face."""
    up = np.array([0.0, 0.0, 1.0]) if abs(normal[2]) < 0.5 else np.array([0.0, 1.0, 0.0])
    right = np.cross(-normal, up)
    u = corners @ right / tile_w
    v = (corners @ up - (z0 if up[2] else 0.0)) / tile_h
    return np.stack([u, v], axis=1)


def _box_mesh(half: np.ndarray, tile: tuple[float, float], with_bottom: bool = False):
    """A box centred at the origin, as one mesh with tiled UVs on every face."""
    hx, hy, hz = half
    faces = [  # normal, four corners counter-clockwise seen from outside
        ((1, 0, 0), [(hx, -hy, -hz), (hx, hy, -hz), (hx, hy, hz), (hx, -hy, hz)]),
        ((-1, 0, 0), [(-hx, hy, -hz), (-hx, -hy, -hz), (-hx, -hy, hz), (-hx, hy, hz)]),
        ((0, 1, 0), [(hx, hy, -hz), (-hx, hy, -hz), (-hx, hy, hz), (hx, hy, hz)]),
        ((0, -1, 0), [(-hx, -hy, -hz), (hx, -hy, -hz), (hx, -hy, hz), (-hx, -hy, hz)]),
        ((0, 0, 1), [(-hx, -hy, hz), (hx, -hy, hz), (hx, hy, hz), (-hx, hy, hz)]),
    ]
    if with_bottom:
        faces.append(((0, 0, -1), [(-hx, hy, -hz), (hx, hy, -hz), (hx, -hy, -hz), (-hx, -hy, -hz)]))
    verts, uvs, normals, idx = [], [], [], []
    for n, c in faces:
        n, c = np.asarray(n, float), np.asarray(c, float)
        v, uv, nn, ii = _quad(c, _face_uv(c, n, tile[0], tile[1], -hz), n)
        idx.extend(len(verts) + k for k in ii)
        verts.extend(v)
        uvs.extend(uv)
        normals.extend(nn)
    return verts, uvs, normals, idx


def _mesh_shape(client: int, mesh) -> int:
    verts, uvs, normals, idx = mesh
    shape = p.createVisualShape(p.GEOM_MESH, vertices=verts, indices=idx, uvs=uvs, normals=normals,
                                physicsClientId=client)
    if shape < 0:
        raise RuntimeError("pybullet could not create a mesh visual shape")
    return shape


def _quat_yaw(yaw_rad: float) -> list[float]:
    return [0.0, 0.0, math.sin(yaw_rad / 2), math.cos(yaw_rad / 2)]


def _textured(client: int, body: int, tex: int, link: int = -1) -> int:
    p.changeVisualShape(body, link, textureUniqueId=tex, rgbaColor=[1, 1, 1, 1], physicsClientId=client)
    return body


# ---------------------------------------------------------------- bodies


def _make_floor(client: int, world: WorldSpec, textures: _TextureLoader) -> int:
    (x0, y0), (sx, sy) = world.floor.origin_m, world.floor.size_m
    tw, th = world.floor.texture.tile_m
    corners = np.array([[-sx / 2, -sy / 2, 0], [sx / 2, -sy / 2, 0], [sx / 2, sy / 2, 0], [-sx / 2, sy / 2, 0]])
    uvs = np.stack([(corners[:, 0] + x0 + sx / 2) / tw, (corners[:, 1] + y0 + sy / 2) / th], axis=1)
    visual = _mesh_shape(client, _quad(corners, uvs, np.array([0.0, 0.0, 1.0])))
    collision = p.createCollisionShape(p.GEOM_BOX, halfExtents=[sx / 2, sy / 2, _FLOOR_THICKNESS_M / 2],
                                       collisionFramePosition=[0, 0, -_FLOOR_THICKNESS_M / 2],
                                       physicsClientId=client)
    body = p.createMultiBody(0, collision, visual, [x0 + sx / 2, y0 + sy / 2, 0.0], physicsClientId=client)
    return _textured(client, body, textures(world.floor.texture))


def _make_ceiling(client: int, world: WorldSpec, textures: _TextureLoader) -> int:
    (x0, y0), (sx, sy) = world.floor.origin_m, world.floor.size_m
    tex = world.floor.ceiling_texture
    # counter-clockwise seen from below
    corners = np.array([[-sx / 2, sy / 2, 0], [sx / 2, sy / 2, 0], [sx / 2, -sy / 2, 0], [-sx / 2, -sy / 2, 0]])
    uvs = np.stack([corners[:, 0] / tex.tile_m[0], corners[:, 1] / tex.tile_m[1]], axis=1)
    visual = _mesh_shape(client, _quad(corners, uvs, np.array([0.0, 0.0, -1.0])))
    body = p.createMultiBody(0, -1, visual, [x0 + sx / 2, y0 + sy / 2, world.floor.ceiling_height_m],
                             physicsClientId=client)
    return _textured(client, body, textures(tex))


def _make_wall(client: int, wall: WallSpec, textures: _TextureLoader) -> int:
    (x0, y0), (x1, y1) = wall.start, wall.end
    half = np.array([wall.length_m / 2 + wall.thickness_m / 2, wall.thickness_m / 2, wall.height_m / 2])
    visual = _mesh_shape(client, _box_mesh(half, wall.texture.tile_m))
    collision = p.createCollisionShape(p.GEOM_BOX, halfExtents=half.tolist(), physicsClientId=client)
    yaw = math.atan2(y1 - y0, x1 - x0)
    body = p.createMultiBody(0, collision, visual, [(x0 + x1) / 2, (y0 + y1) / 2, wall.height_m / 2],
                             _quat_yaw(yaw), physicsClientId=client)
    return _textured(client, body, textures(wall.texture))


def _make_decal(client: int, wall: WallSpec, decal: DecalSpec, textures: _TextureLoader) -> int:
    (x0, y0), (x1, y1) = wall.start, wall.end
    along = np.array([x1 - x0, y1 - y0]) / wall.length_m
    left = np.array([-along[1], along[0]])
    outward = left if decal.side == "left" else -left
    centre = np.array([x0, y0]) + along * decal.at_m + outward * (wall.thickness_m / 2 + _DECAL_GAP_M)
    # seen from outside the face (looking along -outward), "right" is (-outward) x up
    right = np.array([-outward[1], outward[0]])
    w, h = decal.size_m
    corners2 = [centre - right * w / 2, centre + right * w / 2, centre + right * w / 2, centre - right * w / 2]
    z = [decal.bottom_m, decal.bottom_m, decal.bottom_m + h, decal.bottom_m + h]
    corners = np.array([[c[0] - centre[0], c[1] - centre[1], zz] for c, zz in zip(corners2, z)])
    uvs = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    normal = np.array([outward[0], outward[1], 0.0])
    visual = _mesh_shape(client, _quad(corners, uvs, normal))
    body = p.createMultiBody(0, -1, visual, [centre[0], centre[1], 0.0], physicsClientId=client)
    return _textured(client, body, textures(decal.texture))


def _part_shapes(client: int, part: PartSpec) -> tuple[int, int, list[float]]:
    """Collision shape, visual shape and the centre (in the prop frame) of one part."""
    sx, sy, sz = part.size_m
    rgba = [*part.color, 1.0]
    if part.shape == "box":
        half = [sx / 2, sy / 2, sz / 2]
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=rgba, physicsClientId=client)
    elif part.shape == "cylinder":
        col = p.createCollisionShape(p.GEOM_CYLINDER, radius=sx / 2, height=sz, physicsClientId=client)
        vis = p.createVisualShape(p.GEOM_CYLINDER, radius=sx / 2, length=sz, rgbaColor=rgba,
                                  physicsClientId=client)
    else:
        col = p.createCollisionShape(p.GEOM_SPHERE, radius=sx / 2, physicsClientId=client)
        vis = p.createVisualShape(p.GEOM_SPHERE, radius=sx / 2, rgbaColor=rgba, physicsClientId=client)
    ox, oy, oz = part.offset_m
    return col, vis, [ox, oy, oz + sz / 2]


def _make_prop(client: int, prop: PropSpec, textures: _TextureLoader) -> tuple[int, Optional[int]]:
    """The prop's visible body and, for a model, its invisible collision block."""
    x, y, yaw_deg = prop.pose
    orn = _quat_yaw(math.radians(yaw_deg))
    if prop.model is not None:
        path = str(Path(pybullet_data.getDataPath()) / prop.model)
        body = p.loadURDF(path, [x, y, 0.0], orn, useFixedBase=True, globalScaling=prop.scale,
                          physicsClientId=client)
        fx, fy = prop.footprint_m
        block = p.createCollisionShape(p.GEOM_BOX, halfExtents=[fx / 2, fy / 2, _BLOCKER_HEIGHT_M / 2],
                                       physicsClientId=client)
        blocker = p.createMultiBody(0, block, -1, [x, y, _BLOCKER_HEIGHT_M / 2], orn, physicsClientId=client)
        return body, blocker
    shapes = [_part_shapes(client, part) for part in prop.parts]
    (col0, vis0, pos0), rest = shapes[0], shapes[1:]
    cy, sy = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    # the base is the first part; the others hang on fixed joints, positions relative to it
    body = p.createMultiBody(
        baseMass=0, baseCollisionShapeIndex=col0, baseVisualShapeIndex=vis0,
        basePosition=[x + cy * pos0[0] - sy * pos0[1], y + sy * pos0[0] + cy * pos0[1], pos0[2]],
        baseOrientation=orn,
        linkMasses=[0.0] * len(rest),
        linkCollisionShapeIndices=[shape[0] for shape in rest],
        linkVisualShapeIndices=[shape[1] for shape in rest],
        linkPositions=[[shape[2][k] - pos0[k] for k in range(3)] for shape in rest],
        linkOrientations=[[0, 0, 0, 1]] * len(rest),
        linkInertialFramePositions=[[0, 0, 0]] * len(rest),
        linkInertialFrameOrientations=[[0, 0, 0, 1]] * len(rest),
        linkParentIndices=[0] * len(rest),
        linkJointTypes=[p.JOINT_FIXED] * len(rest),
        linkJointAxis=[[0, 0, 1]] * len(rest),
        physicsClientId=client)
    for link, part in enumerate(prop.parts, start=-1):
        if part.texture is not None:
            _textured(client, body, textures(part.texture), link)
    return body, None
