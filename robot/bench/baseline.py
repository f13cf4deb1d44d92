"""``python -m robot.bench baseline``: train the SPTM-style learned action baseline.

Drives ``--episodes`` exploration drives in ``--world`` with the ground-truth expert (see
:mod:`robot.baseline.exploration`), trains the action classifier on frozen EfficientNet-Lite0
features of the frames and the map's node thumbnails, saves it to ``--out`` and prints the data
size, the training and validation accuracy per class (validation: every 5th drive held out)
and the wall time. The map must be a simulator map of that world (nodes with true poses), e.g.
from ``python -m robot.run --mode map --world hospital``.

The paper harness calls :func:`train_baseline` / :func:`load_baseline` directly (re-exported
here from :mod:`robot.baseline.pipeline`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from core.cli import UsageError, check_output_file, existing_folder
from robot.baseline.pipeline import build_baseline, load_baseline, train_baseline

EXIT_BAD_INPUT = 2

__all__ = ["add_arguments", "main", "train_baseline", "load_baseline"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--map", type=Path, required=True,
                        help="map folder of the world (built in the simulator: nodes carry true poses)")
    parser.add_argument("--world", default="hospital",
                        help="world name in configs/worlds or a world YAML file (default: hospital)")
    parser.add_argument("--episodes", type=int, default=64, help="exploration drives (default: 64)")
    parser.add_argument("--steps", type=int, default=50,
                        help="control ticks per drive at most, 10 per simulated second (default: 50)")
    parser.add_argument("--epsilon", type=float, default=0.1,
                        help="chance per tick of starting a random action held for 2-6 ticks (default: 0.1)")
    parser.add_argument("--epochs", type=int, default=40, help="training epochs (default: 40)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the drives and the training (default: 0)")
    parser.add_argument("--out", type=Path, default=None,
                        help="where to save the trained head (default: runs/baseline/sptm-WORLD.pt)")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch threads (default: 1; the machine is shared, and batch-1 features gain little)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _pct(value) -> str:
    return "  -  " if value is None else f"{value:5.3f}"


def format_stats(stats: dict) -> str:
    """The human summary of a trained head's statistics."""
    counts = stats["train"]["counts"]
    val = stats.get("validation")
    total = {k: counts[k] + (val["counts"][k] if val else 0) for k in counts}
    lines = [
        f"data: {stats['drives']} drives in {stats['world']}, {stats['frames']} frames, {stats['samples']} samples "
        f"(" + ", ".join(f"{k} {v}" for k, v in total.items()) + f"); map {stats['map']} ({stats['map_nodes']} nodes)",
        f"{'':12s} {'accuracy':>8s} " + " ".join(f"{k:>7s}" for k in counts) + f" {'samples':>8s} {'majority':>9s}",
    ]
    for name in ("train", "validation"):
        s = stats.get(name)
        if s is None:
            lines.append(f"{name:12s} (no samples)")
            continue
        lines.append(f"{name:12s} {s['accuracy']:8.3f} " + " ".join(f"{_pct(s['per_class'][k]):>7s}" for k in counts)
                     + f" {s['samples']:8d} {s['majority_rate']:9.3f}")
    lines.append(f"wall time: exploring {stats['collect_seconds'] / 60:.1f} min, training "
                 f"{stats['train_seconds'] / 60:.1f} min, total {stats['total_seconds'] / 60:.1f} min")
    return "\n".join(lines)


def _input_errors() -> tuple[type[BaseException], ...]:
    from maps.graph import MapError
    from robot.baseline.expert import ExpertError
    from robot.baseline.exploration import ExplorationError
    from robot.baseline.features import FeatureError
    from robot.baseline.fit import TrainingError
    from robot.baseline.pipeline import BaselineInputError
    from sim.world_spec import WorldError

    return (MapError, WorldError, BaselineInputError, ExpertError, ExplorationError, FeatureError, TrainingError)


def main(args: argparse.Namespace) -> int:
    import torch

    from robot.baseline.exploration import ExplorationConfig
    from robot.baseline.fit import TrainConfig
    from robot.baseline.head import save_head

    if args.threads < 1:
        print(f"error: --threads must be >= 1, got {args.threads}", file=sys.stderr)
        return EXIT_BAD_INPUT
    out = args.out if args.out is not None else Path("runs") / "baseline" / f"sptm-{Path(str(args.world)).stem}.pt"
    try:       # before minutes of drives and training
        existing_folder("--map", args.map, "map folder")
        check_output_file("--out", out)
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    torch.set_num_threads(args.threads)
    try:
        exploration = ExplorationConfig(episodes=args.episodes, steps_per_episode=args.steps, epsilon=args.epsilon)
        train = TrainConfig(epochs=args.epochs)
        head = build_baseline(args.world, args.map, exploration=exploration, train=train, seed=args.seed,
                              progress=not args.quiet)
    except _input_errors() as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        save_head(out, head)
    except OSError as exc:
        print(f"error: cannot write {out}: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(format_stats(head.stats))
    print(f"saved -> {out}")
    return 0
