"""``python -m robot.bench perf``: speed and size of the stack on this machine.

Five numbers a Limo owner needs before trusting the 10 Hz control loop to a small computer:

1. **descriptor time per frame**: ``describe_thirds`` (the full view and its Left / Middle /
   Right thirds, what one control step needs) of one 320x240 frame at batch 1, with the
   configured backend and a vocabulary fitted on a few frames of the drive; median and p90 over
   ``--repeats`` calls after a warm-up (``describe`` of the full view alone beside it), the
   engines' calls alternating so that both see the same machine;
2. **control step split**: ``--steps`` steps of a navigation episode on a map, from the route's
   start toward its goal (``robot.episode.sim.run_sim_navigation``, the loop of
   ``robot.run --mode navigate``; the goal is the image at the route's goal on a ``--map``, the
   last node on the map built here from the drive, which ends at the route's goal): render (``read``) / describe / decide / physics (``tick``)
   per step, median, mean and p90, and the episode's wall time per step, which the stages
   should add up to; with ``--rerun`` the same episode runs once more, recorded for the Rerun
   viewer to an ``.rrd`` file: what logging one step costs (median, p90) and the file's size
   per step;
3. **mapping throughput from a video**: the route is driven with the scripted teleoperator and
   its camera frames written as an MP4 at the recording rate (or ``--video`` is used), then
   mapped ``--map-repeats`` times with the pipeline of ``robot.run --mode map --video`` (fresh
   descriptor, vocabulary fit, describe, build, save, pictures); frames per second of the whole
   pipeline, median over the runs, and the map's node count;
4. **map bytes per node**: the map folder's size on disk (every file in it, pictures included)
   divided by its nodes, with ``maps.store.map_size``'s split (the part that grows per node:
   manifest, descriptors, thumbnails; the fixed vocabulary state and walkthrough log);
5. **peak memory**: the process's peak resident set (``ru_maxrss``) after each section.

Sections 1-3 run once per inference engine of the dense CNN (``--engines``, default both
``onnxruntime`` and ``torch`` for the EfficientNet backends: :mod:`descriptors.inference`),
printed side by side with their ratio. The episode runs on ``--map`` when given, else on the
map built from the video with the first engine. Thread pools are limited as in
:mod:`robot.threads` (one OpenBLAS and one OpenCV thread; ``--threads`` inference threads for
either engine); the header says how it ran. ``--json PATH`` writes every number.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence

import cv2
import numpy as np
from tqdm import tqdm

from core.atomic import move_into_place, temporary_sibling, write_json

EXIT_BAD_INPUT = 2
EXIT_FAILED = 1
TIMING_SIZE = (320, 240)        # the Limo camera's frame (width, height) in px
FIT_FRAMES = 8                  # "a few frames" for the timing vocabulary: 8 x 80 block-13 patches
WARMUP_CALLS = 2                # the first calls load weights and warm torch's allocator
DEFAULTS = {"repeats": 50, "steps": 200, "map_repeats": 3}
QUICK = {"repeats": 10, "steps": 30, "map_repeats": 1}
VIDEO_NAME = "drive.mp4"
MAP_NAME = "map"


class PerfInputError(ValueError):
    """A bad option or input file for the perf command; the message names it."""


# --------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Speed and size on this machine: describe_thirds per 320x240 frame at batch 1, the control step "
        "split (render / describe / decide / physics) of a navigation episode, mapping throughput from a "
        "video (frames/s), map bytes per node and peak memory. Medians over repeated runs.")
    parser.add_argument("--world", default="hospital",
                        help="world name from configs/worlds or a path to a world YAML (default hospital)")
    parser.add_argument("--route", default=None, metavar="NAME",
                        help="evaluation route driven for the video and navigated for the step split "
                             "(default: the world's first easy route)")
    parser.add_argument("--map", type=Path, default=None, metavar="DIR",
                        help="navigate on this map folder (default: the map built from the video here)")
    parser.add_argument("--goal", type=int, default=None, metavar="NODE",
                        help="navigate to this node id of the map (default: the image at the route's goal on "
                             "--map, the last node of the map built here, which is the drive's end)")
    parser.add_argument("--video", type=Path, default=None, metavar="PATH",
                        help="time mapping from this video instead of a drive rendered here")
    parser.add_argument("--repeats", type=int, default=None, metavar="N",
                        help=f"describe_thirds calls timed after {WARMUP_CALLS} warm-up calls "
                             f"(default {DEFAULTS['repeats']}, --quick {QUICK['repeats']})")
    parser.add_argument("--steps", type=int, default=None, metavar="N",
                        help=f"control steps of the navigation episode (default {DEFAULTS['steps']}, "
                             f"--quick {QUICK['steps']}; fewer when the robot arrives first)")
    parser.add_argument("--map-repeats", type=int, default=None, metavar="N",
                        help=f"times the video is mapped (default {DEFAULTS['map_repeats']}, "
                             f"--quick {QUICK['map_repeats']})")
    parser.add_argument("--quick", action="store_true",
                        help="fewer repeats and steps (a smoke test; explicit --repeats/--steps/--map-repeats win)")
    parser.add_argument("--threads", type=int, default=None,
                        help="inference threads of either engine (default: the engines' own, ONNX Runtime half "
                             "the cores, torch all; the paper harness's workers use 1)")
    parser.add_argument("--engines", default=None, metavar="LIST",
                        help="comma-separated inference engines to time side by side: onnxruntime, torch "
                             "(default: both for the EfficientNet backends, else the configured one)")
    parser.add_argument("--appearance-seed", type=int, default=0,
                        help="lighting and props of the world for the drive and the episode (default 0)")
    parser.add_argument("--config", type=Path, default=None,
                        help="stack configuration YAML (default configs/default.yaml)")
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help=f"keep the drive video ({VIDEO_NAME}) and the built map ({MAP_NAME}/) here "
                             "(default: a temporary folder, removed afterwards)")
    parser.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write the numbers as JSON here")
    parser.add_argument("--rerun", action="store_true",
                        help="also run the episode (first engine) while recording it for the Rerun viewer to an "
                             ".rrd file, and report what logging costs per step (needs pip install -e '.[viz]')")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


@dataclass(frozen=True)
class PerfSettings:
    """The validated options."""

    repeats: int
    steps: int
    map_repeats: int
    threads: Optional[int]
    engines: tuple[Optional[str], ...]     # None: the backend has no engine choice


def settings_from(args: argparse.Namespace) -> PerfSettings:
    """Counts resolved against the defaults (or --quick); bad values raise PerfInputError."""
    base = QUICK if args.quick else DEFAULTS
    values = {}
    for name in ("repeats", "steps", "map_repeats"):
        value = getattr(args, name)
        value = base[name] if value is None else value
        if value < 1:
            raise PerfInputError(f"--{name.replace('_', '-')} must be >= 1, got {value}")
        values[name] = value
    if args.goal is not None and args.goal < 0:
        raise PerfInputError(f"--goal must be a node id >= 0, got {args.goal}")
    if args.threads is not None and args.threads < 1:
        raise PerfInputError(f"--threads must be >= 1, got {args.threads}")
    if args.video is not None and not args.video.is_file():
        raise PerfInputError(f"--video {args.video}: no such file")
    if args.map is not None and not args.map.is_dir():
        raise PerfInputError(f"--map {args.map}: no such map folder")
    if getattr(args, "rerun", False):
        from robot.viewer.stream import ViewerUnavailableError, rerun_sdk

        try:
            rerun_sdk()
        except ViewerUnavailableError as exc:
            raise PerfInputError(f"--rerun: {exc}") from None
    engines: tuple[Optional[str], ...] = (None,)
    if args.engines is not None:
        from descriptors.inference import ENGINES

        engines = tuple(e.strip() for e in args.engines.split(",") if e.strip())
        bad = [e for e in engines if e not in ENGINES]
        if bad or not engines or len(set(engines)) != len(engines):
            raise PerfInputError(f"--engines {args.engines!r}: expected a comma-separated list of "
                                 f"{', '.join(ENGINES)}, each once")
    return PerfSettings(threads=args.threads, engines=engines, **values)


#: backends whose CNN runs in either engine (the ``engine`` setting of descriptors.factory)
ENGINE_BACKENDS = ("effnet-vlad", "effnet-gap")


def engine_configs(config, engines: Sequence[Optional[str]]) -> list[tuple[str, object]]:
    """(label, stack config) per engine to time: the descriptor settings with ``engine`` set.
    ``engines == (None,)``: both engines for the EfficientNet backends, else the config as is."""
    from dataclasses import replace

    from descriptors.inference import ENGINES, onnxruntime_available

    backend = config.descriptor.backend
    if engines == (None,):
        if backend not in ENGINE_BACKENDS:
            return [(str(config.descriptor.settings.get("engine", "default")), config)]
        engines = tuple(e for e in ENGINES if e != "onnxruntime" or onnxruntime_available())
    elif backend not in ENGINE_BACKENDS:
        raise PerfInputError(f"--engines: the descriptor backend {backend!r} has no engine choice "
                             f"(only {', '.join(ENGINE_BACKENDS)})")
    return [(e, replace(config, descriptor=replace(config.descriptor,
                                                   settings={**config.descriptor.settings, "engine": e})))
            for e in engines]


def _pick_route(world, name: Optional[str]) -> str:
    routes = world.routes.evaluation
    if not routes:
        raise PerfInputError(f"--world {world.name}: the world has no evaluation routes to drive")
    if name is None:
        easy = [n for n, r in routes.items() if r.difficulty == "easy"]
        return easy[0] if easy else next(iter(routes))
    if name not in routes:
        raise PerfInputError(f"--route {name!r}: world {world.name!r} has no such route "
                             f"(routes: {', '.join(routes)})")
    return name


# --------------------------------------------------------------------------------------------
# Statistics and memory
# --------------------------------------------------------------------------------------------
def summary_ms(values: Sequence[float]) -> dict:
    """Median, p90, mean and fastest of a sample of milliseconds."""
    a = np.asarray(values, dtype=float)
    return {"median": float(np.median(a)), "p90": float(np.percentile(a, 90)), "mean": float(a.mean()),
            "min": float(a.min()), "n": int(a.size)}


def peak_rss_mb() -> float:
    """Peak resident set of this process so far, MB (``ru_maxrss`` is in KiB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0


def time_calls_ms(fn: Callable[[], object], repeats: int, warmup: int = WARMUP_CALLS) -> list[float]:
    """Wall milliseconds of ``repeats`` calls of ``fn`` after ``warmup`` untimed ones."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1000.0)
    return times


# --------------------------------------------------------------------------------------------
# 0. The drive: camera frames along the route, as an MP4
# --------------------------------------------------------------------------------------------
def drive_route(world, route_name: str, config, appearance_seed: int, progress: bool) -> list[np.ndarray]:
    """RGB frames of the scripted teleoperator driving the route, one every
    ``recording.every_n_ticks`` control ticks (the mapping recording's rate)."""
    from robot.episode.start import route_pose
    from robot.mapping.drive import DriveError
    from sim.hal import SimLimo
    from sim.teleop import WaypointTeleop

    route = world.routes.evaluation[route_name]
    teleop = WaypointTeleop(route.path, config.teleop)
    period = config.sim.control_period_s
    max_ticks = int(math.ceil(config.recording.time_budget_factor * teleop.length_m
                              / config.teleop.cruise_v_mps / period)) + 100
    frames: list[np.ndarray] = []
    base = SimLimo(config.sim, start=route_pose(route.start), world=world, appearance_seed=appearance_seed)
    with base, tqdm(total=max_ticks, unit="tick", desc=f"driving {route_name}", disable=not progress,
                    leave=False, file=sys.stderr) as bar:
        truth = base.ground_truth
        for tick in range(max_ticks):
            pose = truth.true_pose()
            if teleop.done(pose):
                break
            if tick % config.recording.every_n_ticks == 0:
                frames.append(base.read().rgb)
            base.apply(teleop.command(pose))
            base.tick()
            bar.update(1)
        else:
            raise DriveError(f"the drive along route {route_name!r} of {world.name!r} did not finish within "
                             f"{max_ticks} control ticks")
        frames.append(base.read().rgb)
    return frames


def write_video(frames: Sequence[np.ndarray], path: Path, fps: float) -> Path:
    """Write RGB ``frames`` as an MP4 (mp4v), as a phone video of the drive would be."""
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames[0].shape[:2]
    tmp = temporary_sibling(path)
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    if not writer.isOpened():
        tmp.unlink(missing_ok=True)
        raise PerfInputError(f"{path}: OpenCV cannot write an MP4 (mp4v) here")
    try:
        for rgb in frames:
            writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    except BaseException:
        writer.release()
        tmp.unlink(missing_ok=True)
        raise
    writer.release()
    return move_into_place(tmp, path)


def video_frames(path: Path, count: int) -> list[np.ndarray]:
    """Up to ``count`` RGB frames spread over the video ``path`` (for timing and the vocabulary)."""
    from robot.mapping.sources import VideoSource

    frames = [f.rgb for f in VideoSource(path)]
    if not frames:
        raise PerfInputError(f"--video {path}: no readable frames")
    picks = np.unique(np.linspace(0, len(frames) - 1, num=min(count, len(frames))).round().astype(int))
    return [frames[i] for i in picks]


# --------------------------------------------------------------------------------------------
# 1. Descriptor time per frame
# --------------------------------------------------------------------------------------------
def time_descriptors(configs: Sequence[tuple[str, object]], frames: Sequence[np.ndarray], repeats: int) -> dict:
    """describe_thirds (and describe) of one 320x240 frame at batch 1, ms, per (label, config):
    the vocabulary is fitted once on up to FIT_FRAMES of ``frames`` and loaded into the others,
    and the calls alternate between the descriptors (A B A B ...), so that every engine sees the
    same frames under the same load on a shared machine; the timed calls cycle over the frames."""
    from descriptors.factory import make_descriptor

    descriptors = [(label, make_descriptor(c.descriptor.backend, **c.descriptor.settings)) for label, c in configs]
    sized = [cv2.resize(f, TIMING_SIZE, interpolation=cv2.INTER_AREA) if f.shape[1::-1] != TIMING_SIZE else f
             for f in frames]
    fit = sized[:: max(1, len(sized) // FIT_FRAMES)][:FIT_FRAMES]
    first = descriptors[0][1]
    if first.needs_fit:
        first.fit(fit)
        for _, other in descriptors[1:]:
            other.load_state(first.state_dict())
    times = {label: {"thirds": [], "full": []} for label, _ in descriptors}
    for method, key in (("describe_thirds", "thirds"), ("describe", "full")):
        for k in range(WARMUP_CALLS + repeats):
            frame = [sized[k % len(sized)]]           # different frames, as a moving camera delivers
            for label, descriptor in descriptors:
                t0 = time.perf_counter()
                getattr(descriptor, method)(frame)
                if k >= WARMUP_CALLS:
                    times[label][key].append((time.perf_counter() - t0) * 1000.0)
    return {label: {"backend": d.identity.backend, "dim": int(d.identity.dim or 0), "frame_px": list(TIMING_SIZE),
                    "fit_frames": len(fit), "repeats": repeats,
                    "describe_thirds_ms": summary_ms(times[label]["thirds"]),
                    "describe_ms": summary_ms(times[label]["full"])}
            for label, d in descriptors}


# --------------------------------------------------------------------------------------------
# 2. Mapping throughput from a video
# --------------------------------------------------------------------------------------------
def time_mapping(video: Path, config, map_dirs: Sequence[Path], progress: bool) -> dict:
    """Map ``video`` once per folder of ``map_dirs`` with the ``robot.run --mode map --video``
    pipeline (a fresh descriptor each time, as the command builds one); frames per second."""
    from descriptors.factory import make_descriptor
    from robot.mapping.make import build_map_from_frames
    from robot.mapping.sources import VideoSource

    seconds, summary = [], {}
    for map_dir in tqdm(map_dirs, desc="mapping the video", unit="run", disable=not progress, leave=False,
                        file=sys.stderr):
        t0 = time.perf_counter()
        source = VideoSource(video)
        descriptor = make_descriptor(config.descriptor.backend, **config.descriptor.settings)
        built = build_map_from_frames(source, descriptor, config.mapping, map_dir, total=len(source),
                                      fit_max_frames=config.descriptor.fit_max_frames,
                                      source=source.description, progress=False)
        seconds.append(time.perf_counter() - t0)
        summary = built.summary
    frames = int(summary["frames_read"])
    fps = [frames / s for s in seconds]
    return {"video": str(video), "frames": frames, "runs": len(seconds), "seconds": seconds,
            "seconds_median": float(np.median(seconds)), "fps_median": float(np.median(fps)),
            "fps_min": float(np.min(fps)), "nodes": int(summary["nodes"])}


# --------------------------------------------------------------------------------------------
# 3. Map bytes per node
# --------------------------------------------------------------------------------------------
def folder_bytes(folder: Path) -> int:
    """Bytes of every file under ``folder`` (recursively)."""
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def map_bytes(map_dir: Path) -> dict:
    """The map folder's size per node; ``growing_bytes_per_node`` is ``map_size``'s per-node part."""
    from maps.store import map_size

    size = map_size(map_dir)
    total = folder_bytes(map_dir)
    return {"map": str(map_dir), "nodes": size.n_nodes, "folder_bytes": total,
            "bytes_per_node": total / size.n_nodes, "growing_bytes_per_node": float(size.per_node_bytes),
            "descriptor_bytes": size.descriptor_bytes, "thumbnail_bytes": size.thumbnail_bytes,
            "state_bytes": size.state_bytes, "walkthrough_bytes": size.walkthrough_bytes}


# --------------------------------------------------------------------------------------------
# 4. Control step split
# --------------------------------------------------------------------------------------------
STAGES = (("read_ms", "render (read)"), ("describe_ms", "describe"), ("decide_ms", "decide"),
          ("tick_ms", "physics (tick)"))


def last_node(map_dir: Path) -> int:
    """The node of the map's last keyframe: the end of the drive the map was built from."""
    from maps.store import load_map

    return max(load_map(map_dir).topomap.nodes(), key=lambda n: n.keyframe_index).node_id


def time_control_steps(world, map_dir: Path, config, route_name: str, steps: int, appearance_seed: int,
                       progress: bool, goal_node: Optional[int] = None, rrd: Optional[Path] = None) -> dict:
    """``steps`` steps of a navigation episode on ``map_dir`` from the route's start toward
    ``goal_node`` (None: the image the camera sees at the route's goal, as ``robot.run --mode
    navigate --route`` does); per-stage ms from ``EpisodeOutcome.timings``. With ``rrd`` the
    episode is also recorded for the viewer there, and what that costs per step is added."""
    from descriptors.factory import make_descriptor
    from robot.episode.sim import EpisodeOutputs, SimEpisode, run_sim_navigation

    descriptor = make_descriptor(config.descriptor.backend, **config.descriptor.settings)
    episode = SimEpisode(world, map_dir, goal=goal_node, route=route_name, appearance_seed=appearance_seed,
                         max_steps=steps)
    viewer = None
    if rrd is not None:
        from robot.viewer.stream import ViewerTarget

        viewer = ViewerTarget(save_path=rrd)
    result = run_sim_navigation(episode, descriptor, config, EpisodeOutputs(progress=progress, viewer=viewer))
    outcome = result.outcome
    timings = outcome.timings
    if not timings:
        raise PerfInputError(f"the episode on {map_dir} ran no control step ({outcome.reason})")
    stages = {key: summary_ms([getattr(t, key) for t in timings]) for key, _ in STAGES}
    goal = f"image at the goal of route {route_name}" if goal_node is None else f"node {goal_node}"
    out = {"map": str(map_dir), "route": route_name, "goal": goal, "steps": len(timings), "end": outcome.end.value,
           "reason": outcome.reason, "stages": stages, "total_ms": summary_ms([t.total_ms for t in timings]),
           "wall_ms_per_step": outcome.wall_time_s * 1000.0 / len(timings),
           "control_period_ms": config.sim.control_period_s * 1000.0}
    if rrd is not None:
        out["viewer"] = {"log_ms": summary_ms(result.viewer_step_ms), "rrd_bytes": rrd.stat().st_size,
                         "rrd_bytes_per_step": rrd.stat().st_size / len(timings)}
    return out


# --------------------------------------------------------------------------------------------
# The report
# --------------------------------------------------------------------------------------------
def _ms(t: dict) -> str:
    return f"{t['median']:.1f} ms (p90 {t['p90']:.1f})"


def format_report(report: dict) -> str:
    """The readable table of :func:`run`'s report: one value column per engine, then the ratio."""
    engines = report["engines"]
    labels = list(engines)
    first = engines[labels[0]]
    w, h = first["descriptor"]["frame_px"]
    rows: list[tuple[str, str, list[str]]] = []

    def row(section: str, quantity: str, value: Callable[[dict], str]) -> None:
        rows.append((section, quantity, [value(engines[label]) for label in labels]))

    row("descriptor", f"describe_thirds {w}x{h}, batch 1", lambda e: _ms(e["descriptor"]["describe_thirds_ms"]))
    row("descriptor", "describe (full view)", lambda e: _ms(e["descriptor"]["describe_ms"]))
    for key, label in STAGES:
        row("control step", label, lambda e, key=key: _ms(e["control_step"]["stages"][key]))
    row("control step", "describe + decide (robot side)",
        lambda e: f"{controller_ms(e['control_step'])['median']:.1f} ms median")
    row("control step", "sum of stages", lambda e: f"{e['control_step']['total_ms']['median']:.1f} ms median "
                                                   f"(period {e['control_step']['control_period_ms']:.0f})")
    row("control step", "episode wall / step", lambda e: f"{e['control_step']['wall_ms_per_step']:.1f} ms "
                                                         f"({e['control_step']['steps']} steps)")
    if "control_step_rerun" in first:
        row("viewer", "log one step (--rerun)", lambda e: _ms(e["control_step_rerun"]["viewer"]["log_ms"])
            if "control_step_rerun" in e else "")
        row("viewer", "episode wall / step, recording", lambda e: f"{e['control_step_rerun']['wall_ms_per_step']:.1f} ms "
            f"({e['control_step_rerun']['viewer']['rrd_bytes_per_step'] / 1024:.0f} KiB .rrd per step)"
            if "control_step_rerun" in e else "")
    row("mapping", "video -> map", lambda e: f"{e['mapping']['fps_median']:.1f} frames/s "
                                             f"({e['mapping']['frames']} frames)")
    row("mapping", "nodes of the video's map", lambda e: f"{e['mapping']['nodes']}")
    ratios = {}
    for key, ratio in report["speedup"].items():
        ratios[f"describe_thirds {w}x{h}, batch 1"] = ratio["describe_thirds"]
        ratios["describe"] = ratio["control_describe"]
        ratios["video -> map"] = ratio["mapping_fps"]
    s = report["map_size"]
    table = [("section", "quantity", labels + (["ratio"] if len(labels) > 1 else []))]
    for section, quantity, values in rows:
        extra = [f"{ratios[quantity]:.2f}x" if quantity in ratios else ""] if len(labels) > 1 else []
        table.append((section, quantity, values + extra))
    single = [("map size", "episode map folder / nodes", f"{s['bytes_per_node'] / 1024:.1f} KiB per node "
                                                         f"({s['folder_bytes'] / 1024:.0f} KiB / {s['nodes']} nodes)"),
              ("map size", "growing part per node", f"{s['growing_bytes_per_node'] / 1024:.1f} KiB "
                                                    "(manifest + descriptors + thumbnails)")]
    single += [("memory", f"peak RSS after {k}", f"{mb:.0f} MB") for k, mb in report["memory"]["peak_rss_mb_after"].items()]
    widths = [max(len(r[i]) for r in table + [(a, b, []) for a, b, _ in single]) for i in range(2)]
    cols = [max(len(r[2][k]) for r in table) for k in range(len(table[0][2]))]
    lines = [f"{a:<{widths[0]}}  {b:<{widths[1]}}  " + "  ".join(f"{v:<{cols[k]}}" for k, v in enumerate(vals))
             for a, b, vals in table]
    lines += [f"{a:<{widths[0]}}  {b:<{widths[1]}}  {v}" for a, b, v in single]
    lines.insert(1, "-" * max(len(line) for line in lines))
    return "\n".join(line.rstrip() for line in lines)


def _header(report: dict) -> list[str]:
    r = report["run"]
    first = next(iter(report["engines"].values()))
    lines = [f"world {r['world']}, route {r['route']} (appearance seed {r['appearance_seed']}); "
             f"descriptor {first['descriptor']['backend']} (dim {first['descriptor']['dim']}); "
             f"engines: {', '.join(report['engines'])}",
             f"threads: inference {r['inference_threads']}, OPENBLAS_NUM_THREADS={r['openblas_num_threads']}, "
             f"OpenCV {r['cv2_threads']}",
             f"video: {first['mapping']['video']} ({'given' if r['video_given'] else 'rendered drive'}); "
             f"map for the episode: {first['control_step']['map']} ({'given' if r['map_given'] else 'built here'}), "
             f"goal {first['control_step']['goal']}"]
    return lines


def run(args: argparse.Namespace, settings: PerfSettings, work: Path) -> dict:
    """Every section of the report as a JSON-ready dict; files go under ``work``."""
    from descriptors.inference import set_threads
    from robot.settings import load_stack_config
    from sim.worlds import load_world

    config = load_stack_config(args.config)
    world = load_world(args.world)
    route = _pick_route(world, args.route)
    runs = engine_configs(config, settings.engines)
    set_threads(settings.threads)
    progress = not args.quiet
    started = time.perf_counter()
    memory: dict[str, float] = {}

    if args.video is not None:
        video = args.video
        frames = video_frames(video, 4 * FIT_FRAMES)
    else:
        frames = drive_route(world, route, config, args.appearance_seed, progress)
        fps = 1.0 / (config.sim.control_period_s * config.recording.every_n_ticks)
        video = write_video(frames, work / VIDEO_NAME, fps)
    memory["drive"] = peak_rss_mb()

    described = time_descriptors(runs, frames, settings.repeats)
    memory["descriptor timing"] = peak_rss_mb()
    engines: dict[str, dict] = {}
    map_dir: Optional[Path] = args.map
    goal_node = args.goal
    for label, engine_config in runs:
        section: dict = {"descriptor": described[label]}
        map_dirs = [work / f"{MAP_NAME}.{label}.{i}" for i in range(settings.map_repeats)]
        section["mapping"] = time_mapping(video, engine_config, map_dirs, progress)
        if map_dir is None:             # the first engine's map is the episode's (and the size's)
            map_dir = work / MAP_NAME
            shutil.copytree(map_dirs[0], map_dir)
            goal_node = args.goal if args.goal is not None else last_node(map_dir)
        for done in map_dirs:
            shutil.rmtree(done, ignore_errors=True)
        memory[f"mapping ({label})"] = peak_rss_mb()
        # A given map is navigated to the image at the route's goal, like robot.run --mode navigate
        # --route. The map built here covers the drive only, which may stop short of seeing the goal
        # view; its last node is the drive's end, a goal it certainly has.
        section["control_step"] = time_control_steps(world, map_dir, engine_config, route, settings.steps,
                                                     args.appearance_seed, progress, goal_node)
        memory[f"control steps ({label})"] = peak_rss_mb()
        if args.rerun and not engines:      # the same episode again, recorded for the viewer
            section["control_step_rerun"] = time_control_steps(world, map_dir, engine_config, route, settings.steps,
                                                               args.appearance_seed, progress, goal_node,
                                                               rrd=work / "perf.rrd")
            memory[f"control steps with the viewer ({label})"] = peak_rss_mb()
        engines[label] = section
    del frames

    return {
        "command": "perf",
        "run": {"world": world.name, "route": route, "appearance_seed": args.appearance_seed,
                "inference_threads": "engine default" if settings.threads is None else settings.threads,
                "openblas_num_threads": os.environ.get("OPENBLAS_NUM_THREADS", "unset"),
                "cv2_threads": cv2.getNumThreads(), "video_given": args.video is not None,
                "map_given": args.map is not None, "repeats": settings.repeats, "steps": settings.steps,
                "map_repeats": settings.map_repeats, "wall_s": time.perf_counter() - started},
        "engines": engines,
        "speedup": speedups(engines),
        "map_size": map_bytes(map_dir),
        "memory": {"peak_rss_mb": peak_rss_mb(), "peak_rss_mb_after": memory},
    }


def controller_ms(control: dict) -> dict:
    """What the robot's own computer spends per step: describe + decide (the simulator's render
    and physics excluded), from the per-stage means and medians."""
    st = control["stages"]
    return {"mean": st["describe_ms"]["mean"] + st["decide_ms"]["mean"],
            "median": st["describe_ms"]["median"] + st["decide_ms"]["median"]}


def speedups(engines: dict) -> dict:
    """How many times faster the first engine is than each other one (medians; >1: faster)."""
    labels = list(engines)
    out = {}
    for other in labels[1:]:
        a, b = engines[labels[0]], engines[other]
        out[f"{labels[0]}_vs_{other}"] = {
            "describe_thirds": b["descriptor"]["describe_thirds_ms"]["median"]
            / a["descriptor"]["describe_thirds_ms"]["median"],
            "control_describe": b["control_step"]["stages"]["describe_ms"]["median"]
            / a["control_step"]["stages"]["describe_ms"]["median"],
            "mapping_fps": a["mapping"]["fps_median"] / b["mapping"]["fps_median"],
        }
    return out


def _input_errors() -> tuple[type[BaseException], ...]:
    """Errors a user causes with options or files: exit 2."""
    from controllers.planner import UnknownNodeError
    from core.configfile import ConfigError
    from descriptors.base import DescriptorError
    from maps.graph import MapError
    from robot.episode.goal import GoalImageError
    from robot.episode.setup import DescriptorMismatchError
    from robot.episode.start import StartError
    from robot.mapping.sources import FrameSourceError

    return (PerfInputError, ConfigError, MapError, DescriptorError, FrameSourceError, DescriptorMismatchError,
            GoalImageError, StartError, UnknownNodeError)


def _run_errors() -> tuple[type[BaseException], ...]:
    """Errors of the runs themselves (a drive that cannot finish, a goal not recognised): exit 1."""
    from controllers.localisation import GoalNotLocalisedError
    from controllers.planner import UnreachableGoalError
    from core.hal import HalError
    from robot.mapping.drive import DriveError

    return (DriveError, HalError, GoalNotLocalisedError, UnreachableGoalError)


def main(args: argparse.Namespace) -> int:
    from robot.threads import limit_helper_threads

    limit_helper_threads()     # also when main() is called without the dispatcher
    try:
        settings = settings_from(args)
    except PerfInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    work = args.out if args.out is not None else Path(tempfile.mkdtemp(prefix="robot-perf-"))
    try:
        work.mkdir(parents=True, exist_ok=True)
        report = run(args, settings, work)
    except _input_errors() as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except _run_errors() as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    finally:
        if args.out is None:
            shutil.rmtree(work, ignore_errors=True)
    if args.out is None:    # the temporary files are gone; say so rather than point at nothing
        for section in report["engines"].values():
            if args.video is None:
                section["mapping"]["video"] = "(temporary, removed)"
            if args.map is None:
                section["control_step"]["map"] = report["map_size"]["map"] = "(temporary, removed)"
    print("\n".join(_header(report)))
    print()
    print(format_report(report))
    print(f"\nwall time {report['run']['wall_s']:.1f} s")
    if args.json is not None:
        write_json(args.json, report)
        print(f"wrote {args.json}")
    return 0
