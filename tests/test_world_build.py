"""Deterministic textures and the PyBullet world builder (real DIRECT clients, TinyRenderer)."""

import math

import numpy as np
import pybullet as p
import pytest

from sim.geometry import prop_footprints, wall_footprint
from sim.textures import KINDS, TextureSpec, make_texture, texture_png
from sim.world import build_world
from sim.world_spec import DecalSpec, FloorSpec, RoutesSpec, WallSpec, WorldSpec
from sim.worlds import load_world


@pytest.fixture
def client():
    cid = p.connect(p.DIRECT)
    yield cid
    p.disconnect(cid)


def _poses(cid, ids):
    return [p.getBasePositionAndOrientation(b, physicsClientId=cid) for b in ids]


# ---------------------------------------------------------------- textures


@pytest.mark.parametrize("kind", KINDS)
def test_texture_is_deterministic_and_seed_dependent(kind):
    spec = TextureSpec(kind=kind, seed=3, text="12" if kind == "sign" else "")
    a, b = make_texture(spec), make_texture(TextureSpec(kind=kind, seed=3, text=spec.text))
    w, h = spec.size
    assert a.shape == (h, w, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    if kind != "plain":
        other = make_texture(TextureSpec(kind=kind, seed=4, text=spec.text))
        if kind in ("sign", "door"):
            # their layout is fixed by design (identical doors must look identical): colour changes them
            other = make_texture(TextureSpec(kind=kind, seed=4, text=spec.text, color=(0.2, 0.6, 0.3)))
        assert not np.array_equal(a, other)
        assert a.std() > 2.0, "a patterned texture must not be flat"


def test_texture_png_is_byte_identical_and_cached(tmp_path):
    spec = TextureSpec(kind="poster", seed=17)
    first = texture_png(spec, tmp_path / "a")
    second = texture_png(spec, tmp_path / "b")
    assert first.read_bytes() == second.read_bytes()
    assert texture_png(spec, tmp_path / "a") == first
    assert texture_png(TextureSpec(kind="poster", seed=18), tmp_path / "a") != first


def test_texture_spec_rejects_bad_values():
    with pytest.raises(ValueError, match="color"):
        TextureSpec(kind="noise", color=(1.5, 0, 0))
    with pytest.raises(ValueError, match="size_px"):
        TextureSpec(kind="noise", size_px=(1024, 64))


# ---------------------------------------------------------------- building


@pytest.fixture(scope="module")
def hospital():
    return load_world("hospital")


def test_same_seed_gives_the_same_bodies(hospital, tmp_path):
    worlds = []
    for _ in range(2):
        cid = p.connect(p.DIRECT)
        try:
            built = build_world(cid, hospital, 3, texture_dir=tmp_path)
            ids = built.floor_ids + built.obstacle_ids + built.scenery_ids
            worlds.append((p.getNumBodies(physicsClientId=cid), ids, _poses(cid, ids), built.render_light))
        finally:
            p.disconnect(cid)
    (n_a, ids_a, poses_a, light_a), (n_b, ids_b, poses_b, light_b) = worlds
    assert n_a == n_b == len(ids_a)
    assert ids_a == ids_b and light_a == light_b
    for (pa, oa), (pb, ob) in zip(poses_a, poses_b):
        assert np.allclose(pa, pb, atol=1e-9) and np.allclose(oa, ob, atol=1e-9)


def test_body_roles_match_the_spec(hospital, client, tmp_path):
    built = build_world(client, hospital, 0, texture_dir=tmp_path)
    decals = sum(len(w.decals) for w in hospital.walls)
    ceiling = 1 if hospital.floor.ceiling_height_m else 0
    assert len(built.wall_ids) == len(hospital.walls)
    assert len(built.prop_ids) == len(hospital.props)
    assert len(built.scenery_ids) == decals + ceiling
    assert len(built.floor_ids) == 1
    assert set(built.obstacle_ids) >= set(built.wall_ids) | set(built.prop_ids)
    assert not set(built.floor_ids) & set(built.obstacle_ids)
    assert built.body_count == p.getNumBodies(physicsClientId=client)
    kwargs = built.render_light
    assert set(kwargs) == {"lightDirection", "lightColor", "lightAmbientCoeff", "lightDiffuseCoeff",
                           "lightSpecularCoeff", "shadow"}


def test_walls_and_props_stand_where_the_spec_puts_them(hospital, client, tmp_path):
    built = build_world(client, hospital, 0, texture_dir=tmp_path)
    for wall, body in zip(hospital.walls, built.wall_ids):
        lo, hi = p.getAABB(body, physicsClientId=client)
        corners = wall_footprint(wall).corners()
        assert np.allclose(lo[:2], corners.min(axis=0), atol=0.01)
        assert np.allclose(hi[:2], corners.max(axis=0), atol=0.01)
        assert abs(lo[2]) < 0.01 and abs(hi[2] - wall.height_m) < 0.01
    for prop, body in zip(hospital.props, built.prop_ids):
        boxes = [p.getAABB(body, link, physicsClientId=client)
                 for link in range(-1, p.getNumJoints(body, physicsClientId=client))]
        lo = np.min([b[0] for b in boxes], axis=0)
        hi = np.max([b[1] for b in boxes], axis=0)
        pts = np.concatenate([fp.corners() for fp in prop_footprints(prop)])
        assert np.allclose(lo[:2], pts.min(axis=0), atol=0.03), prop.name
        assert np.allclose(hi[:2], pts.max(axis=0), atol=0.03), prop.name
        assert lo[2] > -0.01


def test_model_props_get_their_declared_footprint(client, tmp_path):
    office = load_world("office")
    built = build_world(client, office, 0, texture_dir=tmp_path)
    models = [(i, prop) for i, prop in enumerate(office.props) if prop.model is not None]
    assert models, "the office uses pybullet_data models"
    blockers = [b for b in built.obstacle_ids if b not in built.wall_ids and b not in built.prop_ids]
    assert len(blockers) == len(models)
    for (i, prop), blocker in zip(models, blockers):
        lo, hi = p.getAABB(built.prop_ids[i], 0 if p.getNumJoints(built.prop_ids[i], physicsClientId=client)
                           else -1, physicsClientId=client)
        size = np.asarray(hi[:2]) - np.asarray(lo[:2])
        assert np.allclose(sorted(size), sorted(prop.footprint_m), atol=0.05), prop.name
        blo, bhi = p.getAABB(blocker, physicsClientId=client)
        assert np.allclose(np.asarray(bhi[:2]) - np.asarray(blo[:2]), prop.footprint_m, atol=0.01)


def test_appearance_seed_moves_props_and_light_but_not_walls(hospital, tmp_path):
    states = {}
    for seed in (0, 5):
        cid = p.connect(p.DIRECT)
        try:
            built = build_world(cid, hospital, seed, texture_dir=tmp_path)
            states[seed] = (_poses(cid, built.wall_ids), _poses(cid, built.prop_ids), built.render_light)
        finally:
            p.disconnect(cid)
    walls0, props0, light0 = states[0]
    walls5, props5, light5 = states[5]
    assert light0 != light5
    assert all(np.allclose(a[0], b[0]) and np.allclose(a[1], b[1]) for a, b in zip(walls0, walls5))
    moved = [prop.name for prop, a, b in zip(hospital.props, props0, props5)
             if not (np.allclose(a[0], b[0], atol=1e-6) and np.allclose(a[1], b[1], atol=1e-6))]
    assert moved and all(hospital.props[[q.name for q in hospital.props].index(n)].movable for n in moved)
    assert light0["lightAmbientCoeff"] == hospital.light.ambient


def test_floor_carries_a_ball_at_height_zero(hospital, client, tmp_path):
    build_world(client, hospital, 0, texture_dir=tmp_path)
    p.setGravity(0, 0, -9.81, physicsClientId=client)
    ball = p.createMultiBody(1.0, p.createCollisionShape(p.GEOM_SPHERE, radius=0.1, physicsClientId=client),
                             -1, [3.0, 1.2, 0.5], physicsClientId=client)
    for _ in range(480):
        p.stepSimulation(physicsClientId=client)
    (x, y, z), _ = p.getBasePositionAndOrientation(ball, physicsClientId=client)
    assert abs(z - 0.1) < 0.01 and math.hypot(x - 3.0, y - 1.2) < 0.05


def _render(cid, built, eye, target, size=(160, 120)):
    w, h = size
    view = p.computeViewMatrix(eye, target, [0, 0, 1])
    proj = p.computeProjectionMatrixFOV(51.0, w / h, 0.05, 30.0)
    _, _, rgb, _, _ = p.getCameraImage(w, h, view, proj, renderer=p.ER_TINY_RENDERER, physicsClientId=cid,
                                       **built.render_light)
    return np.reshape(np.asarray(rgb, np.uint8), (h, w, 4))[:, :, :3]


def test_decal_shows_on_its_side_of_the_wall(client, tmp_path):
    sign = TextureSpec(kind="sign", seed=1, text="7", color=(0.1, 0.2, 0.9))
    plaster = TextureSpec(kind="plain", color=(0.9, 0.9, 0.9))
    spec = WorldSpec(
        name="decal", floor=FloorSpec(size_m=(6.0, 6.0), origin_m=(-3.0, -3.0)),
        walls=(WallSpec(start=(-2.0, 0.0), end=(2.0, 0.0), texture=plaster,
                        decals=(DecalSpec(texture=sign, at_m=2.0, side="right", size_m=(1.6, 1.2), bottom_m=0.2),)),),
        routes=RoutesSpec(walkthrough=((-1, -1), (1, -1), (0, -2), (-1, -1))))
    built = build_world(client, spec, 0, texture_dir=tmp_path)
    # "right" of a wall running +x is its south face
    front = _render(client, built, [0, -2.5, 0.8], [0, 0, 0.8])
    back = _render(client, built, [0, 2.5, 0.8], [0, 0, 0.8])
    centre = (slice(40, 80), slice(60, 100))
    blue_front = (front[centre][..., 2].astype(int) - front[centre][..., 0]).mean()
    blue_back = (back[centre][..., 2].astype(int) - back[centre][..., 0]).mean()
    assert blue_front > 60, "the sign must be visible from its side"
    assert abs(blue_back) < 10, "the other face shows only plaster"


def test_hospital_view_has_structure(hospital, client, tmp_path):
    built = build_world(client, hospital, 0, texture_dir=tmp_path)
    img = _render(client, built, [3.08, 1.2, 0.18], [4.08, 1.2, 0.18])
    assert img.std() > 20, "a corridor view must show walls, floor and things, not a flat colour"
    # the floor fills the bottom rows, walls and ceiling the top ones: they differ
    assert np.abs(img[:20].mean(axis=(0, 1)) - img[-20:].mean(axis=(0, 1))).max() > 5
