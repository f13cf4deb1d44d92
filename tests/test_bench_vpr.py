"""``python -m robot.bench vpr`` on small routes written from scikit-image photographs.

Each "place" is one photograph; the query traversal sees it shifted by a few pixels and a bit
darker. The tiny backend (no network) checks the plumbing and the ground truth rules; one run
of the real EfficientNet-Lite0 backends at a small input size checks VLAD fitting on the
reference set, the feature cache and the timing columns.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from skimage import data

from core.hal import Pose2D, SensorFrame
from descriptors.efficientnet_lite_spec import block_channels
from robot.bench.__main__ import main as bench_main
from robot.mapping.recording import RecordingWriter

PHOTOS = ["astronaut", "camera", "coffee", "chelsea", "rocket", "coins", "moon", "page", "text",
          "immunohistochemistry", "hubble_deep_field", "clock", "cell", "colorwheel"]


def _place(name: str, shift_px: int = 0, gain: float = 1.0) -> np.ndarray:
    """A 160x120 RGB view of photograph ``name``, moved right by ``shift_px`` and scaled by ``gain``."""
    img = getattr(data, name)()
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    big = cv2.resize(img[:, :, :3], (176, 132), interpolation=cv2.INTER_AREA)
    view = big[6:126, 8 + shift_px:168 + shift_px]
    return np.clip(view.astype(np.float32) * gain, 0, 255).astype(np.uint8)


def _write_folder(folder: Path, views: list[np.ndarray]) -> Path:
    folder.mkdir(parents=True)
    for i, view in enumerate(views):
        assert cv2.imwrite(str(folder / f"img{i:03d}.png"), cv2.cvtColor(view, cv2.COLOR_RGB2BGR))
    return folder


@pytest.fixture(scope="module")
def route(tmp_path_factory) -> dict:
    """ref: the places in order; query: shifted and darker; shuffled: the query in another order."""
    root = tmp_path_factory.mktemp("vpr")
    ref = _write_folder(root / "ref", [_place(n) for n in PHOTOS])
    query_views = [_place(n, shift_px=4, gain=0.85) for n in PHOTOS]
    query = _write_folder(root / "query", query_views)
    order = np.random.default_rng(3).permutation(len(PHOTOS))
    shuffled = _write_folder(root / "shuffled", [query_views[i] for i in order])
    return {"root": root, "ref": ref, "query": query, "shuffled": shuffled, "order": order}


def _run(capsys, *argv) -> tuple[int, str, str]:
    rc = bench_main(["vpr", "--quiet", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


def _json(path: Path) -> dict:
    return json.loads(path.read_text())


def test_easy_route_is_recognised_and_json_says_how(route, capsys, tmp_path):
    out_json = tmp_path / "r" / "easy.json"
    rc, out, err = _run(capsys, "--ref", route["ref"], "--query", route["query"], "--tolerance", 0,
                        "--backend", "tiny", "--timing-frames", 2, "--json", out_json)
    assert rc == 0, err
    result = _json(out_json)
    (tiny,) = result["backends"]
    assert tiny["recall_at_1"] == 1.0 and tiny["recall_at_5"] == 1.0
    assert tiny["label"] == "tiny" and tiny["dim"] > 0 and tiny["bytes"] == 4 * tiny["dim"]
    assert tiny["describe_ms"] > 0 and tiny["describe_thirds_min_ms"] > 0
    assert result["match"] == {"mode": "frame index", "tolerance_frames": 0}
    assert result["reference_images"] == result["query_images"] == result["queries_evaluated"] == len(PHOTOS)
    assert result["vocabulary_fitted_on"] == "reference"
    assert "fit their vocabulary on the reference images" in out
    row = next(line for line in out.splitlines() if line.startswith("tiny "))
    assert row.split()[1:3] == ["1.000", "1.000"]


def test_grey_and_rgba_files_are_read_as_rgb(route, capsys, tmp_path):
    folder = tmp_path / "mixed"
    folder.mkdir()
    for i, name in enumerate(PHOTOS):
        rgb = _place(name, shift_px=4, gain=0.85)
        if i % 2:
            pixels = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        else:
            pixels = np.dstack([cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), np.full(rgb.shape[:2], 255, np.uint8)])
        assert cv2.imwrite(str(folder / f"img{i:03d}.png"), pixels)
    rc, _, err = _run(capsys, "--ref", route["ref"], "--query", folder, "--tolerance", 0, "--backend", "tiny",
                      "--timing-frames", 0, "--json", tmp_path / "mixed.json")
    assert rc == 0, err
    assert _json(tmp_path / "mixed.json")["backends"][0]["recall_at_1"] == 1.0


def test_shuffled_query_scores_what_the_permutation_allows(route, capsys, tmp_path):
    out_json = tmp_path / "shuffled.json"
    rc, _, err = _run(capsys, "--ref", route["ref"], "--query", route["shuffled"], "--tolerance", 1,
                      "--backend", "tiny", "--timing-frames", 0, "--json", out_json)
    assert rc == 0, err
    (tiny,) = _json(out_json)["backends"]
    # The easy test shows every photograph retrieves itself, so query i (photo order[i]) is right
    # exactly when order[i] lies within the tolerance of i.
    expected = float(np.mean(np.abs(route["order"] - np.arange(len(PHOTOS))) <= 1))
    assert expected < 1.0
    assert tiny["recall_at_1"] == pytest.approx(expected, abs=1e-4)
    assert tiny["recall_at_5"] >= tiny["recall_at_1"]


def test_effnet_vlad_fits_on_reference_and_caches_features(route, capsys, tmp_path):
    cache = tmp_path / "cache"
    small = "input_width_px=96,input_height_px=64"
    argv = ["--ref", route["ref"], "--query", route["query"], "--tolerance", 0,
            "--backend", f"effnet-vlad:blocks=[10],{small},clusters=8",
            "--backend", f"effnet-gap:blocks=[10],{small}",
            "--vocab-seeds", "0,1", "--cache", cache, "--timing-frames", 2, "--timing-size", "96x64"]
    rc, out, err = _run(capsys, *argv, "--json", tmp_path / "a.json")
    assert rc == 0, err
    vlad, gap = _json(tmp_path / "a.json")["backends"]
    assert vlad["recall_at_1"] == 1.0 and gap["recall_at_1"] == 1.0
    assert vlad["vocab_seeds"] == [0, 1] and len(vlad["recall_at_1_per_seed"]) == 2
    assert vlad["dim"] == 8 * block_channels(10) and gap["dim"] == block_channels(10)
    assert gap["vocab_seeds"] == [] and vlad["describe_thirds_ms"] > 0
    cached = sorted(cache.iterdir())
    assert len(cached) == 2             # one extractor (vlad and gap share it) x reference and query
    stamps = [p.stat().st_mtime_ns for p in cached]
    rc, _, err = _run(capsys, *argv, "--json", tmp_path / "b.json")
    assert rc == 0, err
    assert [p.stat().st_mtime_ns for p in sorted(cache.iterdir())] == stamps
    assert _json(tmp_path / "b.json")["backends"][0]["recall_at_1_per_seed"] == vlad["recall_at_1_per_seed"]


def _write_recording(folder: Path, places: list[tuple[str, Pose2D]], shift_px: int, gain: float,
                     with_poses: bool = True) -> Path:
    writer = RecordingWriter(folder)
    for i, (name, pose) in enumerate(places):
        writer.append(SensorFrame(stamp_s=0.2 * i, rgb=_place(name, shift_px, gain)), pose if with_poses else None)
    writer.finish()
    return folder


def test_recordings_match_by_true_position_and_heading(capsys, tmp_path):
    line = [(name, Pose2D(2.0 * i, 0.0, 0.0)) for i, name in enumerate(PHOTOS[:8])]
    # The reference also passes place 3 facing back, where it sees another photograph.
    ref = _write_recording(tmp_path / "ref", line + [(PHOTOS[9], Pose2D(6.0, 0.0, math.pi))], 0, 1.0)
    # The query faces back at place 3 but sees place 3's forward photograph: retrieving the forward
    # frame there is wrong (the place is the same, the view direction is not).
    query = _write_recording(tmp_path / "query", line + [(PHOTOS[3], Pose2D(6.1, 0.0, math.pi - 0.1))], 3, 0.9)
    out_json = tmp_path / "rec.json"
    rc, out, err = _run(capsys, "--ref-recording", ref, "--query-recording", query, "--tolerance-m", 0.5,
                        "--backend", "tiny", "--timing-frames", 0, "--json", out_json)
    assert rc == 0, err
    result = _json(out_json)
    assert result["match"] == {"mode": "true pose", "tolerance_m": 0.5, "tolerance_deg": 45.0}
    assert result["queries_evaluated"] == 9
    assert result["backends"][0]["recall_at_1"] == pytest.approx(8 / 9, abs=1e-4)
    assert "0.5 m and 45 deg" in out
    rc, _, err = _run(capsys, "--ref-recording", ref, "--query-recording", query, "--tolerance-m", 0.5,
                      "--tolerance-deg", 180, "--backend", "tiny", "--timing-frames", 0, "--json", out_json)
    assert rc == 0, err
    assert _json(out_json)["backends"][0]["recall_at_1"] == 1.0


def test_bad_input_exits_2_naming_the_culprit(route, capsys, tmp_path):
    ref = route["ref"]
    missing = tmp_path / "nowhere"
    rc, _, err = _run(capsys, "--ref", missing, "--query", ref, "--backend", "tiny")
    assert rc == 2 and f"{missing}: no such folder" in err

    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("no images here")
    rc, _, err = _run(capsys, "--ref", ref, "--query", empty, "--backend", "tiny")
    assert rc == 2 and str(empty) in err and "no images" in err

    broken = tmp_path / "broken"
    broken.mkdir()
    for i in range(len(PHOTOS)):
        cv2.imwrite(str(broken / f"img{i:03d}.png"), cv2.cvtColor(_place(PHOTOS[i]), cv2.COLOR_RGB2BGR))
    (broken / "img005.png").write_bytes(b"this is not a PNG file")
    rc, _, err = _run(capsys, "--ref", ref, "--query", broken, "--backend", "tiny", "--timing-frames", 0)
    assert rc == 2 and f"{broken / 'img005.png'}: cannot read the image" in err
    cv2.imwrite(str(broken / "img005.png"), np.zeros((5, 6), np.uint8))
    rc, _, err = _run(capsys, "--ref", ref, "--query", broken, "--backend", "tiny", "--timing-frames", 0)
    assert rc == 2 and f"{broken / 'img005.png'}: 6x5 px is too small" in err

    short = _write_folder(tmp_path / "short", [_place(n) for n in PHOTOS[:5]])
    rc, _, err = _run(capsys, "--ref", ref, "--query", short, "--backend", "tiny")
    assert rc == 2 and f"{len(PHOTOS)} images" in err and "5" in err and "equal counts" in err

    rc, _, err = _run(capsys, "--ref", ref, "--query", route["query"], "--backend", "no-such-net")
    assert rc == 2 and "unknown descriptor backend 'no-such-net'" in err
    rc, _, err = _run(capsys, "--ref", ref, "--query", route["query"], "--backend", "tiny:width_px")
    assert rc == 2 and "expected key=value" in err
    rc, _, err = _run(capsys, "--ref", ref, "--query", route["query"], "--backend", "tiny:depth=3")
    assert rc == 2 and "no setting 'depth'" in err

    rc, _, err = _run(capsys, "--ref", ref, "--backend", "tiny")
    assert rc == 2 and "--query" in err
    rc, _, err = _run(capsys, "--backend", "tiny")
    assert rc == 2 and "--ref-recording" in err

    no_poses = _write_recording(tmp_path / "real_robot", [(n, None) for n in PHOTOS[:3]], 0, 1.0, with_poses=False)
    rc, _, err = _run(capsys, "--ref-recording", no_poses, "--query-recording", no_poses, "--backend", "tiny")
    assert rc == 2 and str(no_poses / "frames.csv") in err and "no true pose" in err


def _noisy_route(n: int, dim: int, noise: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Reference descriptors of n places along a route (each place shares half its vector with the
    next) and query descriptors of the same places under heavy noise; rows L2-normalised."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(n + 1, dim))
    ref = base[:-1] + 0.5 * base[1:]
    query = ref + noise * rng.normal(size=ref.shape)
    return (ref / np.linalg.norm(ref, axis=1, keepdims=True), query / np.linalg.norm(query, axis=1, keepdims=True))


def test_the_belief_filter_recovers_a_route_that_single_images_miss():
    from robot.bench.vpr import frame_positives, recall_at, sequence_modes, sequence_recall

    ref, query = _noisy_route(120, 64, noise=5.0, seed=4)
    positives = frame_positives(120, 120, 1)
    single = recall_at(query @ ref.T, positives)[1]
    in_order = sequence_recall(sequence_modes(query, ref), positives)
    assert single < 0.5 and in_order > 0.85, (single, in_order)
    # the gain comes from the order of the views: shuffled, the filter does worse than one look
    order = np.random.default_rng(0).permutation(120)
    shuffled = sequence_recall(sequence_modes(query[order], ref), positives[order])
    assert shuffled < single, (shuffled, single)


def _walk(folder: Path, shift_px: int, gain: float) -> Path:
    """A route: 160 px wide crops every 24 px along a panorama of four photographs (neighbouring
    views overlap, as a walk's frames do)."""
    strip = np.hstack([cv2.resize(_place(n), (176, 132)) for n in PHOTOS[:4]])
    views = [np.clip(strip[6:126, x:x + 160].astype(np.float32) * gain, 0, 255).astype(np.uint8)
             for x in range(shift_px, strip.shape[1] - 160, 24)]
    return _write_folder(folder, views)


def test_sequence_flag_reports_the_filter_beside_single_images(route, capsys, tmp_path):
    ref, query = _walk(tmp_path / "ref", 0, 1.0), _walk(tmp_path / "query", 6, 0.8)
    out_json = tmp_path / "seq.json"
    rc, out, err = _run(capsys, "--ref", ref, "--query", query, "--tolerance", 1,
                        "--backend", "tiny", "--timing-frames", 0, "--sequence", "--json", out_json)
    assert rc == 0, err
    (tiny,) = _json(out_json)["backends"]
    assert tiny["sequence_recall_at_1"] >= 0.9 and len(tiny["sequence_recall_at_1_per_seed"]) == 1
    assert any("seq@1" in line for line in out.splitlines())
    # fourteen unrelated photographs are no route: neighbours no more alike than strangers
    rc, _, err = _run(capsys, "--ref", route["ref"], "--query", route["query"], "--tolerance", 0,
                      "--backend", "tiny", "--timing-frames", 0, "--sequence")
    assert rc == 2 and "--sequence needs references along a route" in err and len(err.splitlines()) == 1
