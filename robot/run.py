"""The product's entry point: ``python -m robot.run --mode map|navigate|show``.

    python -m robot.run --mode map [--world hospital] [--out DIR]   # teleop drive, then the map
    python -m robot.run --mode map --video FILE [--every-s 0.5]     # a map from a video, no robot
    python -m robot.run --mode map --images DIR [--every 2]         # a map from an image folder
    python -m robot.run --mode show --map DIR                       # the map's pictures
    python -m robot.run --mode navigate --map DIR --route easy      # drive a route of the world
    python -m robot.run --mode navigate --map DIR --goal 12 --start node:40 --result r.json
    python -m robot.run --mode navigate --map DIR --goal goal.jpg --hal serial --port /dev/ttyTHS1 --camera 0

Configuration is read once here (``configs/default.yaml`` or ``--config FILE``) and passed down.
Every error a user can cause ends in one clear line on stderr and exit status 2, before the robot
moves or anything is written (paths are checked first); the robot is commanded to zero velocity on
every way out: Ctrl-C (130), SIGTERM (143), SIGHUP (129) and errors.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from core.cli import (
    EXIT_FAILED,
    EXIT_USAGE,
    Parser,
    UsageError,
    check_output_file,
    check_output_folder,
    existing_file,
    existing_folder,
    non_negative_int,
    positive_float,
    positive_int,
)
from robot.viewer.stream import add_viewer_arguments


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="python -m robot.run",
        description="Teach a route by driving it once, then navigate it with one camera.")
    parser.add_argument("--mode", required=True, choices=["map", "navigate", "show"],
                        help="map: drive the world's walkthrough with the scripted teleoperator, record it and "
                             "build the topological map (or map a --video / --images without a robot); "
                             "navigate: drive to a goal node or goal image of a map; show: draw a map's pictures")
    parser.add_argument("--world", default="hospital",
                        help="a world name from configs/worlds (hospital, office, warehouse, garage) or a path "
                             "to a world YAML file")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default runs/<world>/)")
    parser.add_argument("--config", type=Path, default=None,
                        help="stack configuration YAML (default configs/default.yaml)")
    parser.add_argument("--appearance-seed", type=non_negative_int, default=0,
                        help="lighting and prop placement of the world (0 = as written in its YAML)")
    parser.add_argument("--seed", type=non_negative_int, default=None,
                        help="simulator noise seed (overrides sim.seed of the configuration)")
    parser.add_argument("--gui", action="store_true", help="open the PyBullet window (needs a display)")
    source = parser.add_argument_group("mapping from a recording (no robot)")
    src = source.add_mutually_exclusive_group()
    src.add_argument("--video", type=Path, help="build the map from this video file")
    src.add_argument("--images", type=Path, help="build the map from the images of this folder (name order)")
    src.add_argument("--recording", type=Path, help="build the map from a drive recorded earlier by --mode map")
    sampling = source.add_mutually_exclusive_group()
    sampling.add_argument("--every", type=positive_int, default=1, metavar="N", help="keep every Nth frame (default 1)")
    sampling.add_argument("--every-s", type=positive_float, default=None, metavar="S",
                          help="keep one frame every S seconds")
    parser.add_argument("--map", type=Path, default=None,
                        help="map folder (default <out>/map); for --mode show, the map to draw")
    parser.add_argument("--no-map", action="store_true", help="--mode map: record the drive only")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    nav = parser.add_argument_group("navigation (--mode navigate)")
    nav.add_argument("--goal", default=None,
                     help="goal: a node id of the map or a path to a goal image (default with --route: the image "
                          "the camera sees at the route's goal pose)")
    nav.add_argument("--route", default=None,
                     help="an evaluation route of the world: start at its start pose; without --goal, its goal")
    nav.add_argument("--start", default=None,
                     help="simulator start: a route name, x,y,yaw_deg (metres, degrees) or node:ID (a map node's "
                          "true pose: a kidnapped start); default the route's start")
    nav.add_argument("--result", type=Path, default=None,
                     help="write the episode's metrics as JSON here (success, distance to goal, SPL, timings, nodes)")
    nav.add_argument("--trace", type=Path, default=None,
                     help="top-down picture of the drive over the map (simulator; default <out>/navigation.png)")
    nav.add_argument("--record-video", type=Path, default=None, metavar="MP4",
                     help="write the camera view with overlays (nodes, scores, action, state) as MP4")
    nav.add_argument("--max-steps", type=positive_int, default=None,
                     help="step budget, >= 1 (default from the route length)")
    hal = parser.add_argument_group("robot base")
    hal.add_argument("--hal", choices=["sim", "serial", "serial-twin"], default="sim",
                     help="sim: the PyBullet Limo; serial: a Limo base on --port with --camera; serial-twin: "
                          "the PyBullet Limo behind the base emulator on a pseudo-terminal, every command "
                          "crossing the serial backend as bytes")
    hal.add_argument("--port", default=None,
                     help="--hal serial: the base's serial device or a pyserial URL (default: the config's "
                          "serial.port, /dev/ttyTHS1)")
    hal.add_argument("--baud", type=positive_int, default=None,
                     help="--hal serial: baud rate (default: the config's serial.baud, 460800)")
    hal.add_argument("--camera", default=None,
                     help="--hal serial: camera device index, stream URL or video file (default: serial.camera)")
    add_viewer_arguments(parser)
    return parser


def _make_descriptor(config):
    from descriptors.factory import make_descriptor

    return make_descriptor(config.descriptor.backend, **config.descriptor.settings)


def _print_map_summary(summary: dict, map_dir: Path) -> None:
    metres = summary.get("mean_arc_length_m")
    spacing = f", mean spacing {metres:.2f} m" if metres else ""
    print(f"map: {summary['frames_read']} frames read -> {summary['nodes']} nodes "
          f"({summary.get('nodes_before_merge', summary['nodes'])} before merging), "
          f"{_count(summary.get('loop_closures', 0))} loop closures{spacing} -> {map_dir}")
    print(f"  pictures: {map_dir / 'map.png'}  {map_dir / 'similarity.png'}")
    for warning in summary.get("warnings", []):
        print(f"  warning: {warning}")


def _count(value) -> int:
    return len(value) if isinstance(value, (list, tuple)) else int(value)


def _mode_map(args, config) -> int:
    from core.atomic import write_json
    from robot.mapping.make import build_map_from_frames, world_picture_of
    from robot.mapping.sources import ImageFolderSource, RecordingSource, Sampling, VideoSource

    sampling = Sampling(every_n=args.every, every_s=args.every_s)
    world_picture = None
    if args.video or args.images:
        source = VideoSource(args.video, sampling) if args.video else ImageFolderSource(args.images, sampling)
        name = (args.video or args.images).stem
        out = args.out if args.out is not None else Path("runs") / name
        summary: dict = {}
    elif args.recording:
        out = args.recording
        summary = _read_summary(out / "summary.json")
        source = RecordingSource(out, sampling)
        world_picture = world_picture_of(summary.get("world"), int(summary.get("appearance_seed", 0)))
    else:
        from robot.mapping.drive import drive_walkthrough
        from sim.worlds import load_world

        world = load_world(args.world)
        out = args.out if args.out is not None else Path("runs") / world.name
        result = drive_walkthrough(world, config, out, appearance_seed=args.appearance_seed, progress=not args.quiet)
        summary = result.summary
        print(f"recorded {summary['frames']} frames, {summary['metres_driven']:.1f} m in "
              f"{summary['duration_s']:.0f} s simulated, {summary['collisions']} collisions -> {out}")
        print(f"  summary: {out / 'summary.json'}   picture: {out / 'world.png'}")
        if args.no_map:
            return 0
        source = RecordingSource(out, sampling)
        world_picture = world_picture_of(world, args.appearance_seed)
    map_dir = args.map if args.map is not None else out / "map"
    built = build_map_from_frames(source, _make_descriptor(config), config.mapping, map_dir, total=len(source),
                                  world_picture=world_picture, fit_max_frames=config.descriptor.fit_max_frames,
                                  source=source.description, progress=not args.quiet, viewer=args.viewer,
                                  extra={k: summary[k] for k in ("world", "appearance_seed") if k in summary})
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "summary.json", {**summary, "map": str(map_dir), **built.summary})
    _print_map_summary(built.summary, map_dir)
    return 0


def _read_summary(path: Path) -> dict:
    """A recording's summary.json (empty when there is none); a broken one is a usage error."""
    if not path.is_file():
        return {}
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: not a readable summary of a recording ({exc})") from None
    if not isinstance(summary, dict):
        raise UsageError(f"{path}: expected a JSON object (the summary of a recording)")
    return summary


def _mode_show(args, config) -> int:
    from robot.mapping.make import draw_saved_map

    if args.map is None:
        raise UsageError("--mode show needs --map DIR")
    for path in draw_saved_map(args.map):
        print(f"wrote {path}")
    return 0


def _mode_navigate(args, config) -> int:
    from robot.episode.metrics import format_summary

    if args.map is None:
        raise UsageError("--mode navigate needs --map DIR (build one with --mode map)")
    if args.hal == "serial":
        metrics = _navigate_serial(args, config)
    else:
        metrics = _navigate_sim(args, config)
    if args.result is None:
        print(format_summary(metrics))
    else:
        print(f"{'success' if metrics.success else 'failure'}: {metrics.reason} -> {args.result}")
    return 0 if (metrics.success or (args.hal == "serial" and metrics.arrived)) else EXIT_FAILED


def _navigate_sim(args, config):
    from robot.episode.sim import EpisodeOutputs, SimEpisode, run_sim_navigation
    from robot.episode.start import parse_start

    if args.goal is None and args.route is None:
        raise UsageError("--mode navigate needs --goal (node id or image) or --route NAME")
    make_base = None
    if args.hal == "serial-twin":
        from sim.serial_twin import SerialTwinLimo

        def make_base(sim_config, start, world, appearance_seed):
            return SerialTwinLimo(world, sim_config, start, appearance_seed=appearance_seed)
    out = args.out if args.out is not None else args.map.parent
    episode = SimEpisode(args.world, args.map, goal=args.goal, route=args.route,
                         start=parse_start(args.start) if args.start is not None else None,
                         appearance_seed=args.appearance_seed, max_steps=args.max_steps)
    outputs = EpisodeOutputs(result_path=args.result,
                             trace_png=args.trace if args.trace is not None else out / "navigation.png",
                             video_path=args.record_video, viewer=args.viewer, progress=not args.quiet)
    result = run_sim_navigation(episode, _make_descriptor(config), config, outputs, make_base=make_base)
    if result.goal.rivals:
        print(f"warning: the goal image also resembles node(s) {', '.join(map(str, result.goal.rivals))} almost as "
              f"much as its node {result.goal.node} (other places; a more distinctive goal picture is safer)",
              file=sys.stderr)
    return result.metrics


def _navigate_serial(args, config):
    """A real Limo (or an emulator on a pty): goal node or image, no ground truth."""
    from dataclasses import replace

    from core.atomic import write_json
    from limo.serial_base import LimoSerialBase
    from maps.store import load_map
    from robot.episode.config import step_budget
    from robot.episode.goal import parse_goal, resolve_goal
    from robot.episode.loop import run_episode
    from robot.episode.metrics import compute_metrics
    from robot.episode.setup import attach_descriptor, configure_navigation
    from robot.viewer.navigation import navigation_viewer

    if args.goal is None:
        raise UsageError("--hal serial needs --goal (a node id or a goal image); routes exist only in simulation")
    loaded = load_map(args.map)
    descriptor = attach_descriptor(loaded, _make_descriptor(config))
    nav = configure_navigation(loaded, config.navigation, config.episode)
    goal = resolve_goal(parse_goal(args.goal), loaded.topomap, descriptor, nav)
    overrides = {k: v for k, v in (("port", args.port), ("baud", args.baud), ("camera", args.camera))
                 if v is not None}
    serial_config = replace(config.serial, **overrides)
    budget = args.max_steps if args.max_steps is not None else step_budget(config.episode, nav,
                                                                          serial_config.control_period_s)
    with navigation_viewer(args.viewer, f"navigate {serial_config.port}", loaded.topomap) as viewer, \
            LimoSerialBase(serial_config) as base:
        if viewer is not None:
            viewer.setup(goal.node, goal.image, goal.source)
        outcome = run_episode(base, loaded.topomap, descriptor, goal.node, nav, budget,
                              observer=None if viewer is None else viewer.observer,
                              goal_descriptor=goal.descriptor, node_columns=loaded.columns)
    metrics = compute_metrics(outcome)
    if args.result is not None:
        write_json(args.result, {**metrics.to_dict(), "setup": {"map": str(args.map), "goal": goal.source,
                                                                        "goal_node": goal.node,
                                                                        "port": serial_config.port}})
    return metrics


def _navigation_input_errors() -> tuple[type[BaseException], ...]:
    """Errors a user causes with navigation arguments: exit 2."""
    from controllers.planner import UnknownNodeError
    from robot.episode.goal import GoalImageError
    from robot.episode.start import StartError
    from sim.world_spec import WorldError

    return (UnknownNodeError, GoalImageError, StartError, WorldError)


def _navigation_run_errors() -> tuple[type[BaseException], ...]:
    """Errors of the run itself (a goal the robot cannot reach or recognise): exit 1."""
    from controllers.localisation import GoalNotLocalisedError
    from controllers.planner import UnreachableGoalError

    return (GoalNotLocalisedError, UnreachableGoalError)


def check_paths(args: argparse.Namespace) -> None:
    """Every file and folder argument, before any work: inputs exist and are what they must be
    (a file, a folder), outputs can be written (:class:`UsageError` naming the option)."""
    existing_file("--config", args.config, "YAML file")
    existing_file("--video", args.video, "video file")
    existing_folder("--images", args.images, "folder of images")
    existing_folder("--recording", args.recording, "recording folder")
    check_output_folder("--out", args.out)
    if args.mode == "map":
        check_output_folder("--map", args.map)
        if args.map is not None and args.map.is_dir() and any(args.map.iterdir()) \
                and not (args.map / "manifest.json").is_file():
            raise UsageError(f"--map {args.map}: exists and is not a map folder; choose another folder")
    else:
        existing_folder("--map", args.map, "map folder")
    for option, path in (("--result", args.result), ("--trace", args.trace), ("--record-video", args.record_video)):
        check_output_file(option, path)
    if args.goal is not None and not str(args.goal).strip().lstrip("-").isdigit():
        existing_file("--goal", Path(args.goal), "goal image file (or a node id)")
    if args.goal is not None and str(args.goal).strip().startswith("-") and str(args.goal).strip()[1:].isdigit():
        raise UsageError(f"--goal {args.goal}: node ids are >= 0")


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from core.shutdown import exit_status, interrupted_by, stop_on_signals

    stop_on_signals()        # SIGTERM / SIGHUP end through the same cleanup as Ctrl-C
    from robot.threads import limit_helper_threads

    limit_helper_threads()
    from dataclasses import replace

    from core.configfile import ConfigError
    from core.hal import HalError
    from descriptors.base import DescriptorError
    from maps.graph import MapError
    from robot.mapping.recording import RecordingError
    from robot.mapping.sources import FrameSourceError
    from robot.settings import load_stack_config
    from robot.viewer.stream import viewer_target

    # the drive's error type comes with the simulator: only the mapping run needs it (the real
    # base's navigation never loads pybullet)
    drive_errors = _drive_errors() if args.mode == "map" else ()

    try:
        check_paths(args)
        args.viewer = viewer_target(args)
        config = load_stack_config(args.config)
        if args.seed is not None or args.gui:
            sim = replace(config.sim, seed=config.sim.seed if args.seed is None else args.seed,
                          gui=args.gui or config.sim.gui)
            config = replace(config, sim=sim)
        return {"map": _mode_map, "navigate": _mode_navigate, "show": _mode_show}[args.mode](args, config)
    except (ConfigError, RecordingError, FrameSourceError, MapError, DescriptorError, UsageError,
            *_navigation_input_errors()) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (*drive_errors, HalError, *_navigation_run_errors()) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE if _is_port_error(exc) else EXIT_FAILED
    except KeyboardInterrupt as exc:
        saved = getattr(args, "viewer", None) and args.viewer.save_path
        kept = f"only the recording of the steps made, {saved}, was written" if saved else "nothing was written"
        print(f"{interrupted_by(exc)}: the robot was stopped; {kept}", file=sys.stderr)
        return exit_status(exc)


def _drive_errors() -> tuple[type[BaseException], ...]:
    from robot.mapping.drive import DriveError

    return (DriveError,)


def _is_port_error(exc: BaseException) -> bool:
    """A serial port that cannot be opened is an argument that cannot work (exit 2)."""
    from limo.serial_base import PortError

    return isinstance(exc, PortError)


if __name__ == "__main__":
    sys.exit(main())
