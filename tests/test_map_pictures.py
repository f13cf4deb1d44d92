"""Map pictures: written, readable PNGs that show what they claim (loop closures in colour)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from maps.builder import MapBuilder, build_map
from maps.calibration import similarity_sample
from maps.config import MappingConfig
from maps.graph import MapError
from maps.pictures import draw_map_picture, draw_similarity_picture
from maps.store import load_map, save_map
from robot.descriptors.base import DescriptorIdentity
from tests.map_synthetic import landmark_route

LOOP_RGB = (214, 39, 40)        # the loop-closure red
MARKER_RGB = (0, 229, 255)      # the loop-closure marker cyan in the similarity picture


def grey_thumb(k: int) -> np.ndarray:
    img = np.full((120, 160, 3), 90 + (k * 13) % 120, np.uint8)
    cv2.putText(img, str(k), (40, 80), cv2.FONT_HERSHEY_SIMPLEX, 1.8, (255, 255, 255), 3)
    return img


def read_png(path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, f"{path} is not a readable PNG"
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def pixels_near(img: np.ndarray, rgb, tol: int = 30) -> int:
    return int(np.all(np.abs(img.astype(int) - np.array(rgb)) < tol, axis=2).sum())


@pytest.fixture(scope="module")
def made():
    route = landmark_route(seed=0)
    return build_map(route.descriptors, MappingConfig(sparsity=0.5), true_poses=route.poses,
                     stamps_s=route.stamps_s), route


def test_map_picture_over_a_world_picture(tmp_path, made):
    build, _ = made
    background = np.full((400, 400, 3), 235, np.uint8)
    cv2.rectangle(background, (40, 40), (360, 360), (120, 120, 120), 2)
    to_px = lambda x, y: (40 + 40 * x, 360 - 40 * y)      # noqa: E731  8 m square -> 320 px
    out = draw_map_picture(build.topomap, tmp_path / "map.png", thumbnail=grey_thumb,
                           background=background, world_to_pixel=to_px, title="test")
    img = read_png(out)
    assert img.shape[0] >= 800 and img.shape[1] >= 800
    assert img.std() > 20
    assert build.topomap.loop_closures()
    assert pixels_near(img, LOOP_RGB) > 100, "the loop closure must be drawn in red"


def test_map_picture_without_loops_has_no_red(tmp_path, made):
    build, route = made
    b = MapBuilder(build.thresholds.__class__(**{**build.thresholds.to_dict(), "T_loop_closure": 1.0}))
    b.add_frames(route.descriptors)
    topo, _ = b.finish()
    assert not topo.loop_closures()
    img = read_png(draw_map_picture(topo, tmp_path / "ring.png", thumbnail=grey_thumb))
    assert pixels_near(img, LOOP_RGB) == 0
    assert img.std() > 20


def test_map_picture_in_metres_from_a_loaded_map(tmp_path, made):
    build, _ = made
    ident = DescriptorIdentity(backend="test", dim=build.topomap.dim)
    path = save_map(tmp_path / "m", build.topomap, identity=ident, descriptor_state={},
                    thresholds=build.thresholds,
                    thumbnails={n: grey_thumb(n) for n in build.topomap.node_ids.tolist()})
    loaded = load_map(path, expected_identity=ident)
    out = draw_map_picture(loaded.topomap, tmp_path / "metres.png", thumbnail=loaded.thumbnail)
    img = read_png(out)
    assert pixels_near(img, LOOP_RGB) > 100
    with pytest.raises(MapError, match="world_to_pixel"):
        draw_map_picture(loaded.topomap, tmp_path / "x.png", background=np.zeros((10, 10, 3), np.uint8))


def test_similarity_picture_marks_keyframes_and_loop_closures(tmp_path, made):
    build, route = made
    sample = similarity_sample(route.descriptors, max_frames=300)
    out = draw_similarity_picture(sample, build.log, tmp_path / "sim.png", merged=build.merge.merged, title="t")
    img = read_png(out)
    assert img.shape[0] > img.shape[1] >= 900
    assert build.log.loop_closure_events()
    assert pixels_near(img, MARKER_RGB, tol=25) > 50
    assert pixels_near(img, (44, 160, 44), tol=25) > 50            # green keyframe dots / node lines
