"""``python -m limo.emulator``: an emulated Limo base on a pseudo-terminal; prints the device
path and runs until Ctrl-C (or ``--duration``)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Dict, List, Optional

from core.cli import Parser, non_negative_float, non_negative_int, positive_float
from core.shutdown import exit_status, interrupted_by, stop_on_signals
from limo.emulator.firmware import EmulatorConfig, EmulatorError, EmulatorFaults, LimoEmulator
from limo.emulator.models import MODELS


def parse_fault(text: str) -> Dict[str, float]:
    """Parse one ``--fault`` value: ``flip-bits=P``, ``drop-bytes=P``, ``freeze-at=S``, ``freeze``."""
    name, _, value = text.partition("=")
    known = ("flip-bits", "drop-bytes", "freeze-at", "freeze")
    if name not in known:
        raise EmulatorError(f"--fault {text!r}: unknown fault {name!r} (known: {', '.join(known)})")
    if name == "freeze":
        if value:
            raise EmulatorError(f"--fault {text!r}: 'freeze' takes no value (use freeze-at=SECONDS)")
        return {"freeze-at": 0.0}
    try:
        number = float(value)
    except ValueError:
        raise EmulatorError(f"--fault {text!r}: expected {name}=NUMBER, got {value!r}") from None
    if name in ("flip-bits", "drop-bytes") and not 0.0 <= number <= 1.0:
        raise EmulatorError(f"--fault {text!r}: {name} is a probability per frame in [0, 1]")
    if name == "freeze-at" and not (math.isfinite(number) and number >= 0):
        raise EmulatorError(f"--fault {text!r}: freeze-at is seconds after start, >= 0")
    return {name: number}


def _error_bits(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer such as 0x0002, got {text!r}") from None
    if not 0 <= value <= 0xFFFF:
        raise argparse.ArgumentTypeError(f"error bits are 16 bits (0..0xFFFF), got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="python -m limo.emulator",
        description="Emulate an AgileX Limo base on a pseudo-terminal. Prints the device path; "
                    "point the serial backend at it (LimoSerialConfig(port=PATH)). Ctrl-C stops.")
    parser.add_argument("--model", choices=sorted(MODELS), default="kinematic",
                        help="physics behind the firmware (default: kinematic unicycle with accel limits)")
    parser.add_argument("--fault", action="append", default=[], metavar="SPEC",
                        help="inject a fault, repeatable: flip-bits=P (fraction of feedback frames with "
                             "one flipped bit), drop-bytes=P (fraction with one byte removed), "
                             "freeze-at=S (freeze the link S seconds after start), freeze (from the start)")
    parser.add_argument("--battery-v", type=non_negative_float, default=12.2, help="battery voltage to report (V)")
    parser.add_argument("--error-bits", type=_error_bits, default=0,
                        help="error bits to report in 0x211, e.g. 0x0002 (battery warning)")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="seed of the fault injection")
    parser.add_argument("--duration", type=positive_float, default=None,
                        help="stop after this many seconds (default: run until Ctrl-C)")
    parser.add_argument("--status-every", type=non_negative_float, default=0.0,
                        help="print commanded/actual velocity and pose every N seconds (0: never)")
    return parser


def main(argv: Optional[List[str]] = None) -> int:
    args = build_parser().parse_args(argv)
    stop_on_signals()
    try:
        specs: Dict[str, float] = {}
        for text in args.fault:
            specs.update(parse_fault(text))
        faults = EmulatorFaults(flip_bit_prob=specs.get("flip-bits", 0.0),
                                drop_byte_prob=specs.get("drop-bytes", 0.0),
                                frozen=specs.get("freeze-at") == 0.0)
        config = EmulatorConfig(battery_v=args.battery_v, error_bits=args.error_bits, seed=args.seed,
                                faults=faults)
        emulator = LimoEmulator(MODELS[args.model](), config)
        path = emulator.start()
    except EmulatorError as exc:
        print(f"limo.emulator: error: {exc}", file=sys.stderr)
        return 2
    print(path, flush=True)
    start = time.monotonic()
    freeze_at = specs.get("freeze-at")
    next_status = start + args.status_every if args.status_every > 0 else math.inf
    try:
        while args.duration is None or time.monotonic() - start < args.duration:
            time.sleep(0.05)
            now = time.monotonic()
            if freeze_at and not emulator.faults.frozen and now - start >= freeze_at:
                emulator.freeze(True)
                print("link frozen", file=sys.stderr, flush=True)
            if now >= next_status:
                next_status += args.status_every
                cmd, act, pose = emulator.commanded, emulator.actual, emulator.pose
                print(f"cmd v={cmd.v_mps:+.3f} w={cmd.w_radps:+.3f}  actual v={act.v_mps:+.3f} "
                      f"w={act.w_radps:+.3f}  pose x={pose.x_m:+.3f} y={pose.y_m:+.3f} "
                      f"yaw={pose.yaw_rad:+.3f}", file=sys.stderr, flush=True)
    except KeyboardInterrupt as exc:
        print(f"limo.emulator: {interrupted_by(exc)}", file=sys.stderr)
        return exit_status(exc)
    finally:
        emulator.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
