"""``python -m robot.bench sim``: time one control step of the simulated Limo.

For each scene (a plain floor, and the world named by ``--world``) and each image size, the
robot drives a slow circle for ``--steps`` control periods; every period the physics step
(``tick()``: ``control_period_s / physics_dt_s`` PyBullet steps plus odometry and collision
bookkeeping) and the camera render (``read()``) are timed separately. Prints median and p90
milliseconds per control step as a table; the sum tells how far from real time (100 ms at 10 Hz)
the simulation runs on this machine.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Any, Callable, Optional

import numpy as np
from tqdm import tqdm

from core.hal import Pose2D, VelocityCommand
from sim.config import SimConfig
from sim.hal import SimLimo

_WARMUP_STEPS = 3      # the first renders load textures into TinyRenderer's caches


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--steps", type=int, default=50, help="control steps timed per row (default 50)")
    parser.add_argument("--width", type=int, nargs="*", default=[],
                        help="extra image widths to time, paired with --height (320x240 is always timed)")
    parser.add_argument("--height", type=int, nargs="*", default=[],
                        help="extra image heights, one per --width")
    parser.add_argument("--world", default=None, metavar="NAME",
                        help="also time this world (configs/worlds/NAME.yaml, or a path to a world YAML)")
    parser.add_argument("--appearance-seed", type=int, default=0, help="appearance seed of --world (default 0)")


def _sizes(args: argparse.Namespace) -> list[tuple[int, int]]:
    if len(args.width) != len(args.height):
        raise ValueError(f"--width and --height must come in pairs, got {len(args.width)} widths "
                         f"and {len(args.height)} heights")
    sizes = [(320, 240)]
    for size in zip(args.width, args.height):
        if size not in sizes:
            sizes.append(size)
    return sizes


def _load_world(name: str) -> tuple[Any, Pose2D]:
    """(world description, start pose) of the world ``name``, via the world modules.

    Kept apart from the timing code: the world side (sim.world_spec / sim.world) is optional here.
    The robot starts on the walkthrough's first waypoint, facing the second.
    """
    try:
        import sim.world  # noqa: F401  (SimLimo.connect imports build_world from it)
        from sim.worlds import load_world
    except ImportError as exc:
        raise ValueError(f"--world {name}: the world modules are not available ({exc})") from None
    spec = load_world(name)           # its WorldError (a ValueError) names the file and field
    (x0, y0), (x1, y1) = spec.routes.walkthrough[0], spec.routes.walkthrough[1]
    return spec, Pose2D(x0, y0, math.atan2(y1 - y0, x1 - x0))


def _time_ms(fn: Callable[[], Any]) -> float:
    t0 = time.perf_counter()
    fn()
    return (time.perf_counter() - t0) * 1000.0


def time_scene(config: SimConfig, steps: int, world: Any = None, start: Optional[Pose2D] = None,
               appearance_seed: int = 0, label: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Per-control-step times in ms: (physics, render) arrays of length ``steps``."""
    kwargs = {"world": world, "appearance_seed": appearance_seed}
    if start is not None:
        kwargs["start"] = start
    physics, render = [], []
    with SimLimo(config, **kwargs) as base:
        base.apply(VelocityCommand(0.2, 0.3))          # a slow circle, so the view changes every step
        for _ in range(_WARMUP_STEPS):
            base.tick()
            base.read()
        for _ in tqdm(range(steps), desc=label, leave=False, file=sys.stderr):
            physics.append(_time_ms(base.tick))
            render.append(_time_ms(base.read))
    return np.asarray(physics), np.asarray(render)


def main(args: argparse.Namespace) -> int:
    try:
        sizes = _sizes(args)
        if args.steps < 1:
            raise ValueError(f"--steps must be >= 1, got {args.steps}")
        scenes: list[tuple[str, Any, Any]] = [("plain floor", None, None)]
        if args.world:
            world, start = _load_world(args.world)
            scenes.append((args.world, world, start))
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    defaults = SimConfig()
    print(f"control period {defaults.control_period_s * 1000:.0f} ms = {defaults.steps_per_tick} physics steps "
          f"of {defaults.physics_dt_s * 1000:.2f} ms; TinyRenderer, DIRECT mode; {args.steps} steps per row")
    header = f"{'scene':<14} {'image':>9} {'physics med':>12} {'physics p90':>12} {'render med':>11} {'render p90':>11}"
    print(header)
    print("-" * len(header))
    for name, world, start in scenes:
        for width, height in sizes:
            config = SimConfig(width_px=width, height_px=height)
            physics, render = time_scene(config, args.steps, world, start, args.appearance_seed,
                                         label=f"{name} {width}x{height}")
            print(f"{name:<14} {f'{width}x{height}':>9} {np.median(physics):>9.2f} ms {np.percentile(physics, 90):>9.2f} ms "
                  f"{np.median(render):>8.2f} ms {np.percentile(render, 90):>8.2f} ms", flush=True)
    return 0
