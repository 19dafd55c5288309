"""Shared command line and train-then-evaluate loop of the per-dataset example scripts.

Each ``examples/<dataset>.py`` builds its train and test sets and calls :func:`train_and_evaluate`,
which trains with ``models.training.Trainer``, evaluates, and prints a paper-style table with a
best-constant-depth baseline for reference.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
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


def constant_baseline(
    train_set: Dataset, test_set: Dataset, metrics: Callable[..., dict[str, float]], **kwargs: Any
) -> dict[str, float] | None:
    """Metrics of the best constant depth (geometric mean of the training depths), or None when
    the data has no depth."""
    logs = [torch.log(s["depth"][s["mask"]]) for s in train_set if bool(s["mask"].any())]
    if not logs:
        return None
    constant = math.exp(float(torch.cat(logs).mean()))
    totals: dict[str, float] = {}
    for sample in test_set:
        row = metrics(torch.full_like(sample["depth"], constant), sample["depth"], sample["mask"],
                      **kwargs)
        for key, value in row.items():
            totals[key] = totals.get(key, 0.0) + value / len(test_set)
    return totals


def reconstruction_metrics(trainer: Any, test_set: Dataset) -> dict[str, float]:
    """Mean self-supervised loss terms on ``test_set`` (for data without ground-truth depth)."""
    from torch.utils.data import default_collate

    totals: dict[str, float] = {}
    for sample in test_set:
        batch = default_collate([sample])
        depth = trainer.predict(batch["image"], batch["focused"], batch["camera"])
        with torch.no_grad():
            terms = trainer.loss_fn(depth, batch["image"], batch["focused"], batch["camera"])
        for key, value in terms.items():
            totals[key] = totals.get(key, 0.0) + float(value) / len(test_set)
    return totals


def train_and_evaluate(
    name: str,
    args: argparse.Namespace,
    train_set: Dataset,
    test_set: Dataset,
    depth_range: tuple[float, float],
    crop: str | Sequence[float] | None = None,
    has_depth: bool = True,
) -> dict[str, dict[str, float]]:
    """Train on ``train_set``, evaluate on ``test_set`` and print the table; returns its rows.

    Args:
        name: dataset name for the table.
        args: parsed :func:`build_parser` arguments.
        train_set, test_set: datasets in the sample format.
        depth_range: ``(depth_min, depth_max)`` metres of the network's output; ``depth_max`` is
            also the evaluation cap.
        crop: evaluation crop (``"eigen"``, ``"garg"`` or fractions), see ``Trainer.evaluate``.
        has_depth: False for data without ground truth: the table then holds reconstruction
            losses instead of depth metrics.
    """
    from models.metrics import depth_metrics, format_table
    from models.training import TrainConfig, Trainer

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
    trainer = Trainer(config, train_set)
    trainer.fit()
    method = f"ours ({args.network}, {args.input_mode}, {args.steps} steps)"
    if has_depth:
        rows = {method: trainer.evaluate(test_set, depth_cap=depth_range[1], crop=crop)}
        baseline = constant_baseline(train_set, test_set, depth_metrics,
                                     max_depth=depth_range[1], crop=crop)
        if baseline is not None:
            rows["best constant depth"] = baseline
        print(format_table(rows))
    else:
        rows = {method: reconstruction_metrics(trainer, test_set)}
        print("no ground-truth depth: self-supervised reconstruction losses on the test set")
        print(format_table(rows, metrics=tuple(rows[method])))
    return rows
