"""Map pictures: written, readable PNGs that show what they claim (loop closures in colour)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from descriptors.base import DescriptorIdentity
from maps.builder import MapBuilder
from maps.calibration import similarity_sample
from maps.config import MappingConfig, MapThresholds
from maps.graph import MapError
from maps.pictures import BACKGROUND_FADE, draw_map_picture, draw_similarity_picture
from maps.pipeline import build_map
from maps.store import load_map, save_map
from tests.map_synthetic import landmark_route, place_route

LOOP_RGB = (214, 39, 40)        # the loop-closure red
MARKER_RGB = (0, 229, 255)      # the loop-closure marker cyan in the similarity picture
PURPLE_RGB = (148, 103, 189)    # rejected look-alikes


def grey_thumb(k: int) -> np.ndarray:
    img = np.full((120, 160, 3), 90 + (k * 13) % 120, np.uint8)
    cv2.putText(img, str(k), (40, 80), cv2.FONT_HERSHEY_SIMPLEX, 1.8, (255, 255, 255), 3)
    return img


def read_png(path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, f"{path} is not a readable PNG"
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def pixels_mask(img: np.ndarray, rgb, tol: int = 30) -> np.ndarray:
    return np.all(np.abs(img.astype(int) - np.asarray(rgb, dtype=float)) < tol, axis=2)


def pixels_near(img: np.ndarray, rgb, tol: int = 30) -> int:
    return int(pixels_mask(img, rgb, tol).sum())


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


def _box_of(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.nonzero(mask)
    return rows.min(), rows.max(), cols.min(), cols.max()


def test_map_picture_draws_the_world_large_and_keeps_thumbnails_off_it(tmp_path, made):
    build, _ = made
    world_rgb = np.array([40, 170, 60])
    background = np.full((500, 700, 3), 255, np.uint8)          # white margin, as a legend panel
    background[50:450, 50:450] = world_rgb                        # the 8 m square's floor
    to_px = lambda x, y: (50 + 50 * x, 450 - 50 * y)             # noqa: E731
    blue = lambda k: np.tile(np.array([0, 0, 255], np.uint8), (120, 160, 1))   # noqa: E731
    img = read_png(draw_map_picture(build.topomap, tmp_path / "map.png", thumbnail=blue,
                                    background=background, world_to_pixel=to_px, max_thumbnails=8))
    faded = BACKGROUND_FADE * 255 + (1 - BACKGROUND_FADE) * world_rgb
    floor = pixels_mask(img, faded, tol=12)
    r0, r1, c0, c1 = _box_of(floor)
    assert (r1 - r0) * (c1 - c0) > 0.4 * img.shape[0] * img.shape[1], "the world must fill the picture"
    thumbs = pixels_mask(img, (0, 0, 255), tol=12)
    assert thumbs.sum() > 8 * 1500, "eight thumbnails are drawn"
    tr, _, _, _ = _box_of(thumbs)
    assert tr > r1, "thumbnails sit in a strip below the world, not on it"


def test_rejected_look_alikes_are_drawn_in_purple(tmp_path):
    x = place_route(list(range(17)) + [0, 1, 2, 3, 4, 5], frames_per_leg=8, twins={12: (3, 0.97), 13: (4, 0.97)})
    t = MapThresholds(T_add_new_node=0.8, T_interval=1, T_add_distance=0.999, T_loop_closure=0.9, T_merge=0.9,
                   loop_min_gap_frames=20, loop_exclude_recent_nodes=2, T_loop_verify=0.8,
                   loop_verify_frames=16, loop_verify_hops=2)
    b = MapBuilder(t)
    b.add_frames(x)
    topo, log = b.finish()
    rejected = log.rejected_loop_events()
    assert rejected
    sim = read_png(draw_similarity_picture(similarity_sample(x), log, tmp_path / "sim.png"))
    assert pixels_near(sim, PURPLE_RGB, tol=20) > 100
    plain = read_png(draw_map_picture(topo, tmp_path / "plain.png"))
    marked = read_png(draw_map_picture(topo, tmp_path / "marked.png",
                                       rejected_loops=[(e.node_id, e.loop_candidate) for e in rejected]))
    assert pixels_near(marked, PURPLE_RGB, tol=20) > pixels_near(plain, PURPLE_RGB, tol=20) + 50
