"""Camera image size and horizontal field of view, checked against the pinhole model."""

import math

import numpy as np
import pybullet as p
import pybullet_data
import pytest

from core.hal import Pose2D
from sim.camera import Camera, check_light
from sim.config import CameraError, CameraSpec, SimConfig, vertical_fov_deg
from sim.hal import SimLimo

DISTANCE_M = 3.0       # the pole's distance from the lens


def _add_pole(client_id: int, bearing_rad: float, lens_xy=(0.084, 0.0)) -> int:
    """A thin, tall, pure-red box DISTANCE_M from the lens at ``bearing_rad`` (left positive)."""
    x = lens_xy[0] + DISTANCE_M * math.cos(bearing_rad)
    y = lens_xy[1] + DISTANCE_M * math.sin(bearing_rad)
    half = [0.01, 0.01, 1.0]
    col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client_id)
    vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[1, 0, 0, 1], physicsClientId=client_id)
    return p.createMultiBody(0, col, vis, basePosition=[x, y, 1.0], physicsClientId=client_id)


def _red_columns(rgb: np.ndarray) -> np.ndarray:
    r, g, b = (rgb[:, :, i].astype(int) for i in range(3))
    red = (r > 120) & (g < 60) & (b < 60)
    return np.flatnonzero(red.any(axis=0))


@pytest.mark.parametrize("hfov_deg,width,height", [(65.0, 320, 240), (90.0, 160, 90), (50.0, 128, 128)])
def test_image_size_and_pole_column(hfov_deg, width, height):
    spec = CameraSpec(hfov_deg=hfov_deg, width_px=width, height_px=height)
    bearing = math.radians(0.6 * hfov_deg / 2)
    with SimLimo(SimConfig(hfov_deg=hfov_deg, width_px=width, height_px=height), start=Pose2D(0, 0, 0)) as base:
        _add_pole(base.client_id, bearing)
        rgb = base.read().rgb
    assert rgb.shape == (height, width, 3) and rgb.dtype == np.uint8
    cols = _red_columns(rgb)
    assert cols.size > 0, "the pole is not in the image"
    predicted = spec.column_of_bearing(bearing)
    assert abs(cols.mean() - predicted) < 1.5, f"pole at column {cols.mean():.1f}, pinhole predicts {predicted:.1f}"


@pytest.mark.parametrize("hfov_deg", [65.0, 80.0])
def test_horizontal_fov_edges(hfov_deg):
    """Poles just inside the half-FOV on both sides appear at the image edges; poles just outside do not."""
    margin = math.radians(2.0)
    half = math.radians(hfov_deg) / 2
    config = SimConfig(hfov_deg=hfov_deg, width_px=320, height_px=240)
    for bearing, visible in ((half - margin, True), (-(half - margin), True), (half + margin, False), (-(half + margin), False)):
        with SimLimo(config) as base:
            _add_pole(base.client_id, bearing)
            cols = _red_columns(base.read().rgb)
        assert (cols.size > 0) == visible, f"pole at {math.degrees(bearing):.1f} deg: visible={cols.size > 0}"
        if visible:   # near the edge on its own side (left bearing -> left edge)
            edge = cols.min() if bearing > 0 else 320 - 1 - cols.max()
            assert edge < 25


def test_vertical_fov_follows_aspect_ratio():
    assert vertical_fov_deg(65.0, 320, 240) == pytest.approx(2 * math.degrees(math.atan(math.tan(math.radians(32.5)) * 0.75)))
    assert vertical_fov_deg(90.0, 100, 100) == pytest.approx(90.0)


def test_camera_is_level_at_its_height():
    """The horizon sits on the middle row: a pole top at lens height projects to the image centre row."""
    with SimLimo(SimConfig(width_px=160, height_px=120)) as base:
        half = [0.01, 0.3, 0.18 / 2]      # a wide red board whose top edge is exactly at lens height
        cid = base.client_id
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=cid)
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[1, 0, 0, 1], physicsClientId=cid)
        p.createMultiBody(0, col, vis, basePosition=[2.0, 0, 0.09], physicsClientId=cid)
        rgb = base.read().rgb
    r, g, b = (rgb[:, :, i].astype(int) for i in range(3))
    rows = np.flatnonzero(((r > 120) & (g < 60) & (b < 60)).any(axis=1))
    assert abs(rows.min() - 59.5) <= 1.0


def test_bad_settings_name_the_field():
    with pytest.raises(CameraError, match="hfov_deg"):
        CameraSpec(hfov_deg=0.0)
    with pytest.raises(CameraError, match="width_px"):
        CameraSpec(width_px=3)
    with pytest.raises(CameraError, match="lightPosition"):
        check_light({"lightPosition": [0, 0, 1]})


def test_render_light_changes_the_picture():
    """The world's light keywords reach getCameraImage (a low light darkens the floor)."""
    cid = p.connect(p.DIRECT)
    try:
        p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=cid)
        p.loadURDF("plane.urdf", physicsClientId=cid)
        camera = Camera(CameraSpec(width_px=80, height_px=60), base_height_m=0.045)
        pose = dict(base_position=(0.0, 0.0, 0.045), base_orientation=(0.0, 0.0, 0.0, 1.0))
        bright = camera.render(cid, **pose)
        dim = camera.render(cid, **pose, lightDirection=[0, 0, 1], lightAmbientCoeff=0.1, lightDiffuseCoeff=0.2,
                            lightSpecularCoeff=0.0, lightColor=[0.5, 0.5, 0.5], shadow=0)
    finally:
        p.disconnect(physicsClientId=cid)
    assert bright.shape == dim.shape == (60, 80, 3)
    floor_rows = slice(40, 60)
    assert dim[floor_rows].mean() < bright[floor_rows].mean() - 20
