"""`python -m robot.bench perf` on the tiny world: every section measured, numbers consistent.

One run of the command (drive the route, write the MP4, time the descriptor, map the video,
navigate a few steps on that map) is shared by the tests; a second run reuses its map and video
(``--map``, ``--video``, ``--goal``). Both run the real simulator, the real EfficientNet weights
and real files, with few repeats and steps.
"""

import json
import math
import os
from pathlib import Path

import cv2
import pytest

from maps.store import load_map
from robot.bench.__main__ import main as bench_main

pytestmark = pytest.mark.slow      # the perf benchmark: a drive, a map and control steps

TINY = str(Path(__file__).parent / "data" / "tiny_world.yaml")
FEW = ["--repeats", "4", "--steps", "12", "--map-repeats", "1", "--threads", "1", "--quiet"]
ENGINES = ("onnxruntime", "torch")
STAGES = ("read_ms", "describe_ms", "decide_ms", "tick_ms")


@pytest.fixture(scope="module")
def perf_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("perf")
    report = out / "perf.json"
    rc = bench_main(["perf", "--world", TINY, *FEW, "--out", str(out / "work"), "--json", str(report)])
    assert rc == 0
    return out / "work", json.loads(report.read_text())


def _numbers(tree, path=""):
    """(path, value) of every number in a JSON tree (booleans are not numbers here)."""
    if isinstance(tree, dict):
        for key, value in tree.items():
            yield from _numbers(value, f"{path}.{key}")
    elif isinstance(tree, list):
        for i, value in enumerate(tree):
            yield from _numbers(value, f"{path}[{i}]")
    elif isinstance(tree, (int, float)) and not isinstance(tree, bool):
        yield path, tree


def test_every_section_has_positive_finite_numbers(perf_run):
    _, report = perf_run
    assert list(report["engines"]) == list(ENGINES)
    sections = [report["engines"][e][s] for e in ENGINES for s in ("descriptor", "control_step", "mapping")]
    for section in sections + [report["map_size"], report["memory"], report["speedup"]]:
        numbers = list(_numbers(section))
        assert numbers, section
        for path, value in numbers:
            assert math.isfinite(value), (path, value)
            # the fastest physics step may be the final one, which has no tick
            if not path.endswith(".min"):
                assert value > 0, (path, value)
    for engine in ENGINES:
        d = report["engines"][engine]["descriptor"]
        assert d["backend"] == "effnet-vlad" and d["frame_px"] == [320, 240]
        assert d["describe_thirds_ms"]["n"] == 4


def test_the_speedup_is_the_ratio_of_the_engines_medians(perf_run):
    _, report = perf_run
    ort, torch_ = report["engines"]["onnxruntime"], report["engines"]["torch"]
    ratio = report["speedup"]["onnxruntime_vs_torch"]
    assert ratio["describe_thirds"] == pytest.approx(torch_["descriptor"]["describe_thirds_ms"]["median"]
                                                     / ort["descriptor"]["describe_thirds_ms"]["median"])
    assert ratio["mapping_fps"] == pytest.approx(ort["mapping"]["fps_median"] / torch_["mapping"]["fps_median"])


def test_step_split_sums_to_the_episode_wall_time(perf_run):
    _, report = perf_run
    for engine in ENGINES:
        c = report["engines"][engine]["control_step"]
        assert 1 <= c["steps"] <= 12
        stages = c["stages"]
        # the stages are timed inside the loop, the wall time around it: only the observer and the
        # loop's bookkeeping lie between them
        assert c["total_ms"]["mean"] <= c["wall_ms_per_step"]
        assert c["total_ms"]["mean"] == pytest.approx(c["wall_ms_per_step"], rel=0.15)
        for key in STAGES:
            assert stages[key]["n"] == c["steps"]


def test_bytes_per_node_is_folder_size_over_nodes(perf_run):
    work, report = perf_run
    s = report["map_size"]
    map_dir = work / "map"
    total = sum(os.path.getsize(os.path.join(root, f)) for root, _, files in os.walk(map_dir) for f in files)
    nodes = len(load_map(map_dir).topomap)
    assert s["nodes"] == nodes == report["engines"]["onnxruntime"]["mapping"]["nodes"]
    assert s["folder_bytes"] == total
    assert s["bytes_per_node"] == pytest.approx(total / nodes)
    assert s["growing_bytes_per_node"] < s["bytes_per_node"]


def test_mapping_throughput_counts_the_video_frames(perf_run):
    work, report = perf_run
    cap = cv2.VideoCapture(str(work / "drive.mp4"))
    frames = 0
    while cap.read()[0]:
        frames += 1
    cap.release()
    for engine in ENGINES:
        m = report["engines"][engine]["mapping"]
        assert m["frames"] == frames > 20          # the 4.5 m route at 5 frames/s
        assert m["runs"] == 1
        assert m["fps_median"] == pytest.approx(frames / m["seconds_median"])
    # a process that ran the CNN holds its weights and runtime (well over 150 MB) and, on the tiny
    # world, nothing near a few GB: a leak or a lost measurement fails here
    mem = report["memory"]
    assert list(mem["peak_rss_mb_after"])[0] == "drive"
    assert 150 < mem["peak_rss_mb_after"]["descriptor timing"] <= mem["peak_rss_mb"] < 3000


def test_reusing_map_and_video_prints_every_section(perf_run, capsys):
    work, report = perf_run
    """A second run on the first run's map and video, to a node given by id."""
    goal = int(load_map(work / "map").topomap.node_ids[0])
    rc = bench_main(["perf", "--world", TINY, *FEW, "--steps", "5", "--map", str(work / "map"),
                     "--video", str(work / "drive.mp4"), "--goal", str(goal)])
    assert rc == 0
    out = capsys.readouterr().out
    for label in ("describe_thirds 320x240", "render (read)", "describe", "decide", "physics (tick)",
                  "frames/s", "per node", "peak RSS", "onnxruntime", "torch", "ratio"):
        assert label in out, label
    assert f"{work / 'drive.mp4'} (given)" in out and f"{work / 'map'} (given), goal node {goal}" in out


@pytest.mark.parametrize("extra, option", [
    (["--repeats", "0"], "--repeats"),
    (["--steps", "-3"], "--steps"),
    (["--map-repeats", "0"], "--map-repeats"),
    (["--threads", "0"], "--threads"),
    (["--map", "/nonexistent/map"], "--map"),
    (["--video", "/nonexistent/walk.mp4"], "--video"),
    (["--route", "nowhere"], "--route"),
    (["--goal", "-1"], "--goal"),
    (["--engines", "onnxruntime,tensorflow"], "--engines"),
    (["--world", "nowhere"], "no world named 'nowhere'"),
    (["--config", "/nonexistent/stack.yaml"], "/nonexistent/stack.yaml"),
])
def test_bad_arguments_exit_2_naming_the_option(extra, option, capsys):
    assert bench_main(["perf", "--world", TINY, "--quiet", *extra]) == 2
    err = capsys.readouterr().err
    assert option in err and "error" in err


def test_unparsable_number_exits_2():
    with pytest.raises(SystemExit) as exc:
        bench_main(["perf", "--steps", "many"])
    assert exc.value.code == 2
