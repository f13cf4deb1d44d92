"""Benchmark and evaluation commands: ``python -m robot.bench <command> ...``.

Each command lives in its own module of this package with ``add_arguments(parser)`` and
``main(args) -> int``; they are imported only when chosen, so one command's heavy
dependencies never slow another down.
"""

from __future__ import annotations

import importlib
import sys

from core.cli import Parser
from core.shutdown import exit_status, interrupted_by, stop_on_signals

COMMANDS = {
    "sim": ("robot.bench.sim", "time one control step of the simulated Limo: physics and render"),
    "vpr": ("robot.bench.vpr", "place recognition recall@1/@5 of each descriptor backend"),
    "perf": ("robot.bench.perf", "speed and size: descriptor, control step split, mapping fps, bytes/node, memory"),
    "baseline": ("robot.bench.baseline", "train the SPTM-style learned action baseline from expert drives"),
    "paper": ("robot.bench.paper", "the paper's table: SR/SPL per route for our method and the baseline"),
    "replay": ("robot.bench.replay", "replay one episode of a paper run with a per-step log; checks it reproduces"),
    "bearing": ("robot.bench.bearing", "the target view's bearing beside and turned off mapped places (rendered)"),
    "compare": ("robot.bench.compare", "runs of the paper harness side by side: one row per run, config changes named"),
    "belief": ("robot.bench.belief", "run the belief filter offline over replayed episodes, judged by true poses"),
}


def main(argv: list[str] | None = None) -> int:
    from robot.threads import limit_helper_threads

    limit_helper_threads()
    argv = sys.argv[1:] if argv is None else argv
    parser = Parser(prog="python -m robot.bench", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        sub.add_parser(name, help=help_text, add_help=False)
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in COMMANDS:
        parser.print_help()
        if argv and argv[0] not in ("-h", "--help"):
            print(f"\nerror: unknown command {argv[0]!r}", file=sys.stderr)
            return 2
        return 0
    module = importlib.import_module(COMMANDS[argv[0]][0])
    cmd_parser = Parser(prog=f"python -m robot.bench {argv[0]}", description=COMMANDS[argv[0]][1])
    module.add_arguments(cmd_parser)
    args = cmd_parser.parse_args(argv[1:])
    stop_on_signals()          # SIGTERM / SIGHUP end through the commands' Ctrl-C handling
    try:
        return int(module.main(args) or 0)
    except KeyboardInterrupt as exc:     # a command without its own handling: one line, no traceback
        print(f"python -m robot.bench {argv[0]}: {interrupted_by(exc)}", file=sys.stderr)
        return exit_status(exc)


if __name__ == "__main__":
    sys.exit(main())
