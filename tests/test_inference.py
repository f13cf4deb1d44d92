"""The descriptor network's two engines (descriptors.inference): ONNX Runtime and torch give the
same descriptors, the exported graph is cached and rebuilt when it must be, and the engine is no
part of the descriptor's identity (a map made with one navigates with the other)."""

import os

import numpy as np
import pytest
import torch
from skimage import data

import descriptors.effnet_extractor as effnet_extractor
from descriptors.base import DescriptorError
from descriptors.factory import make_descriptor
from descriptors.inference import cache_dir, check_engine, default_engine, set_threads, threads


@pytest.fixture(scope="module")
def photos():
    """Real photographs (scikit-image's samples), crops of them, and one upside down."""
    imgs = [data.chelsea(), data.astronaut(), data.coffee(), data.rocket()]
    return imgs + [imgs[1][30:330, 60:460], imgs[2][::-1]]


@pytest.fixture(scope="module")
def pair(photos):
    """The default descriptor fitted with torch, and the same state in an ONNX Runtime one."""
    by_torch = make_descriptor("effnet-vlad", engine="torch")
    by_torch.fit(photos)
    by_ort = make_descriptor("effnet-vlad", engine="onnxruntime")
    by_ort.load_state(by_torch.state_dict())
    return by_torch, by_ort


def test_onnxruntime_is_the_default_engine():
    assert default_engine() == "onnxruntime" == check_engine(None)
    assert make_descriptor("effnet-vlad").extractor.engine == "onnxruntime"


def test_both_engines_give_the_same_descriptors_full_view_and_thirds(pair, photos):
    by_torch, by_ort = pair
    a, b = by_torch.describe_thirds(photos), by_ort.describe_thirds(photos)     # (N, 4, D)
    assert a.shape == b.shape == (len(photos), 4, by_torch.identity.dim)
    cosines = np.sum(a * b, axis=2)
    assert cosines.min() >= 0.9999, cosines.min()
    local_a = by_torch.local_features(photos[:2])
    local_b = by_ort.local_features(photos[:2])
    assert np.abs(local_a - local_b).max() < 1e-4


def test_the_engine_is_no_part_of_the_identity(pair):
    by_torch, by_ort = pair
    assert by_torch.identity == by_ort.identity
    assert "engine" not in by_ort.identity.settings and "threads" not in by_ort.identity.settings
    again = make_descriptor("effnet-vlad", engine="torch")
    again.load_state(by_ort.state_dict())              # a map made with ONNX Runtime, navigated with torch
    assert again.identity == by_ort.identity


def test_the_graph_is_exported_once_and_rebuilt_when_blocks_size_or_weights_change(monkeypatch, tmp_path, photos):
    monkeypatch.setenv("LIMO_TOPONAV_CACHE", str(tmp_path / "cache"))
    exports = []
    real = effnet_extractor.export_torch_module
    monkeypatch.setattr(effnet_extractor, "export_torch_module", lambda *a: (exports.append(a[-1]), real(*a)))
    frame = [photos[0]]
    first = make_descriptor("effnet-gap", blocks=[13]).extractor
    first(frame)
    assert [p.parent for p in exports] == [cache_dir() / "onnx"] and exports[0].is_file()
    stamp = os.stat(exports[0]).st_mtime_ns
    make_descriptor("effnet-gap", blocks=[13]).extractor(frame)            # reused
    assert len(exports) == 1 and os.stat(exports[0]).st_mtime_ns == stamp
    make_descriptor("effnet-gap", blocks=[12]).extractor(frame)
    make_descriptor("effnet-gap", blocks=[13], input_width_px=224, input_height_px=160).extractor(frame)
    state = torch.load(first.weights_path, weights_only=True)
    state["_conv_stem.weight"] = state["_conv_stem.weight"] * 1.01         # other weights, same file name
    other = tmp_path / "w" / first.weights_path.name
    other.parent.mkdir()
    torch.save(state, other)
    retrained = make_descriptor("effnet-gap", blocks=[13], weights=str(other)).extractor
    assert not np.allclose(retrained(frame), first(frame), atol=1e-4)
    assert len({p.name for p in exports}) == 4                              # one graph per (weights, blocks, size)


def test_a_damaged_cached_graph_is_exported_again(monkeypatch, tmp_path, photos):
    monkeypatch.setenv("LIMO_TOPONAV_CACHE", str(tmp_path / "cache"))
    extractor = make_descriptor("effnet-gap").extractor
    want = extractor([photos[0]])
    path = extractor.onnx_net().path
    path.write_bytes(b"not an onnx graph")
    fresh = make_descriptor("effnet-gap").extractor
    np.testing.assert_allclose(fresh([photos[0]]), want, atol=1e-6)
    assert path.stat().st_size > 1_000_000


def test_threads_and_providers_are_settings(monkeypatch):
    session = make_descriptor("effnet-gap", threads=1).extractor.onnx_net().session()
    assert session.get_session_options().intra_op_num_threads == 1
    set_threads(2)
    try:
        assert threads() == 2
        assert make_descriptor("effnet-gap").extractor.onnx_net().session().get_session_options().intra_op_num_threads == 2
    finally:
        set_threads(None)
    gpu_first = make_descriptor("effnet-gap", providers=["CUDAExecutionProvider", "CPUExecutionProvider"])
    assert gpu_first.extractor.onnx_net().session().get_providers()[-1] == "CPUExecutionProvider"
    with pytest.raises(DescriptorError, match="NoSuchExecutionProvider"):
        make_descriptor("effnet-gap", providers=["NoSuchExecutionProvider"]).extractor.onnx_net().session()


@pytest.mark.parametrize("settings, match", [
    ({"engine": "tensorflow"}, "engine must be one of onnxruntime, torch"),
    ({"threads": 0}, "threads"),
    ({"providers": "CPUExecutionProvider"}, "providers"),
])
def test_bad_engine_settings_are_named(settings, match):
    with pytest.raises(DescriptorError, match=match):
        make_descriptor("effnet-vlad", **settings)


def test_int8_is_part_of_the_identity_and_stays_close_to_fp32(pair, photos):
    by_torch, _ = pair
    int8 = make_descriptor("effnet-vlad", precision="int8")
    assert int8.identity.settings["precision"] == "int8" and "precision" not in by_torch.identity.settings
    with pytest.raises(DescriptorError, match="precision"):
        int8.load_state(by_torch.state_dict())                # an fp32 map is not an int8 one
    int8.fit(photos)
    a = int8.describe_thirds(photos)
    again = make_descriptor("effnet-vlad", precision="int8")
    again.load_state(int8.state_dict())
    np.testing.assert_array_equal(again.describe_thirds(photos), a)       # deterministic
    fp32 = make_descriptor("effnet-vlad")
    fp32.load_state({**int8.state_dict(), "settings": fp32.settings})   # the same vocabulary, fp32 features
    cosines = np.sum(fp32.describe_thirds(photos) * a, axis=2)
    assert 0.7 < cosines.min() < 0.9999                     # close, but not the same features
    with pytest.raises(DescriptorError, match="ONNX Runtime only"):
        make_descriptor("effnet-vlad", engine="torch", precision="int8")


def test_a_map_made_with_one_engine_navigates_with_the_other(pair, photos, tmp_path):
    """The map folder records the identity and state of the ONNX Runtime descriptor; the torch
    descriptor attaches to it and describes a view as the map's nodes were described."""
    from maps.config import MappingConfig
    from maps.graph import TopoMap
    from maps.pipeline import build_map
    from maps.store import load_map, save_map
    from maps.thumbnails import make_thumbnail
    from robot.episode.setup import attach_descriptor
    from tests.map_synthetic import landmark_route

    _, by_ort = pair
    nodes = by_ort.describe(photos)
    topomap = TopoMap(nodes.shape[1])
    for k, d in enumerate(nodes):
        topomap.add_node(d, keyframe_index=k, stamp_s=float(k))
    for k in range(len(nodes) - 1):
        topomap.add_arc(k, k + 1, 1.0, "sequential")
    thresholds = build_map(landmark_route(seed=0, stand_frames=0).descriptors, MappingConfig()).thresholds
    path = save_map(tmp_path / "m", topomap, identity=by_ort.identity, descriptor_state=by_ort.state_dict(),
                    thresholds=thresholds, thumbnails={k: make_thumbnail(p) for k, p in enumerate(photos)})
    loaded = load_map(path)
    by_torch = attach_descriptor(loaded, make_descriptor("effnet-vlad", engine="torch"))
    view = by_torch.describe([photos[2]])[0]
    assert int(loaded.topomap.node_ids[int(np.argmax(loaded.topomap.similarities(view)))]) == 2
    assert float(loaded.topomap.similarities(view)[2]) > 0.9999
