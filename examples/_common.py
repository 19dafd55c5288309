"""The options every example script takes; the work is `models.experiment.train_and_evaluate`.

Each `examples/<dataset>.py` builds its train and test sets and calls `train_and_evaluate`
below, which turns the options into a `TrainConfig`, measures a few steps, plans the budget,
trains on random crops of the full-resolution samples, evaluates on whole test images next to
the best constant depth (`models.metrics.best_constant_depth`) and prints the paper-style table.

Defaults follow the machine:

- CPU: random `128 x 128` crops, batch 8, as many steps as fit in `--minutes 10` together with
  the evaluation (and at most `--max-epochs 200` passes over the training pixels, so small data
  finishes in seconds).
- GPU (`--device cuda`, or `auto` with CUDA available): `256 x 256` crops, batch 8, 20000 steps,
  no time budget.

Synthesised focal stacks are cached in the per-user cache folder
(`optics.cache.user_cache_dir("focal_stacks")`) when it is writable (`--cache-dir` to choose
another, `--no-cache` to keep nothing on disk), and the full-resolution samples are kept in
memory up to `--memory-cache-mb`.
"""

from __future__ import annotations

import argparse
import math
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import Dataset, Subset

#: Defaults per device kind: crop side (pixels), steps, time budget (minutes).
DEVICE_DEFAULTS = {"cpu": {"crop": 128, "steps": None, "minutes": 10.0},
                   "cuda": {"crop": 256, "steps": 20000, "minutes": None}}


def build_parser(description: str, out: str) -> argparse.ArgumentParser:
    """Arguments every example takes (`--root` plus training knobs)."""
    parser = argparse.ArgumentParser(
        description=description, formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    parser.add_argument("--root", type=Path, required=True, help="dataset folder (see the header)")
    parser.add_argument("--device", default="auto",
                        help="'auto' (CUDA when available), 'cpu', 'cuda', 'cuda:1', ...")
    parser.add_argument("--steps", type=int, default=None,
                        help="training steps (default: CPU as many as fit in --minutes, GPU 20000)")
    parser.add_argument("--minutes", type=float, default=None,
                        help="time budget of training + evaluation (default: CPU 10, GPU none)")
    parser.add_argument("--max-epochs", type=float, default=200.0,
                        help="with --minutes: at most this many passes over the training pixels")
    parser.add_argument("--batch-size", type=int, default=8, help="samples per step")
    parser.add_argument("--crop", type=int, nargs="+", metavar="PX", default=None,
                        help="train on random H [W] crops of the full-resolution samples "
                             "(default: CPU 128, GPU 256; 0: whole images)")
    parser.add_argument("--depth-range", type=float, nargs=2, metavar=("MIN", "MAX"), default=None,
                        help="depths the network can output, metres (default: the dataset's)")
    parser.add_argument("--depth-spacing", choices=["depth", "inverse"], default="depth",
                        help="space the network's output evenly in depth or in inverse depth")
    parser.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate")
    parser.add_argument("--network", choices=["small", "paper"], default="small",
                        help="depth network (the paper's is large; use a GPU)")
    parser.add_argument("--width", type=int, default=32, help="channel width of the small network")
    parser.add_argument("--input-mode", choices=["aif+focused", "aif"], default="aif+focused",
                        help="network input: the all-in-focus image, optionally with the focused ones")
    parser.add_argument("--size", type=int, nargs=2, metavar=("H", "W"), default=None,
                        help="resize whole images to H x W pixels first (the pixel pitch follows, "
                             "so the blur in pixels shrinks too; prefer --crop)")
    parser.add_argument("--max-train", type=int, default=None, help="use at most this many training samples")
    parser.add_argument("--max-test", type=int, default=None, help="evaluate on at most this many samples")
    parser.add_argument("--cache-dir", type=Path, default=None,
                        help="keep synthesised focal stacks here (default: the per-user cache)")
    parser.add_argument("--no-cache", action="store_true",
                        help="keep no synthesised focal stacks on disk")
    parser.add_argument("--memory-cache-mb", type=float, default=2048,
                        help="keep up to this many MiB of full-resolution samples in memory")
    parser.add_argument("--out", type=Path, default=Path(out), help="run folder (logs, checkpoints)")
    parser.add_argument("--threads", type=int, default=0,
                        help="CPU threads of PyTorch (0: its default, one per core; on a "
                             "machine shared with other jobs 1 wastes less time waiting)")
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    return parser


def loss_window(size: Sequence[int], largest: int = 63) -> int:
    """The loss's largest PSF window (odd, pixels) for training inputs of `size = (H, W)`:
    `largest`, or less for inputs smaller than that, where a wider window adds only work.

    Example:
        >>> loss_window((128, 128)), loss_window((12, 18))
        (63, 11)
    """
    side = min(int(size[0]), int(size[1]), largest)
    return max(side - 1 + side % 2, 3)


def device_kind(name: str) -> str:
    """`"cuda"` or `"cpu"` for a `--device` value (`"auto"`: CUDA when available)."""
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    try:
        return "cuda" if torch.device(name).type == "cuda" else "cpu"
    except RuntimeError:
        raise SystemExit(f"--device must be 'auto', 'cpu' or 'cuda[:N]', got {name!r}") from None


def crop_size(args: argparse.Namespace) -> tuple[int, int] | None:
    """The training crop `(H, W)` from `--crop` and the device defaults; None for whole images."""
    crop = args.crop or [DEVICE_DEFAULTS[device_kind(args.device)]["crop"]]
    if len(crop) > 2 or any(c < 0 for c in crop):
        raise SystemExit(f"--crop takes one or two sizes in pixels (0: whole images), got {crop}")
    if crop[0] == 0:
        return None
    return (crop[0], crop[-1])


def dataset_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments shared by the dataset classes, from the command line."""
    cache: Any = None if args.no_cache else (args.cache_dir or "auto")
    return {"size": None if args.size is None else tuple(args.size), "cache_dir": cache,
            "memory_cache_mb": args.memory_cache_mb}


def limit(dataset: Dataset, count: int | None) -> Dataset:
    """The first `count` samples of `dataset` (all of them for None)."""
    return dataset if count is None or count >= len(dataset) else Subset(dataset, range(count))


def truncation_warning_once() -> None:
    """Show the renderer's "PSFs are truncated" warning once, not at every training step
    whose predicted depths reach the ends of the depth range."""
    original = warnings.showwarning
    seen = [False]

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
        if "PSFs are truncated" in str(message):
            if seen[0]:
                return
            seen[0] = True
            message = UserWarning(f"{message} (shown once; predictions near the ends of the "
                                  "depth range blur the most)")
        original(message, category, filename, lineno, file, line)

    warnings.showwarning = show


def train_and_evaluate(
    name: str,
    args: argparse.Namespace,
    train_set: Dataset,
    test_set: Dataset,
    depth_range: tuple[float, float],
    crop: str | Sequence[float] | None = None,
    has_depth: bool = True,
    constant_set: Dataset | None = None,
) -> dict[str, dict[str, float]]:
    """Run `models.experiment.train_and_evaluate` with the command line's settings and print
    the table; returns its rows.

    `train_set` gives random crops (see `training_crop`); `constant_set`, the same training
    samples whole, chooses the best constant depth.
    """
    from models.experiment import keep_freed_memory
    from models.experiment import train_and_evaluate as run
    from models.metrics import format_table
    from models.training import TrainConfig

    keep_freed_memory()
    truncation_warning_once()
    if args.depth_range is not None:
        if not 0 < args.depth_range[0] < args.depth_range[1]:
            raise SystemExit(f"--depth-range must be 0 < MIN < MAX metres, got {args.depth_range}")
        depth_range = (args.depth_range[0], args.depth_range[1])
    if args.threads < 0:
        raise SystemExit(f"--threads must be >= 0 (0: PyTorch's default), got {args.threads}")
    if args.threads:
        torch.set_num_threads(args.threads)
    kind = device_kind(args.device)
    defaults = DEVICE_DEFAULTS[kind]
    train_set, test_set = limit(train_set, args.max_train), limit(test_set, args.max_test)
    if constant_set is not None:
        constant_set = limit(constant_set, args.max_train)
    first = train_set[0]
    steps = args.steps if args.steps is not None else defaults["steps"]
    minutes = args.minutes if args.minutes is not None else (
        defaults["minutes"] if steps is None else None)
    config = TrainConfig(
        steps=steps or 1, batch_size=args.batch_size, lr=args.lr, network=args.network,
        input_mode=args.input_mode, out_dir=args.out, seed=args.seed,
        supervision=getattr(args, "supervision", "self"), depth_spacing=args.depth_spacing,
        depth_min=depth_range[0], depth_max=depth_range[1],
        device=kind if args.device == "auto" else args.device,
        n_focus=int(first["focused"].shape[0]), width=args.width, progress=not args.no_progress,
        max_kernel_size=loss_window(first["image"].shape[-2:]),
    )
    whole = (constant_set or train_set)[0]["image"].shape[-2:]
    crop_text = (f"random {tuple(first['image'].shape[-2:])} crops of"
                 if tuple(first["image"].shape[-2:]) != tuple(whole) else "whole")
    print(f"{name}: {len(train_set)} training samples ({crop_text} {tuple(whole)} pixels) and "
          f"{len(test_set)} whole test samples, {config.n_focus} focused images each; "
          f"device {kind}")
    max_steps = None
    if minutes is not None:
        source = constant_set if constant_set is not None else train_set
        dataset_pixels = len(source) * int(source[0]["image"][0].numel())
        step_pixels = args.batch_size * int(first["image"][0].numel())
        max_steps = max(10, math.ceil(args.max_epochs * dataset_pixels / step_pixels))
    rows = run(config, train_set, test_set, crop=crop, has_depth=has_depth,
               constant_set=constant_set, minutes=minutes, max_steps=max_steps,
               report_every=None if args.no_progress else 0)
    if not has_depth:
        print("no ground-truth depth: self-supervised reconstruction losses on the test set")
    print(format_table(rows, metrics=tuple(next(iter(rows.values())))) if not has_depth
          else format_table(rows))
    return rows


def training_crop(args: argparse.Namespace, probe: Dataset) -> tuple[int, int] | None:
    """The crop of `--crop` (or the device default), made to fit inside `probe[0]` (the
    unaugmented training set): a crop larger than the image becomes the whole image side."""
    crop = crop_size(args)
    if crop is None:
        return None
    h, w = probe[0]["image"].shape[-2:]
    fitted = (min(crop[0], h), min(crop[1], w))
    if fitted != crop:
        print(f"crop {crop[0]}x{crop[1]} does not fit the {h}x{w} images: using {fitted[0]}x"
              f"{fitted[1]}")
    return None if fitted == (h, w) else fitted


def run_example(
    name: str,
    args: argparse.Namespace,
    make: Callable[[str], Dataset],
    depth_range: tuple[float, float],
    splits: tuple[str, str] = ("train", "test"),
    **evaluate_kwargs: Any,
) -> dict[str, dict[str, float]]:
    """The whole example: `make(split)` builds a dataset; training takes random crops (flips and
    gains) of the whole training samples, which also choose the best constant depth; evaluation
    runs on the whole test samples (the training set itself when both splits are the same)."""
    from datasets import JointAugment

    whole = make(splits[0])
    crop = training_crop(args, whole)
    train = whole.with_augment(JointAugment(crop_size=crop, hflip=0.5, gain=0.1))
    test = whole if splits[1] == splits[0] else make(splits[1])
    if evaluate_kwargs.get("has_depth", True):
        evaluate_kwargs.setdefault("constant_set", whole)
    return train_and_evaluate(name, args, train, test, depth_range=depth_range, **evaluate_kwargs)


# ---- focal-stack benchmarks: score a method with the benchmark's own protocol -----------------

#: Defaults per device kind for the benchmark examples: samples scored, working pixels.
BENCHMARK_DEFAULTS = {"cpu": {"max_samples": 8, "max_pixels": 250_000},
                      "cuda": {"max_samples": None, "max_pixels": 1_500_000}}


def build_benchmark_parser(description: str, split: str | None) -> argparse.ArgumentParser:
    """Arguments of the focal-stack benchmark examples (`--root` plus the method's knobs)."""
    parser = argparse.ArgumentParser(
        description=description, formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    parser.add_argument("--root", type=Path, required=True, help="dataset folder (see the header)")
    if split is not None:
        parser.add_argument("--split", default=split, help="the split to score")
    parser.add_argument("--device", default="auto",
                        help="'auto' (CUDA when available), 'cpu', 'cuda', 'cuda:1', ...")
    parser.add_argument("--method", choices=["auto", "sweep", "relative-blur", "focus"],
                        default="auto", help="label-free method (auto: the sweep with an "
                        "all-in-focus photo, the relative blur without)")
    parser.add_argument("--max-samples", type=int, default=None,
                        help="score at most this many samples (default: CPU 8, GPU all)")
    parser.add_argument("--max-pixels", type=int, default=None,
                        help="most pixels of the method's working resolution (default: CPU "
                             "250000, GPU 1500000); metrics use the native resolution")
    parser.add_argument("--threads", type=int, default=0,
                        help="CPU threads of PyTorch (0: its default)")
    parser.add_argument("--json", type=Path, default=None, help="also write the metrics here")
    return parser


def run_benchmark_example(name: str, args: argparse.Namespace, dataset: Dataset,
                          protocol: str | None) -> dict[str, float] | None:
    """Score `args.method` on `dataset` with `protocol` (`models.metrics.PROTOCOLS`) through
    `models.benchmarks.evaluate_benchmark` and print the paper-style table; with no protocol
    (no ground truth) print the depth range of each scene instead. Returns the metrics."""
    import json

    from models.benchmarks import evaluate_benchmark, label_free_method
    from models.metrics import PROTOCOLS, format_table

    if args.threads:
        torch.set_num_threads(args.threads)
    kind = device_kind(args.device)
    defaults = BENCHMARK_DEFAULTS[kind]
    device = kind if args.device == "auto" else args.device
    count = args.max_samples if args.max_samples is not None else defaults["max_samples"]
    count = len(dataset) if count is None else min(count, len(dataset))
    method = label_free_method(dataset.depth_range, args.method, device=device,
                               max_pixels=args.max_pixels or defaults["max_pixels"])
    print(f"{name}: scoring {count} of {len(dataset)} samples with the {method.name} method on "
          f"{device}")
    samples = (dataset[i] for i in range(count))
    if protocol is None:
        for i, sample in enumerate(samples):
            depth = method(sample)
            print(f"  {sample['id']}: depth {float(depth.min()):.3g}-{float(depth.max()):.3g} m "
                  f"({i + 1}/{count}); no ground truth: judge the depth maps by eye")
        return None

    def report(index: int, sample_id: str, values: dict[str, float]) -> None:
        print(f"  {index + 1}/{count} {sample_id}: abs rel {values['abs_rel']:.4g}", flush=True)

    metrics = evaluate_benchmark(samples, method, protocol, report=report)
    print(format_table({f"{method.name} (label-free)": metrics},
                       metrics=PROTOCOLS[protocol].metrics, number_format="{:.4g}"))
    print(f"protocol: {PROTOCOLS[protocol].source}")
    if args.json:
        args.json.write_text(json.dumps(metrics, indent=2))
    return metrics
