"""Map folders: round trip, refusal of damaged or mismatched folders, crash-safe saving."""

from __future__ import annotations

import functools
import hashlib
import io
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

import core.atomic as atomic
import maps.store as store
from descriptors.base import DescriptorIdentity
from maps.calibration import calibrate, similarity_sample
from maps.config import MappingConfig
from maps.graph import MapError
from maps.pipeline import build_map
from maps.store import load_map, map_size, save_map
from maps.thumbnails import encode_thumbnail, make_thumbnail
from tests.map_synthetic import landmark_route

IDENTITY = DescriptorIdentity(backend="test-projection", settings={"layer": 10, "clusters": 4},
                              vocabulary_sha256="ab" * 32, dim=256)


@functools.lru_cache(maxsize=None)
def frame_image(k: int) -> np.ndarray:
    """A 480x640 RGB picture that differs per node (text and a gradient)."""
    img = np.zeros((480, 640, 3), np.uint8)
    img[..., 0] = np.linspace(0, 255, 640, dtype=np.uint8)[None, :]
    img[..., 2] = (37 * k) % 256
    cv2.putText(img, f"node {k}", (120, 260), cv2.FONT_HERSHEY_SIMPLEX, 3, (255, 255, 255), 6)
    return img


def build(sparsity: float):
    route = landmark_route(seed=0, stand_frames=0)
    made = build_map(route.descriptors, MappingConfig(sparsity=sparsity), true_poses=route.poses,
                     stamps_s=route.stamps_s)
    return made, route


@pytest.fixture(scope="module")
def made():
    return build(0.5)


def save(path: Path, made_route, **kw) -> Path:
    made, route = made_route
    state = {"centroids": np.arange(4 * 256, dtype=np.float32).reshape(4, 256), "layer": 10,
             "facet": "value", "scale": np.float64(0.5)}
    return save_map(path, made.topomap, identity=IDENTITY, descriptor_state=state,
                    thresholds=made.thresholds,
                    thumbnails={n: make_thumbnail(frame_image(n)) for n in made.raw_map.node_ids.tolist()},
                    calibration=made.calibration.to_dict() if made.calibration else None, log=made.log,
                    similarity=similarity_sample(route.descriptors, 200), merged=made.merge.merged,
                    extra={"source": "synthetic"}, **kw)


def test_round_trip_keeps_graph_descriptors_thresholds_and_state(tmp_path, made):
    path = save(tmp_path / "m", made)
    loaded = load_map(path, expected_identity=IDENTITY)
    a, b = made[0].topomap, loaded.topomap
    assert b.nodes() == a.nodes()
    assert b.arcs() == a.arcs()
    np.testing.assert_array_equal(b.descriptors, a.descriptors)
    np.testing.assert_array_equal(b.node_ids, a.node_ids)
    assert loaded.thresholds == made[0].thresholds
    assert loaded.identity == IDENTITY
    assert loaded.calibration == json.loads(json.dumps(made[0].calibration.to_dict()))
    np.testing.assert_array_equal(loaded.descriptor_state["centroids"],
                                  np.arange(4 * 256, dtype=np.float32).reshape(4, 256))
    assert loaded.descriptor_state["layer"] == 10 and loaded.descriptor_state["facet"] == "value"
    assert loaded.descriptor_state["scale"] == 0.5
    assert loaded.log.events == made[0].log.events
    np.testing.assert_array_equal(loaded.log.sim_to_node, made[0].log.sim_to_node)
    assert loaded.similarity.matrix.shape == (200, 200)
    assert loaded.extra == {"source": "synthetic"}
    assert loaded.merged == made[0].merge.merged
    thumb = loaded.thumbnail(int(a.node_ids[3]))
    assert thumb.shape == (120, 160, 3)
    want = make_thumbnail(frame_image(int(a.node_ids[3]))).astype(int)
    assert np.abs(thumb.astype(int) - want).mean() < 8            # JPEG, quality 80
    manifest = json.loads((path / "manifest.json").read_text())
    assert manifest["schema_version"] == store.SCHEMA_VERSION
    assert manifest["descriptor"] == IDENTITY.to_dict()
    assert manifest["vocabulary_sha256"] == IDENTITY.vocabulary_sha256
    assert all("true_pose" in n for n in manifest["nodes"])


def test_true_poses_are_stored_only_when_given_and_jpeg_thumbnails_are_kept(tmp_path):
    route = landmark_route(seed=1, stand_frames=0)
    made = build_map(route.descriptors, MappingConfig())
    jpegs = {n: encode_thumbnail(frame_image(n)) for n in made.topomap.node_ids.tolist()}
    path = save_map(tmp_path / "m", made.topomap, identity=IDENTITY, descriptor_state={},
                    thresholds=made.thresholds, thumbnails=jpegs)
    manifest = json.loads((path / "manifest.json").read_text())
    assert not any("true_pose" in n for n in manifest["nodes"])
    loaded = load_map(path)
    assert not loaded.topomap.has_true_poses and loaded.log is None
    node = int(made.topomap.node_ids[2])
    assert loaded.thumbnail_path(node).read_bytes() == jpegs[node]
    with pytest.raises(MapError, match="not a readable JPEG"):
        encode_thumbnail(b"not a jpeg")


def test_odometry_headings_round_trip_and_bad_ones_are_refused(tmp_path):
    route = landmark_route(seed=1, stand_frames=0)
    made = build_map(route.descriptors, MappingConfig())
    topomap = made.topomap
    assert topomap.odom_headings is None                    # none recorded (a video map)
    ids = topomap.node_ids.tolist()
    headings = {n: 0.1 * k - 3.0 for k, n in enumerate(ids)}
    for n in ids[:-1]:
        topomap.set_odom_yaw(n, headings[n])
    assert topomap.odom_headings is None                    # only when every node has one
    topomap.set_odom_yaw(ids[-1], headings[ids[-1]])
    assert topomap.odom_headings == headings
    with pytest.raises(MapError, match="finite"):
        topomap.set_odom_yaw(ids[0], float("nan"))
    jpegs = {n: encode_thumbnail(frame_image(n)) for n in ids}
    path = save_map(tmp_path / "m", topomap, identity=IDENTITY, descriptor_state={},
                    thresholds=made.thresholds, thumbnails=jpegs)
    assert load_map(path).topomap.odom_headings == headings
    manifest = json.loads((path / "manifest.json").read_text())
    manifest["nodes"][1]["odom_yaw_rad"] = "north"
    (path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(MapError, match=r"nodes\[1\]\.odom_yaw_rad: expected a finite number"):
        load_map(path)


@pytest.mark.parametrize("change, words", [
    ({"backend": "anyloc-dinov2-vlad"}, "descriptor backend 'test-projection' does not match"),
    ({"settings": {"layer": 31, "clusters": 4}}, "descriptor settings .* do not match"),
    ({"vocabulary_sha256": "cd" * 32}, "vocabulary hash abab.* does not match cdcd"),
    ({"dim": 512}, "descriptor dimension 256 does not match 512"),
])
def test_a_different_descriptor_is_refused(tmp_path, made, change, words):
    path = save(tmp_path / "m", made)
    other = DescriptorIdentity(**{**IDENTITY.to_dict(), **change})
    with pytest.raises(MapError, match=f"built with another descriptor.*: {words}"):
        load_map(path, expected_identity=other)


# -- damaged folders ---------------------------------------------------------------------
def rewrite(path: Path, name: str, data: bytes) -> None:
    """Replace a file and update the manifest's file table, as buggy software might."""
    (path / name).write_bytes(data)
    manifest = json.loads((path / "manifest.json").read_text())
    manifest["files"][name] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    (path / "manifest.json").write_text(json.dumps(manifest))


def edit_manifest(path: Path, fn) -> None:
    manifest = json.loads((path / "manifest.json").read_text())
    fn(manifest)
    (path / "manifest.json").write_text(json.dumps(manifest))


def npy(array: np.ndarray) -> bytes:
    import io
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _damage(kind: str, path: Path) -> None:
    desc = np.load(path / "descriptors.npy")
    if kind == "missing descriptors":
        (path / "descriptors.npy").unlink()
    elif kind == "truncated descriptors":
        data = (path / "descriptors.npy").read_bytes()
        (path / "descriptors.npy").write_bytes(data[: len(data) // 2])
    elif kind == "flipped byte in a thumbnail":
        p = path / "thumbs" / "000003.jpg"
        data = bytearray(p.read_bytes())
        data[len(data) // 2] ^= 0xFF
        p.write_bytes(bytes(data))
    elif kind == "float64 descriptors":
        rewrite(path, "descriptors.npy", npy(desc.astype(np.float64)))
    elif kind == "wrong descriptor shape":
        rewrite(path, "descriptors.npy", npy(desc[:-1]))
    elif kind == "NaN descriptor":
        desc[2, 5] = np.nan
        rewrite(path, "descriptors.npy", npy(desc))
    elif kind == "not a .npy":
        rewrite(path, "descriptors.npy", b"hello, I am not numpy")
    elif kind == "arc to unknown node":
        edit_manifest(path, lambda m: m["arcs"].append({"src": 0, "dst": 999, "weight": 1, "kind": "sequential"}))
    elif kind == "newer schema":
        edit_manifest(path, lambda m: m.update(schema_version=store.SCHEMA_VERSION + 1))
    elif kind == "manifest not JSON":
        (path / "manifest.json").write_text('{"schema_version": 1, "nodes": [')
    elif kind == "missing manifest":
        (path / "manifest.json").unlink()
    elif kind == "missing threshold":
        edit_manifest(path, lambda m: m["thresholds"].pop("T_loop_closure"))
    elif kind == "file outside the folder":
        edit_manifest(path, lambda m: m["nodes"][0].update(thumbnail="../../etc/passwd"))
    elif kind == "bad arc weight":
        edit_manifest(path, lambda m: m["arcs"][0].update(weight="far"))
    elif kind == "unreadable state":
        rewrite(path, "descriptor_state.npz", b"PK\x03\x04 broken zip")
    else:
        raise AssertionError(kind)


@pytest.mark.parametrize("kind, message", [
    ("missing descriptors", r"descriptors\.npy: file is missing"),
    ("truncated descriptors", r"descriptors\.npy: is \d+ bytes, the manifest says \d+ \(truncated"),
    ("flipped byte in a thumbnail", r"thumbs/000003\.jpg: content does not match its SHA-256"),
    ("float64 descriptors", r"descriptors\.npy: dtype is float64, expected float32"),
    ("wrong descriptor shape", r"descriptors\.npy: shape is \(\d+, 256\), expected"),
    ("NaN descriptor", r"descriptors\.npy: row 2 has NaN"),
    ("not a .npy", r"descriptors\.npy: not a readable \.npy"),
    ("arc to unknown node", r"arcs\[\d+\]: arc 0 -> 999 refers to unknown node 999"),
    ("newer schema", r"schema_version 2 is newer than this software reads \(1\)"),
    ("manifest not JSON", r"manifest\.json: not valid JSON"),
    ("missing manifest", r"manifest\.json: file is missing"),
    ("missing threshold", r"thresholds: .*T_loop_closure"),
    ("file outside the folder", r"nodes\[0\]\.thumbnail: .*outside the map folder"),
    ("bad arc weight", r"arcs\[0\]\.weight: expected a finite number"),
    ("unreadable state", r"descriptor_state\.npz: not a readable descriptor state"),
])
def test_damaged_map_folders_are_refused_with_a_clear_message(tmp_path, made, kind, message):
    path = save(tmp_path / "m", made)
    _damage(kind, path)
    with pytest.raises(MapError, match=message) as err:
        load_map(path)
    assert str(path) in str(err.value)


def test_missing_folder_and_bad_inputs_to_save(tmp_path, made):
    with pytest.raises(MapError, match="folder not found"):
        load_map(tmp_path / "nothing")
    with pytest.raises(MapError, match="no thumbnail for node"):
        save_map(tmp_path / "m", made[0].topomap, identity=IDENTITY, descriptor_state={},
                 thresholds=made[0].thresholds, thumbnails={})
    with pytest.raises(MapError, match=r"descriptor_state\['bad'\]"):
        save_map(tmp_path / "m", made[0].topomap, identity=IDENTITY, descriptor_state={"bad": object()},
                 thresholds=made[0].thresholds,
                 thumbnails={n: frame_image(n) for n in made[0].topomap.node_ids.tolist()})
    assert not (tmp_path / "m").exists()
    assert not list(tmp_path.glob(".m.*")), "a refused save leaves nothing behind"


def test_save_refuses_to_replace_a_folder_that_is_not_a_map(tmp_path, made):
    target = tmp_path / "photos"
    target.mkdir()
    (target / "holiday.jpg").write_bytes(b"precious")
    with pytest.raises(MapError, match="not a map folder"):
        save(target, made)
    assert (target / "holiday.jpg").read_bytes() == b"precious"
    empty = tmp_path / "empty"
    empty.mkdir()
    save(empty, made)
    assert load_map(empty).topomap.nodes() == made[0].topomap.nodes()


# -- crash safety ------------------------------------------------------------------------
def _crash_child(path: Path, new_made, crash_at: int, steps_file: Path, no_exchange: bool) -> None:
    """In a forked child: save, and die with os._exit right after step number ``crash_at``."""
    count = [0]

    def checkpoint(step: str) -> None:
        with open(steps_file, "a") as fh:
            fh.write(step + "\n")
        if count[0] == crash_at:
            os._exit(17)                                  # like a power cut: no cleanup runs
        count[0] += 1

    store._checkpoint = checkpoint
    if no_exchange:
        atomic.exchange_paths = lambda a, b: False
    try:
        save(path, new_made)
    except BaseException:
        os._exit(3)
    os._exit(0)


def _save_steps(tmp_path: Path, made_route, no_exchange: bool, monkeypatch) -> list[str]:
    """The checkpoint names of one complete save over an existing map, in order."""
    steps: list[str] = []
    path = save(tmp_path / "dry", made_route)
    with monkeypatch.context() as m:
        m.setattr(store, "_checkpoint", steps.append)
        if no_exchange:
            m.setattr(atomic, "exchange_paths", lambda a, b: False)
        save(path, made_route)
    return steps


@pytest.mark.parametrize("no_exchange", [False, True], ids=["renameat2-exchange", "two-renames"])
def test_a_save_interrupted_at_any_step_leaves_a_loadable_map(tmp_path, made, no_exchange, monkeypatch):
    old_made = made
    new_made = build(0.9)
    assert len(new_made[0].topomap) != len(old_made[0].topomap)
    steps = _save_steps(tmp_path, new_made, no_exchange, monkeypatch)
    assert steps[-1] == "remove previous" and ("move previous aside" in steps) is no_exchange
    # every step, except that of the many thumbnail writes only the first and last are tried
    thumbs = [k for k, s in enumerate(steps) if s.startswith("write thumbs/")]
    crash_points = [k for k in range(len(steps)) if k not in thumbs[1:-1]]
    path = save(tmp_path / "m", old_made)
    old_nodes = load_map(path).topomap.nodes()
    new_nodes = new_made[0].topomap.nodes()
    for crash_at in crash_points:
        steps_file = tmp_path / f"steps-{crash_at}.txt"
        pid = os.fork()
        if pid == 0:
            _crash_child(path, new_made, crash_at, steps_file, no_exchange)
        _, status = os.waitpid(pid, 0)
        assert os.waitstatus_to_exitcode(status) == 17, f"the save did not reach step {steps[crash_at]!r}"
        assert steps_file.read_text().splitlines()[-1] == steps[crash_at]
        loaded = load_map(path)                                  # never raises
        swapped = crash_at >= steps.index("exchange" if not no_exchange else "rename into place")
        assert loaded.topomap.nodes() == (new_nodes if swapped else old_nodes), steps[crash_at]
        save(path, old_made)                                     # the next save cleans up
        assert not list(tmp_path.glob(".m.*")), f"debris left after a crash at {steps[crash_at]!r}"
    save(path, new_made)
    assert load_map(path).topomap.nodes() == new_nodes


@pytest.mark.parametrize("step, no_exchange, committed", [
    ("write manifest.json", False, False),
    ("move previous aside", True, False),
    ("exchange", False, True),
])
def test_an_exception_during_save_leaves_one_complete_map(tmp_path, made, monkeypatch, step, no_exchange,
                                                          committed):
    path = save(tmp_path / "m", made)
    before = (path / "manifest.json").read_bytes()
    new_made = build(0.9)

    def fail(at: str) -> None:
        if at == step:
            raise OSError(28, "No space left on device")

    monkeypatch.setattr(store, "_checkpoint", fail)
    if no_exchange:
        monkeypatch.setattr(atomic, "exchange_paths", lambda a, b: False)
    with pytest.raises(OSError, match="No space left"):
        save(path, new_made)
    assert not list(tmp_path.glob(".m.*")), "no temporary or previous folder is left behind"
    assert ((path / "manifest.json").read_bytes() == before) is not committed
    want = new_made if committed else made
    assert load_map(path).topomap.nodes() == want[0].topomap.nodes()


def test_map_size_per_node(tmp_path, made):
    path = save(tmp_path / "m", made)
    size = map_size(path)
    n = len(made[0].topomap)
    assert size.n_nodes == n
    assert size.descriptor_bytes == (path / "descriptors.npy").stat().st_size >= n * 256 * 4
    thumbs = sum(p.stat().st_size for p in (path / "thumbs").iterdir())
    assert size.thumbnail_bytes == thumbs
    assert size.per_node_bytes == pytest.approx(
        (size.manifest_bytes + size.descriptor_bytes + size.thumbnail_bytes) / n)
    assert 1_000 < thumbs / n < 20_000                   # 160x120 JPEG at quality 80


def test_merged_nodes_round_trip(tmp_path):
    route = landmark_route(seed=0, stand_frames=0)
    calibrated = calibrate(route.descriptors, MappingConfig()).thresholds
    # a builder that never closes loops leaves the revisit to the merge pass
    cfg = MappingConfig(calibrated=False, **{**calibrated.to_dict(), "T_loop_closure": 1.0})
    made = build_map(route.descriptors, cfg, true_poses=route.poses, stamps_s=route.stamps_s)
    assert made.merge.merged
    loaded = load_map(save(tmp_path / "m", (made, route)))
    assert loaded.merged == made.merge.merged
    assert not set(loaded.merged) & set(loaded.topomap.node_ids.tolist())
    assert loaded.calibration is None


def test_gyro_headings_round_trip_beside_the_odometrys(tmp_path):
    made = build_map(landmark_route(seed=1, stand_frames=0).descriptors, MappingConfig())
    topomap = made.topomap
    ids = topomap.node_ids.tolist()
    gyro = {n: 0.05 * k for k, n in enumerate(ids)}
    for n in ids:
        topomap.set_gyro_yaw(n, gyro[n])
    assert topomap.headings("gyro") == gyro and topomap.odom_headings is None
    with pytest.raises(MapError, match="gyro heading of node"):
        topomap.set_gyro_yaw(ids[0], float("inf"))
    with pytest.raises(MapError, match="heading source"):
        topomap.headings("compass")
    jpegs = {n: encode_thumbnail(frame_image(n)) for n in ids}
    path = save_map(tmp_path / "m", topomap, identity=IDENTITY, descriptor_state={},
                    thresholds=made.thresholds, thumbnails=jpegs)
    loaded = load_map(path).topomap
    assert loaded.headings("gyro") == gyro and loaded.odom_headings is None
    assert loaded.node(ids[3]).gyro_yaw_rad == gyro[ids[3]]


def test_column_profiles_round_trip_and_bad_ones_are_refused(tmp_path, made):
    from maps.store import COLUMNS

    n = len(made[0].topomap)
    columns = np.random.default_rng(0).normal(size=(n, 10, 6)).astype(np.float32)
    loaded = load_map(save(tmp_path / "with", made, columns=columns))
    assert loaded.columns.dtype == np.float32 and loaded.columns.shape == (n, 10, 6)
    assert np.allclose(loaded.columns, columns, atol=2e-3)          # stored as float16
    assert load_map(save(tmp_path / "without", made)).columns is None   # maps before them
    with pytest.raises(MapError, match=r"columns must be finite, of shape"):
        save(tmp_path / "bad", made, columns=columns[:-1])
    # a columns file of the wrong shape behind a consistent file table is named on load
    path = save(tmp_path / "damaged", made, columns=columns)
    manifest = json.loads((path / "manifest.json").read_text())
    data = io.BytesIO()
    np.save(data, columns[:-1].astype(np.float16))
    (path / COLUMNS).write_bytes(data.getvalue())
    manifest["files"][COLUMNS] = {"bytes": len(data.getvalue()), "sha256": hashlib.sha256(data.getvalue()).hexdigest()}
    (path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(MapError, match=rf"{COLUMNS}.*shape is \({n - 1}, 10, 6\)"):
        load_map(path)
