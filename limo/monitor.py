"""``python -m limo.monitor``: watch a Limo base's feedback (battery, error bits, wheels, gyro,
link counters) while streaming zero velocity: the first-run checklist's tool."""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Optional

from core.configfile import ConfigError, load_config
from core.hal import HalError
from limo.protocol import describe_error_bits
from limo.serial_base import LimoSerialBase, LimoSerialConfig


def main(argv: Optional[list] = None) -> int:
    """Print the base's feedback while commanding zero velocity; exit status 0, 1 (link), 2 (input)."""
    parser = argparse.ArgumentParser(
        prog="python -m limo.monitor",
        description="Connect to a Limo base (or the emulator) and print its feedback: battery, error "
                    "bits, wheel odometry, gyro yaw rate, fused heading, link counters. Streams ZERO "
                    "velocity the whole time: use it for the first-run checklist (README, 'Running on a real Limo').")
    parser.add_argument("--config", help="LimoSerialConfig YAML (port, baud, odometry_unit_m, ...)")
    parser.add_argument("--port", help="device or pyserial URL; overrides the config (default /dev/ttyTHS1)")
    parser.add_argument("--baud", type=int, help="baud rate; overrides the config (default 460800)")
    parser.add_argument("--seconds", type=float, default=10.0, help="how long to watch (default 10)")
    parser.add_argument("--every", type=float, default=0.5, help="seconds between lines (default 0.5)")
    args = parser.parse_args(argv)
    overrides = {k: v for k, v in (("port", args.port), ("baud", args.baud)) if v is not None}
    try:
        if args.config:
            config = load_config(LimoSerialConfig, args.config, overrides)
        else:
            config = LimoSerialConfig(**overrides)
    except (ConfigError, ValueError) as exc:
        print(f"limo.monitor: error: {exc}", file=sys.stderr)
        return 2
    try:
        with LimoSerialBase(config) as base:
            end = time.monotonic() + args.seconds
            while time.monotonic() < end:
                frame, stats = base.read(), base.link_stats()
                odo = frame.odometry
                print(f"battery {frame.battery_v} V  errors {frame.error_bits:#06x} "
                      f"{', '.join(describe_error_bits(frame.error_bits))}  "
                      + (f"wheels L {odo.left_m:+.3f} R {odo.right_m:+.3f} m  yaw {math.degrees(odo.yaw_rad):+7.2f} deg  "
                         if odo else "no odometry  ")
                      + (f"gyro {math.degrees(frame.imu_yaw_rate_radps):+7.2f} deg/s  " if frame.imu_yaw_rate_radps
                         is not None else "")
                      + f"frames {stats.feedback_frames} bad {stats.bad_checksums}"
                      + (f"  FAULT: {frame.fault}" if frame.fault else ""), flush=True)
                time.sleep(args.every)
    except HalError as exc:
        print(f"limo.monitor: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
