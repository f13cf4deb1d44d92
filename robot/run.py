"""The product's entry point: ``python -m robot.run --mode map|...``.

    python -m robot.run --mode map [--world hospital] [--out DIR]   # teleop mapping run

Configuration is read once here (``configs/default.yaml`` or ``--config FILE``) and passed down.
Every error a user can cause ends in one clear line on stderr and a non-zero exit code; the
robot is commanded to zero velocity on every way out, Ctrl-C included.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

EXIT_USAGE = 2        # bad arguments, configuration or input files
EXIT_FAILED = 1       # the run itself failed (robot stuck, toppled, lost)
EXIT_INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m robot.run",
        description="Teach a route by driving it once, then navigate it with one camera.")
    parser.add_argument("--mode", required=True, choices=["map"],
                        help="map: drive the world's walkthrough with the scripted teleoperator and record it")
    parser.add_argument("--world", default="hospital",
                        help="a world name from configs/worlds (hospital, office) or a path to a world YAML file")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default runs/<world>/)")
    parser.add_argument("--config", type=Path, default=None,
                        help="stack configuration YAML (default configs/default.yaml)")
    parser.add_argument("--appearance-seed", type=int, default=0,
                        help="lighting and prop placement of the world (0 = as written in its YAML)")
    parser.add_argument("--seed", type=int, default=None,
                        help="simulator noise seed (overrides sim.seed of the configuration)")
    parser.add_argument("--gui", action="store_true", help="open the PyBullet window (needs a display)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def _mode_map(args, config) -> int:
    from sim.world_spec import load_world
    from robot.walkthrough import drive_walkthrough

    world = load_world(args.world)
    out = args.out if args.out is not None else Path("runs") / world.name
    result = drive_walkthrough(world, config, out, appearance_seed=args.appearance_seed, progress=not args.quiet)
    s = result.summary
    print(f"recorded {s['frames']} frames, {s['metres_driven']:.1f} m in {s['duration_s']:.0f} s simulated, "
          f"{s['collisions']} collisions -> {result.out_dir}")
    print(f"  summary: {result.out_dir / 'summary.json'}   picture: {result.out_dir / 'world.png'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from dataclasses import replace

    from robot.configfile import ConfigError
    from robot.hal import HalError
    from robot.recording import RecordingError
    from robot.settings import load_stack_config
    from robot.walkthrough import DriveError

    try:
        config = load_stack_config(args.config)
        if args.seed is not None or args.gui:
            sim = replace(config.sim, seed=config.sim.seed if args.seed is None else args.seed,
                          gui=args.gui or config.sim.gui)
            config = replace(config, sim=sim)
        return {"map": _mode_map}[args.mode](args, config)
    except (ConfigError, RecordingError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (DriveError, HalError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print("interrupted: the robot was stopped; nothing was written", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
