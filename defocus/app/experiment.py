"""Train and evaluate on a dataset, or score a label-free method on a focal-stack benchmark: the
work of the scripts under `examples/` (their options: `defocus.options.example_parser` and
`benchmark_parser`).

Training runs `models.experiment.train_and_evaluate`: the options become a `TrainConfig`, a
few steps are measured, the budget is planned, the network trains on random crops of the
full-resolution samples and is evaluated on whole test images next to the best constant depth
(`models.metrics.best_constant_depth`).
"""

from __future__ import annotations

import argparse
import math
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch.utils.data import Dataset, Subset

from defocus.options import (
    BENCHMARK_DEFAULTS,
    DEVICE_DEFAULTS,
    check_training_options,
    crop_size,
    device_kind,
)

Report = Callable[[str], None]


def _silent(text: str) -> None:
    """A `report` that drops the text."""


def loss_window(size: Sequence[int], largest: int = 63) -> int:
    """The loss's largest PSF window (odd, pixels) for training inputs of `size = (H, W)`:
    `largest`, or less for inputs smaller than that, where a wider window adds only work.

    Example:
        >>> loss_window((128, 128)), loss_window((12, 18))
        (63, 11)
    """
    side = min(int(size[0]), int(size[1]), largest)
    return max(side - 1 + side % 2, 3)


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


def _training_config(args: argparse.Namespace, first: dict, depth_range: tuple[float, float],
                     kind: str, steps: int | None):
    from models.training import TrainConfig

    side = getattr(args, "side", "both")
    focus = 0.0
    if side != "both":
        focus_distances = first["camera"].focus_distance.reshape(-1)
        if focus_distances.numel() != 1:
            raise SystemExit(f"--side {side} needs samples of one focus setting, got "
                             f"{focus_distances.numel()}")
        focus = float(focus_distances[0])
    return TrainConfig(
        steps=steps or 1, batch_size=args.batch_size, lr=args.lr, network=args.network,
        input_mode=args.input_mode, out_dir=args.out, seed=args.seed,
        supervision=getattr(args, "supervision", "self"), depth_spacing=args.depth_spacing,
        side=side, focus_distance=focus,
        depth_min=depth_range[0], depth_max=depth_range[1],
        device=kind if args.device == "auto" else args.device,
        n_focus=int(first["focused"].shape[0]), width=args.width, progress=not args.no_progress,
        max_kernel_size=loss_window(first["image"].shape[-2:]),
        workers=args.workers, precision=args.precision, compile=args.compile,
        smoothness_weight=getattr(args, "smoothness_weight", TrainConfig.smoothness_weight),
    )


def _epoch_steps(args: argparse.Namespace, source: Dataset, first: dict) -> int:
    """The most steps of `--max-epochs` passes over the training pixels of `source`."""
    dataset_pixels = len(source) * int(source[0]["image"][0].numel())
    step_pixels = args.batch_size * int(first["image"][0].numel())
    return max(10, math.ceil(args.max_epochs * dataset_pixels / step_pixels))


def train_and_evaluate(
    name: str,
    args: argparse.Namespace,
    train_set: Dataset,
    test_set: Dataset,
    depth_range: tuple[float, float],
    crop: str | Sequence[float] | None = None,
    has_depth: bool = True,
    constant_set: Dataset | None = None,
    report: Report = _silent,
) -> dict[str, dict[str, float]]:
    """Run `models.experiment.train_and_evaluate` with the options of `example_parser` and
    report the table; returns its rows.

    `train_set` gives random crops (see `training_crop`); `constant_set`, the same training
    samples whole, chooses the best constant depth.
    """
    from models.experiment import keep_freed_memory
    from models.experiment import train_and_evaluate as run
    from models.metrics import format_table

    keep_freed_memory()
    truncation_warning_once()
    check_training_options(args)
    if args.depth_range is not None:
        depth_range = (args.depth_range[0], args.depth_range[1])
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
    config = _training_config(args, first, depth_range, kind, steps)
    whole = (constant_set or train_set)[0]["image"].shape[-2:]
    crop_text = (f"random {tuple(first['image'].shape[-2:])} crops of"
                 if tuple(first["image"].shape[-2:]) != tuple(whole) else "whole")
    report(f"{name}: {len(train_set)} training samples ({crop_text} {tuple(whole)} pixels) and "
           f"{len(test_set)} whole test samples, {config.n_focus} focused images each; "
           f"device {kind}")
    max_steps = None if minutes is None else _epoch_steps(
        args, constant_set if constant_set is not None else train_set, first)
    rows = run(config, train_set, test_set, crop=crop, has_depth=has_depth,
               constant_set=constant_set, minutes=minutes, max_steps=max_steps,
               report_every=None if args.no_progress else 0, report=report)
    if not has_depth:
        report("no ground-truth depth: self-supervised reconstruction losses on the test set")
    report(format_table(rows, metrics=tuple(next(iter(rows.values())))) if not has_depth
           else format_table(rows))
    return rows


def training_crop(args: argparse.Namespace, probe: Dataset,
                  report: Report = _silent) -> tuple[int, int] | None:
    """The crop of `--crop` (or the device default), made to fit inside `probe[0]` (the
    unaugmented training set): a crop larger than the image becomes the whole image side."""
    crop = crop_size(args)
    if crop is None:
        return None
    h, w = probe[0]["image"].shape[-2:]
    fitted = (min(crop[0], h), min(crop[1], w))
    if fitted != crop:
        report(f"crop {crop[0]}x{crop[1]} does not fit the {h}x{w} images: using {fitted[0]}x"
               f"{fitted[1]}")
    return None if fitted == (h, w) else fitted


def run_example(
    name: str,
    args: argparse.Namespace,
    make: Callable[[str], Dataset],
    depth_range: tuple[float, float],
    splits: tuple[str, str] = ("train", "test"),
    report: Report = _silent,
    **evaluate_kwargs: Any,
) -> dict[str, dict[str, float]]:
    """The whole example: `make(split)` builds a dataset; training takes random crops (flips and
    gains) of the whole training samples, which also choose the best constant depth; evaluation
    runs on the whole test samples (the training set itself when both splits are the same)."""
    from datasets import JointAugment

    whole = make(splits[0])
    crop = training_crop(args, whole, report)
    train = whole.with_augment(JointAugment(crop_size=crop, hflip=0.5, gain=0.1))
    test = whole if splits[1] == splits[0] else make(splits[1])
    if evaluate_kwargs.get("has_depth", True):
        evaluate_kwargs.setdefault("constant_set", whole)
    return train_and_evaluate(name, args, train, test, depth_range=depth_range, report=report,
                              **evaluate_kwargs)


def plan_json_option(args: argparse.Namespace, what: str = "metrics JSON",
                     inputs: Any = None) -> Any:
    """The checked plan of an example's `--json` (`defocus.options.add_json_argument`), None
    without it, made before any work: not an existing file of `--root` nor one of `inputs`
    (`(name, path)` pairs), no earlier result replaced without `--overwrite`
    (`defocus.app.outputs.plan_json`); a refusal ends the script in one line (`SystemExit`).

    Example:
        >>> plan_json_option(argparse.Namespace(json=None)) is None
        True
    """
    from .outputs import plan_json

    try:
        return plan_json(getattr(args, "json", None), getattr(args, "overwrite", False),
                         inputs, {"--root": getattr(args, "root", None)}, what)
    except (OSError, ValueError) as error:
        raise SystemExit(str(error)) from None


def run_benchmark_example(name: str, args: argparse.Namespace, dataset: Dataset,
                          protocol: str | None, report: Report = _silent) -> dict[str, float] | None:
    """Score `args.method` on `dataset` with `protocol` (`models.protocols.PROTOCOLS`) and report
    the paper-style table; with no protocol (no ground truth) report the depth range of each
    scene instead. Returns the metrics; `--json` is planned before any sample is scored and
    written through the output policy (`plan_json_option`)."""
    from models.evaluation import label_free_method
    from models.metrics import format_table
    from models.protocols import PROTOCOLS

    from .outputs import write_json

    plan = plan_json_option(args)
    if args.threads:
        torch.set_num_threads(args.threads)
    kind = device_kind(args.device)
    defaults = BENCHMARK_DEFAULTS[kind]
    device = kind if args.device == "auto" else args.device
    count = args.max_samples if args.max_samples is not None else defaults["max_samples"]
    count = len(dataset) if count is None else min(count, len(dataset))
    method = label_free_method(dataset.depth_range, args.method, device=device,
                               max_pixels=args.max_pixels or defaults["max_pixels"])
    report(f"{name}: scoring {count} of {len(dataset)} samples with the {method.name} method on "
           f"{device}")
    samples = (dataset[i] for i in range(count))
    if protocol is None:
        for i, sample in enumerate(samples):
            depth = method(sample)
            report(f"  {sample['id']}: depth {float(depth.min()):.3g}-{float(depth.max()):.3g} m "
                   f"({i + 1}/{count}); no ground truth: judge the depth maps by eye")
        return None
    metrics = score_benchmark(samples, method, protocol, count, report)
    report(format_table({f"{method.name} (label-free)": metrics},
                        metrics=PROTOCOLS[protocol].metrics, number_format="{:.4g}"))
    report(f"protocol: {PROTOCOLS[protocol].source}")
    if plan is not None:
        write_json(plan, args.json, metrics)
    return metrics


def score_benchmark(samples, method, protocol: str, count: int,
                    report: Report = _silent) -> dict[str, float]:
    """`models.evaluate` of `method` on `count` samples with `protocol`, reporting each
    sample's abs rel as it is scored."""
    from models import evaluate

    def each(index: int, sample_id: str, values: dict[str, float]) -> None:
        report(f"  {index + 1}/{count} {sample_id}: abs rel {values['abs_rel']:.4g}")

    return evaluate(samples=samples, predict=method, protocol=protocol, report=each)
