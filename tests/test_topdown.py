"""The top-down picture of a world: size, transform, content, overlays and the CLI."""

import math

import cv2
import numpy as np
import pytest

from sim import topdown
from sim.topdown import ROUTE_COLORS, WALKTHROUGH_COLOR, WALL_COLOR, render_topdown
from sim.worlds import load_world


@pytest.fixture(scope="module")
def hospital():
    return load_world("hospital")


@pytest.fixture(scope="module")
def picture(hospital):
    return render_topdown(hospital, px_per_m=40.0)


def test_size_follows_the_floor_and_the_scale(hospital, picture):
    (sx, sy) = hospital.floor.size_m
    h, w, c = picture.image.shape
    assert c == 3 and picture.image.dtype == np.uint8
    map_w = math.ceil((sx + 2 * topdown._MARGIN_M) * 40.0)
    assert w == map_w + topdown._LEGEND_W_PX
    assert h == max(math.ceil((sy + 2 * topdown._MARGIN_M) * 40.0), 460)
    bigger = render_topdown(hospital, px_per_m=60.0)
    assert bigger.image.shape[1] - topdown._LEGEND_W_PX == math.ceil((sx + 2 * topdown._MARGIN_M) * 60.0)


def test_world_to_pixel_transform(picture):
    (fx, fy) = (0.0, 0.0)
    c0, r0 = picture.to_pixel(fx, fy)
    c1, r1 = picture.to_pixel(fx + 1.0, fy + 2.0)
    assert (c1 - c0, r0 - r1) == (40, 80), "1 m is px_per_m pixels; y grows upwards"
    assert picture.to_pixel(picture.x_min_m, picture.y_max_m) == (0, 0)
    assert np.array_equal(picture.to_pixels([(fx, fy), (fx + 1.0, fy + 2.0)]), [[c0, r0], [c1, r1]])


def test_walls_routes_and_legend_are_drawn(hospital, picture):
    img = picture.image
    # the middle of every wall is wall-coloured, unless a decal stripe covers that spot
    wall_hits = 0
    for wall in hospital.walls:
        mid = ((wall.start[0] + wall.end[0]) / 2, (wall.start[1] + wall.end[1]) / 2)
        c, r = picture.to_pixel(*mid)
        wall_hits += int(np.abs(img[r, c].astype(int) - WALL_COLOR).max() <= 10)
    assert wall_hits >= len(hospital.walls) - 3
    # each route's colour is present around the middle of its first leg, off the walkthrough line
    for i, route in enumerate(hospital.routes.evaluation.values()):
        (x0, y0), (x1, y1) = route.path[0], route.path[1]
        c, r = picture.to_pixel((x0 + x1) / 2, (y0 + y1) / 2)
        patch = img[r - 8:r + 9, c - 8:c + 9].reshape(-1, 3).astype(int)
        want = np.asarray(ROUTE_COLORS[i])
        assert (np.abs(patch - want).max(axis=1) < 60).any(), f"route {i} colour missing"
    # the walkthrough's blue is on the map, the legend panel has text on white
    assert (np.abs(img.reshape(-1, 3).astype(int) - WALKTHROUGH_COLOR).max(axis=1) < 30).sum() > 500
    legend = img[:, -topdown._LEGEND_W_PX:]
    assert (legend < 100).any() and (legend == 255).mean() > 0.5
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 200, "the picture must not be a few flat colours"


def test_appearance_seed_changes_the_props_in_the_picture(hospital, picture):
    moved = render_topdown(hospital, appearance_seed=5, px_per_m=40.0)
    diff = np.abs(moved.image.astype(int) - picture.image).max(axis=2)
    assert (diff > 0).sum() > 100


def test_overlay_helpers_and_save_png(picture, tmp_path):
    td = picture.copy()
    before = td.image.copy()
    td.draw_polyline([(3.0, 3.0), (5.0, 3.0), (5.0, 5.0)], (255, 0, 255), 3, arrow_every_m=1.0)
    td.draw_marker(6.0, 6.0, (0, 255, 255), label="node 7", shape="diamond", yaw_rad=0.5)
    c, r = td.to_pixel(4.0, 3.0)
    assert tuple(td.image[r, c]) == (255, 0, 255)
    assert (np.abs(td.image.astype(int) - before).max(axis=2) > 0).sum() > 300
    assert np.array_equal(picture.image, before), "copy() must not draw on the original"
    path = td.save_png(tmp_path / "sub" / "top.png")
    back = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
    assert np.array_equal(back, td.image)


def test_labels_at_the_same_spot_do_not_overlap(picture):
    td = picture.copy()
    td.draw_marker(10.0, 10.0, (255, 0, 0), label="first")
    td.draw_marker(10.0, 10.0, (255, 0, 0), label="second")
    (a, b) = td._label_boxes[-2:]
    assert a[3] <= b[1] or b[3] <= a[1]


def test_cli_checks_and_draws_a_world(tmp_path, capsys):
    out = tmp_path / "office.png"
    assert topdown.main(["office", "--out", str(out)]) == 0
    assert cv2.imread(str(out)) is not None
    assert "main" in capsys.readouterr().out
    assert topdown.main(["no_such_world"]) == 2
    assert "available" in capsys.readouterr().err
