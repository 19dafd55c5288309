"""The options every example script takes; the work is `models.experiment.train_and_evaluate`.

Each ``examples/<dataset>.py`` builds its train and test sets and calls `train_and_evaluate`
below, which turns the options into a `TrainConfig`, runs the library's experiment (train, then
evaluate next to the best constant depth, `models.metrics.best_constant_depth`) and prints the
paper-style table.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from torch.utils.data import Dataset, Subset


def build_parser(description: str, out: str) -> argparse.ArgumentParser:
    """Arguments every example takes (``--root`` plus training knobs)."""
    parser = argparse.ArgumentParser(
        description=description, formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    parser.add_argument("--root", type=Path, required=True, help="dataset folder (see the header)")
    parser.add_argument("--steps", type=int, default=2000, help="training steps")
    parser.add_argument("--batch-size", type=int, default=8, help="samples per step")
    parser.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate")
    parser.add_argument("--network", choices=["small", "paper"], default="small",
                        help="depth network (the paper's is large; use a GPU)")
    parser.add_argument("--width", type=int, default=32, help="channel width of the small network")
    parser.add_argument("--input-mode", choices=["aif+focused", "aif"], default="aif+focused",
                        help="network input: the all-in-focus image, optionally with the focused ones")
    parser.add_argument("--size", type=int, nargs=2, metavar=("H", "W"), default=None,
                        help="resize images to H x W pixels (the pixel pitch follows)")
    parser.add_argument("--max-train", type=int, default=None, help="use at most this many training samples")
    parser.add_argument("--max-test", type=int, default=None, help="evaluate on at most this many samples")
    parser.add_argument("--cache-dir", type=Path, default=None,
                        help="keep synthesised focal stacks here and reuse them")
    parser.add_argument("--out", type=Path, default=Path(out), help="run folder (logs, checkpoints)")
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    return parser


def dataset_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments shared by the dataset classes, from the command line."""
    return {"size": None if args.size is None else tuple(args.size), "cache_dir": args.cache_dir}


def limit(dataset: Dataset, count: int | None) -> Dataset:
    """The first ``count`` samples of ``dataset`` (all of them for None)."""
    return dataset if count is None or count >= len(dataset) else Subset(dataset, range(count))


def train_and_evaluate(
    name: str,
    args: argparse.Namespace,
    train_set: Dataset,
    test_set: Dataset,
    depth_range: tuple[float, float],
    crop: str | Sequence[float] | None = None,
    has_depth: bool = True,
) -> dict[str, dict[str, float]]:
    """Run `models.experiment.train_and_evaluate` with the command line's settings and print
    the table; returns its rows."""
    from models.experiment import train_and_evaluate as run
    from models.metrics import format_table
    from models.training import TrainConfig

    train_set, test_set = limit(train_set, args.max_train), limit(test_set, args.max_test)
    first = train_set[0]
    config = TrainConfig(
        steps=args.steps, batch_size=args.batch_size, lr=args.lr, network=args.network,
        input_mode=args.input_mode, out_dir=args.out, seed=args.seed,
        depth_min=depth_range[0], depth_max=depth_range[1],
        n_focus=int(first["focused"].shape[0]), width=args.width, progress=not args.no_progress,
    )
    print(f"{name}: {len(train_set)} training and {len(test_set)} test samples of "
          f"{tuple(first['image'].shape[-2:])} pixels, {config.n_focus} focused images each")
    rows = run(config, train_set, test_set, crop=crop, has_depth=has_depth)
    if not has_depth:
        print("no ground-truth depth: self-supervised reconstruction losses on the test set")
    print(format_table(rows, metrics=tuple(next(iter(rows.values())))) if not has_depth
          else format_table(rows))
    return rows
