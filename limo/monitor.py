"""``python -m limo.monitor``: watch a Limo base's feedback (battery, error bits, wheels, gyro,
link counters) while streaming zero velocity: the first-run checklist's tool."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Optional

from core.cli import EXIT_FAILED, EXIT_USAGE, Parser, UsageError, existing_file, positive_float, positive_int
from core.configfile import ConfigError, load_config
from core.hal import HalError
from core.shutdown import exit_status, interrupted_by, stop_on_signals
from limo.config import LimoSerialConfig
from limo.protocol import describe_error_bits
from limo.serial_base import LimoSerialBase, PortError


def main(argv: Optional[list] = None) -> int:
    """Print the base's feedback while commanding zero velocity. Exit status: 0 watched to the
    end, 1 the link failed (no feedback, port gone), 2 bad input, 130 / 143 / 129 Ctrl-C /
    SIGTERM / SIGHUP (core.shutdown)."""
    parser = Parser(
        prog="python -m limo.monitor",
        description="Connect to a Limo base (or the emulator) and print its feedback: battery, error "
                    "bits, wheel odometry, gyro yaw rate, fused heading, link counters. Streams ZERO "
                    "velocity the whole time: use it for the first-run checklist (README, 'Running on a real Limo').")
    parser.add_argument("--config", type=Path,
                        help="the stack config (its serial section) or a YAML of the serial settings alone "
                             "(port, baud, odometry_unit_m, ...); default: configs/default.yaml's defaults")
    parser.add_argument("--port", help="device or pyserial URL; overrides the config (default /dev/ttyTHS1)")
    parser.add_argument("--baud", type=positive_int, help="baud rate; overrides the config (default 460800)")
    parser.add_argument("--seconds", type=positive_float, default=10.0, help="how long to watch (default 10)")
    parser.add_argument("--every", type=positive_float, default=0.5, help="seconds between lines (default 0.5)")
    args = parser.parse_args(argv)
    stop_on_signals()
    overrides = {k: v for k, v in (("port", args.port), ("baud", args.baud)) if v is not None}
    try:
        existing_file("--config", args.config, "YAML file")
        if args.config is not None:
            config = load_config(LimoSerialConfig, args.config, overrides, section="serial")
        else:
            config = LimoSerialConfig(**overrides)
    except (ConfigError, UsageError, ValueError) as exc:
        print(f"limo.monitor: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        with LimoSerialBase(config) as base:
            end = time.monotonic() + args.seconds
            while time.monotonic() < end:
                frame, stats = base.read(), base.link_stats()
                if frame.fault:
                    print(f"limo.monitor: error: the link failed: {frame.fault} (frames {stats.feedback_frames}, "
                          f"bad {stats.rejected}); the base was commanded to stop", file=sys.stderr)
                    return EXIT_FAILED
                odo = frame.odometry
                print(f"battery {frame.battery_v} V  errors {frame.error_bits:#06x} "
                      f"{', '.join(describe_error_bits(frame.error_bits))}  "
                      + (f"wheels L {odo.left_m:+.3f} R {odo.right_m:+.3f} m  yaw {math.degrees(odo.yaw_rad):+7.2f} deg  "
                         if odo else "no odometry  ")
                      + (f"gyro {math.degrees(frame.imu_yaw_rate_radps):+7.2f} deg/s  " if frame.imu_yaw_rate_radps
                         is not None else "")
                      + f"frames {stats.feedback_frames} bad {stats.rejected}"
                      + (f" (last: {stats.last_rejected})" if stats.last_rejected else ""), flush=True)
                time.sleep(args.every)
    except PortError as exc:
        print(f"limo.monitor: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except HalError as exc:
        print(f"limo.monitor: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt as exc:
        print(f"limo.monitor: {interrupted_by(exc)}; the base was commanded to stop", file=sys.stderr)
        return exit_status(exc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
