"""Column profiles and the shift that aligns two views (descriptors/columns.py)."""

from dataclasses import replace

import numpy as np
import pytest

from descriptors.columns import column_profiles, column_shift
from descriptors.tiny import TinyDescriptor
from descriptors.vlad import l2_normalise

W, H, C = 12, 4, 16


def _scene(seed: int, width: int) -> np.ndarray:
    """(H, width, C) unit features of a panorama."""
    return l2_normalise(np.random.default_rng(seed).normal(size=(H, width, C)))


def _view(panorama: np.ndarray, left: int) -> np.ndarray:
    return panorama[None, :, left:left + W]


@pytest.mark.parametrize("moved", [-3, -1, 0, 2, 4])
def test_a_view_turned_by_whole_columns_is_found_at_that_shift(moved):
    pano = _scene(0, 3 * W)
    reference = column_profiles(_view(pano, W))[0]
    # the query looks `moved` columns further right in the panorama (the robot turned right):
    # it sees the reference's content further left, and must turn left (positive) to face it
    query = column_profiles(_view(pano, W + moved))[0]
    bearing, score = column_shift(query, reference)
    assert bearing == pytest.approx(moved / W, abs=0.1 / W)      # refined a little by the parabola
    assert score == pytest.approx(1.0, abs=1e-5)


def test_a_shift_between_columns_is_found_between_them():
    pano = _scene(1, 3 * W)
    reference = column_profiles(_view(pano, W))[0]
    halfway = l2_normalise(pano[:, W:2 * W] + pano[:, W + 1:2 * W + 1])     # half a column further right
    bearing, _ = column_shift(column_profiles(halfway[None])[0], reference)
    assert 0.3 / W < bearing < 0.7 / W


def test_unrelated_views_score_below_the_same_place_and_bad_shapes_are_refused():
    same = column_shift(column_profiles(_view(_scene(2, W), 0))[0], column_profiles(_view(_scene(2, W), 0))[0])
    other = column_shift(column_profiles(_view(_scene(3, W), 0))[0], column_profiles(_view(_scene(4, W), 0))[0])
    assert other[1] < same[1] - 0.5
    with pytest.raises(ValueError, match="one shape"):
        column_shift(np.ones((W, C)), np.ones((W + 1, C)))
    with pytest.raises(ValueError, match=r"\(N, H, W, C\)"):
        column_profiles(np.ones((W, C)))


def test_the_tiny_descriptor_gives_columns_that_follow_a_turn():
    rng = np.random.default_rng(5)
    wide = (rng.random((60, 240, 3)) * 255).astype(np.uint8)
    wide = np.repeat(np.repeat(wide[::6, ::6], 6, axis=0), 6, axis=1)       # blocks survive shrinking
    tiny = TinyDescriptor(width_px=24, height_px=18)
    ref_img, turned = wide[:, 60:180], wide[:, 80:200]          # a sixth of the view further right
    thirds, cols = tiny.describe_with_columns([ref_img, turned])
    assert np.array_equal(thirds, tiny.describe_thirds([ref_img, turned])) and cols.shape[:2] == (2, 24)
    bearing, _ = column_shift(cols[1], cols[0])
    assert bearing == pytest.approx(20 / 120, abs=0.03)


class _CellColours:
    """A dense extractor for tests: the mean colour of 6 x 10 cells, with products, unit length."""

    feature_dim = 7
    settings: dict = {}

    def __call__(self, images: np.ndarray) -> np.ndarray:
        x = np.asarray(images, dtype=np.float32) / 255.0
        n, h, w, _ = x.shape
        cells = x[:, :h - h % 6, :w - w % 10].reshape(n, 6, h // 6, 10, w // 10, 3).mean(axis=(2, 4))
        r, g, b = cells[..., 0], cells[..., 1], cells[..., 2]
        return l2_normalise(np.stack([r, g, b, r * g, g * b, r * b, r - b + 1.0], axis=-1))


def test_dense_descriptors_give_their_thirds_and_columns_from_one_pass():
    from descriptors.dense import DenseMeanPool, DenseVlad

    images = [(np.random.default_rng(k).random((60, 100, 3)) * 255).astype(np.uint8) for k in range(4)]
    vlad = DenseVlad("cells", _CellColours(), num_clusters=2)
    vlad.fit(images)
    for descriptor in (vlad, DenseMeanPool("cells", _CellColours())):
        thirds, columns = descriptor.describe_with_columns(images)
        assert np.allclose(thirds, descriptor.describe_thirds(images))
        assert np.allclose(columns, column_profiles(descriptor.local_features(images)))
        assert columns.shape == (4, 10, 7)


def test_a_map_without_column_profiles_is_steered_by_the_thirds_with_a_note():
    from pathlib import Path
    from types import SimpleNamespace

    from controllers.config import BearingConfig, NavigationConfig
    from robot.episode.setup import configure_bearing

    on = NavigationConfig(bearing=BearingConfig(enabled=True))
    old = SimpleNamespace(path=Path("maps/old"), columns=None)
    used, note = configure_bearing(old, on)
    assert not used.bearing.enabled and used == replace(on, bearing=replace(on.bearing, enabled=False))
    assert "maps/old has no column profiles" in note and "rebuild" in note
    new = SimpleNamespace(path=Path("maps/new"), columns=np.zeros((3, 10, 4)))
    assert configure_bearing(new, on) == (on, None)
    off = NavigationConfig(bearing=BearingConfig(enabled=False))
    assert configure_bearing(old, off) == (off, None)
