"""The descriptor interface and the default offline backend, with the real packaged weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from skimage import data

from descriptors.base import Descriptor, DescriptorError, DescriptorIdentity
from descriptors.efficientnet_lite import load_efficientnet_lite0
from descriptors.efficientnet_lite_spec import INPUT_MEAN, INPUT_STD
from descriptors.factory import BACKENDS, descriptor_from_state, make_descriptor
from descriptors.preprocess import resize_rgb
from descriptors.vlad import VladVocabulary, cosine_kmeans, l2_normalise


@pytest.fixture(scope="module")
def photos() -> list[np.ndarray]:
    """Real photographs shipped with scikit-image, plus crops of them (different sizes)."""
    imgs = [data.chelsea(), data.astronaut(), data.coffee(), data.rocket(), data.immunohistochemistry()]
    imgs += [img[20:220, 30:330] for img in imgs[:3]]
    return imgs


@pytest.fixture(scope="module")
def fitted(photos):
    d = make_descriptor("effnet-vlad", clusters=8)
    d.fit(photos)
    return d


def test_packaged_weights_classify_a_real_cat():
    """Weights really loaded: the chelsea photograph is a cat (ImageNet classes 281-285)."""
    net = load_efficientnet_lite0()
    img = resize_rgb(data.chelsea(), 224, 224).astype(np.float32) / 255.0
    x = torch.from_numpy((img - np.float32(INPUT_MEAN)) / np.float32(INPUT_STD)).permute(2, 0, 1)[None]
    with torch.inference_mode():
        probs = torch.softmax(net(x.float()), dim=1)[0]
    top = int(probs.argmax())
    assert 281 <= top <= 285, f"class {top}"
    assert float(probs[281:286].sum()) > 0.5


def test_effnet_vlad_implements_the_protocol(fitted, photos):
    assert isinstance(fitted, Descriptor)
    x = fitted.describe(photos)
    assert x.shape == (len(photos), 8 * 192) and x.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(x, axis=1), 1.0, atol=1e-5)
    assert fitted.identity.dim == x.shape[1]
    assert len(fitted.identity.vocabulary_sha256) == 64


def test_thirds_share_the_full_view_pass_and_differ_from_each_other(fitted, photos):
    full = fitted.describe(photos[:3])
    th = fitted.describe_thirds(photos[:3])
    assert th.shape == (3, 4, full.shape[1])
    np.testing.assert_allclose(th[:, 0], full, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(th, axis=2), 1.0, atol=1e-5)
    # Left and right thirds of a photograph are different places; each resembles the full view.
    assert np.all(np.einsum("nd,nd->n", th[:, 1], th[:, 3]) < 0.95)
    assert np.all(np.einsum("nd,nd->n", th[:, 2], th[:, 0]) > np.einsum("nd,nd->n", th[:, 1], th[:, 3]))


def test_same_place_scores_higher_than_other_places(fitted, photos):
    """A crop of an image is more similar to its source than to any other photograph."""
    x = fitted.describe(photos)
    sims = x[5:8] @ x[:5].T
    assert list(sims.argmax(axis=1)) == [0, 1, 2]


def test_describe_is_deterministic_and_state_round_trips(fitted, photos):
    a = fitted.describe(photos[:2])
    assert np.array_equal(a, fitted.describe(photos[:2]))
    rebuilt = descriptor_from_state(fitted.state_dict())
    assert rebuilt.identity == fitted.identity
    np.testing.assert_array_equal(rebuilt.describe(photos[:2]), a)


def test_identity_changes_with_settings_and_vocabulary(photos, fitted):
    other = make_descriptor("effnet-vlad", clusters=8, seed=1)
    other.fit(photos)
    assert other.identity.mismatch(fitted.identity) is not None
    assert "seed" in fitted.identity.mismatch(other.identity) or "settings" in fitted.identity.mismatch(other.identity)
    same = DescriptorIdentity.from_dict(fitted.identity.to_dict())
    assert same.mismatch(fitted.identity) is None


def test_load_state_refuses_other_backend_or_settings(fitted):
    state = fitted.state_dict()
    with pytest.raises(DescriptorError, match="clusters|settings"):
        make_descriptor("effnet-vlad", clusters=16).load_state(state)
    with pytest.raises(DescriptorError, match="backend"):
        make_descriptor("tiny").load_state(state)
    with pytest.raises(DescriptorError, match="vocabulary"):
        make_descriptor("effnet-vlad", clusters=8).load_state({k: v for k, v in state.items() if k != "vlad_centres"})


def test_unfitted_vlad_says_what_to_do(photos):
    d = make_descriptor("effnet-vlad")
    assert d.needs_fit
    with pytest.raises(DescriptorError, match="not fitted"):
        d.describe(photos[:1])


@pytest.mark.parametrize("bad, match", [
    ([], "empty batch"),
    ([np.zeros((4, 4, 3), np.uint8)], "too small"),
    ([np.zeros((64, 64, 2), np.uint8)], "shape"),
    ([np.full((64, 64, 3), 2.0)], r"\[0, 1\]"),
    (["cat.jpg"], "numpy array"),
])
def test_bad_input_is_named(fitted, bad, match):
    with pytest.raises(DescriptorError, match=match):
        fitted.describe(bad)


def test_any_size_grey_and_float_images_are_accepted(fitted):
    grey = data.camera()                       # (512, 512) uint8
    as_float = data.chelsea().astype(np.float32) / 255.0
    x = fitted.describe([grey, as_float])
    assert x.shape[0] == 2 and np.all(np.isfinite(x))


def test_factory_names_unknown_backends_and_settings():
    with pytest.raises(DescriptorError, match="available: .*effnet-vlad"):
        make_descriptor("netvlad")
    with pytest.raises(DescriptorError, match="no setting 'block'"):
        make_descriptor("effnet-vlad", block=3)
    assert {"effnet-vlad", "effnet-gap", "anyloc-dinov2", "tiny"} <= set(BACKENDS)


def test_global_pooling_baseline_and_tiny_stand_in(photos):
    for name in ("effnet-gap", "tiny"):
        d = make_descriptor(name)
        assert not d.needs_fit
        th = d.describe_thirds(photos[:2])
        full = d.describe(photos[:2])
        assert th.shape == (2, 4, full.shape[1])
        np.testing.assert_allclose(th[:, 0], full, atol=1e-6)
        np.testing.assert_allclose(np.linalg.norm(full, axis=1), 1.0, atol=1e-5)
        assert descriptor_from_state(d.state_dict()).identity == d.identity


def test_cosine_kmeans_finds_separated_clusters_and_is_seeded():
    rng = np.random.default_rng(3)
    centres = l2_normalise(rng.normal(size=(4, 16)))
    x = l2_normalise(np.repeat(centres, 50, axis=0) + 0.05 * rng.normal(size=(200, 16)))
    found = cosine_kmeans(x, 4, seed=0)
    assert np.all((found @ centres.T).max(axis=0) > 0.98)
    np.testing.assert_array_equal(found, cosine_kmeans(x, 4, seed=0))
    with pytest.raises(DescriptorError, match="at least 4"):
        cosine_kmeans(x[:3], 4, seed=0)


def test_vlad_columns_ranges_equal_aggregating_the_cropped_map():
    rng = np.random.default_rng(0)
    maps = l2_normalise(rng.normal(size=(2, 5, 9, 8)).astype(np.float32))
    v = VladVocabulary(num_clusters=4, seed=0)
    v.fit(maps)
    parts = v.aggregate(maps, [(0, 3), (3, 9)])
    np.testing.assert_allclose(parts[:, 0], v.aggregate(maps[:, :, 0:3]), atol=1e-6)
    np.testing.assert_allclose(parts[:, 1], v.aggregate(maps[:, :, 3:9]), atol=1e-6)
