"""The teleop mapping drive in the simulator: drive a world's walkthrough and record it.

The scripted teleoperator (the stand-in for a person with a joystick) steers from ground truth;
the recording keeps the camera frames with their timestamps and odometry, plus the true poses,
which are for evaluation and pictures only. Everything the drive needs comes in as arguments;
the command line lives in :mod:`robot.run`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from core.hal import Pose2D
from robot.mapping.recording import RecordingWriter
from robot.settings import StackConfig
from sim.hal import SimLimo
from sim.teleop import WaypointTeleop
from sim.topdown import render_topdown
from sim.world_spec import WorldSpec


class DriveError(RuntimeError):
    """The walkthrough could not be completed (time budget, toppled robot)."""


@dataclass(frozen=True)
class DriveResult:
    out_dir: Path
    summary: dict


def walkthrough_start(world: WorldSpec) -> Pose2D:
    """The first walkthrough waypoint, facing the second."""
    (x0, y0), (x1, y1) = world.routes.walkthrough[:2]
    return Pose2D(x0, y0, math.atan2(y1 - y0, x1 - x0))


def drive_walkthrough(world: WorldSpec, config: StackConfig, out_dir: str | Path,
                      appearance_seed: int = 0, progress: bool = True) -> DriveResult:
    """Drive ``world``'s walkthrough with the scripted teleoperator and record it to ``out_dir``.

    The recording appears at ``out_dir`` only when the drive finished; on any error (or Ctrl-C)
    the robot is stopped, the partial recording dropped and an earlier one left untouched.
    """
    out_dir = Path(out_dir)
    teleop = WaypointTeleop(world.routes.walkthrough, config.teleop)
    period = config.sim.control_period_s
    max_ticks = int(math.ceil(config.recording.time_budget_factor * teleop.length_m
                              / config.teleop.cruise_v_mps / period)) + 100
    writer = RecordingWriter(out_dir, jpeg_quality=config.recording.jpeg_quality)
    trace: list[tuple[float, float]] = []
    base = SimLimo(config.sim, start=walkthrough_start(world), world=world, appearance_seed=appearance_seed)
    bar = tqdm(total=round(teleop.length_m, 1), unit="m", desc=f"driving {world.name}", disable=not progress,
               bar_format="{l_bar}{bar}| {n:.1f}/{total:.1f} m [{elapsed}<{remaining}]")
    try:
        with base:
            truth = base.ground_truth
            ticks = 0
            while True:
                pose = truth.true_pose()
                if teleop.done(pose):
                    break
                if ticks >= max_ticks:
                    raise DriveError(
                        f"the walkthrough of {world.name!r} was not finished within {max_ticks} control ticks "
                        f"({max_ticks * period:.0f} s simulated); stuck at x={pose.x_m:.2f}, y={pose.y_m:.2f} "
                        f"after {teleop.progress_m:.1f} of {teleop.length_m:.1f} m")
                if truth.toppled():
                    raise DriveError(f"the robot toppled at x={pose.x_m:.2f}, y={pose.y_m:.2f}")
                if ticks % config.recording.every_n_ticks == 0:
                    writer.append(base.read(), pose)
                    trace.append((pose.x_m, pose.y_m))
                base.apply(teleop.command(pose))
                base.tick()
                ticks += 1
                bar.n = round(min(teleop.progress_m, teleop.length_m), 1)
                bar.refresh() if ticks % 10 == 0 else None
            collisions = truth.collision_count()
            writer.append(base.read(), truth.true_pose())
            trace.append((truth.true_pose().x_m, truth.true_pose().y_m))
    except BaseException:
        writer.abort()
        raise
    finally:
        bar.close()

    picture = render_topdown(world, appearance_seed=appearance_seed)
    picture.draw_polyline(trace, color=(220, 30, 30), thickness=2)
    picture.draw_marker(*trace[0], color=(220, 30, 30), label="drive start")
    picture.save_png(writer.path / "world.png")
    summary = writer.finish({
        "world": world.name,
        "appearance_seed": appearance_seed,
        "sim_seed": config.sim.seed,
        "control_period_s": period,
        "record_every_n_ticks": config.recording.every_n_ticks,
        "collisions": collisions,
        "walkthrough_length_m": round(teleop.length_m, 3),
    })
    return DriveResult(out_dir=out_dir, summary=summary)
