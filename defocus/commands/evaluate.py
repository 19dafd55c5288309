"""`defocus evaluate`: metrics of a trained checkpoint on a dataset or the motorcycle scene, or
of a method on a focal-stack benchmark with the benchmark's own protocol (`--dataset`)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from datasets.registry import STACK_DATASET_NAMES
from defocus.app.outputs import write_json
from defocus.errors import CommandError
from defocus.options import (
    METHOD_NAMES,
    add_data_arguments,
    add_overwrite_argument,
    dataset_from_options,
    say,
)

BENCHMARKS = STACK_DATASET_NAMES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=Path, nargs="?", default=None,
                        help="checkpoint file (.pt) written by training; optional with --dataset "
                             "(then a label-free method is scored)")
    add_data_arguments(parser, extra_choices=("motorcycle",), default="motorcycle")
    parser.set_defaults(split=None)
    parser.add_argument("--dataset", choices=BENCHMARKS, default=None,
                        help="a focal-stack benchmark in its release layout under --root, scored "
                             "with its paper's protocol (replaces --data)")
    parser.add_argument("--method", choices=METHOD_NAMES, default="auto",
                        help="label-free method for --dataset without a checkpoint (auto: the "
                             "sweep with an all-in-focus photo, the relative blur without)")
    parser.add_argument("--max-samples", type=int, default=None,
                        help="--dataset: score at most this many samples")
    parser.add_argument("--max-pixels", type=int, default=1_500_000,
                        help="--dataset: most pixels of the label-free method's working "
                             "resolution (metrics are computed at the native resolution)")
    parser.add_argument("--scale", type=float, default=0.25,
                        help="downscale factor of the motorcycle scene (--data motorcycle)")
    parser.add_argument("--depth-cap", type=float, default=None,
                        help="ignore ground truth beyond this depth, metres (and clamp predictions)")
    parser.add_argument("--min-depth", type=float, default=1e-3,
                        help="ignore ground truth at or below this depth, metres")
    parser.add_argument("--crop", choices=["garg", "eigen"], default=None,
                        help="KITTI evaluation crop")
    parser.add_argument("--median-scaling", action="store_true",
                        help="scale predictions by median(gt)/median(pred) (reported in the table)")
    parser.add_argument("--json", type=Path, default=None, help="also write the metrics here")
    add_overwrite_argument(parser)


def plan_json(args: argparse.Namespace):
    """The checked plan of `--json` (`defocus.app.outputs.plan_json`), None without it: not the
    checkpoint nor a file of `--root`, no earlier result replaced without `--overwrite`."""
    from defocus.app.outputs import plan_json as plan_one

    return plan_one(args.json, args.overwrite, {"CHECKPOINT": args.checkpoint},
                    {"--root": args.root})


def run(args: argparse.Namespace) -> int:
    from optics.checks import check_depth_bounds

    cap = math.inf if args.depth_cap is None else args.depth_cap
    check_depth_bounds(args.min_depth, cap, names=("--min-depth", "--depth-cap"))
    plan = plan_json(args)
    if args.dataset is not None:
        return run_benchmark(args)
    if args.checkpoint is None:
        raise CommandError("give a checkpoint file, or --dataset NAME --root FOLDER to score a "
                           "label-free method on a focal-stack benchmark")
    from defocus.app.evaluate import evaluate_checkpoint
    from models.metrics import format_table

    if args.data == "motorcycle":
        from datasets.middlebury import motorcycle_sample

        test_set = [motorcycle_sample(args.scale)]
    else:
        test_set = dataset_from_options(args, split=args.split or "test", seed_offset=1_000)
    metrics, warning = evaluate_checkpoint(args.checkpoint, test_set, args.depth_cap, args.crop,
                                           args.median_scaling, args.min_depth)
    print(format_table({args.checkpoint.parent.parent.name or "model": metrics}))
    if warning is not None:
        print(f"warning: {warning}")
    if plan is not None:
        write_json(plan, args.json, metrics)
    return 0


def run_benchmark(args: argparse.Namespace) -> int:
    """`--dataset NAME --root FOLDER`: the benchmark's protocol table of one method."""
    from datasets.registry import build_stack_dataset
    from defocus.app.evaluate import evaluate_on_benchmark
    from models.metrics import format_table
    from models.protocols import PROTOCOLS

    if args.root is None:
        raise CommandError(f"--dataset {args.dataset} needs --root, the dataset folder")
    if args.max_samples is not None and args.max_samples < 1:
        raise CommandError(f"--max-samples must be >= 1, got {args.max_samples}")
    if args.max_pixels < 1024:
        raise CommandError(f"--max-pixels must be >= 1024, got {args.max_pixels}")
    dataset = build_stack_dataset(args.dataset, args.root, split=args.split)
    if args.dataset not in PROTOCOLS:
        print(f"{args.dataset}: {len(dataset)} scenes read from {args.root}; it has no "
              "ground-truth depth, so it is judged by eye: nothing is scored (see "
              f"examples/{args.dataset}.py for the depth maps)")
        return 0
    name, metrics = evaluate_on_benchmark(dataset, args.dataset, args.method, args.checkpoint,
                                          args.max_samples, args.max_pixels,
                                          report=say(args))
    protocol = PROTOCOLS[args.dataset]
    print(format_table({name: metrics}, metrics=protocol.metrics, number_format="{:.4g}"))
    print(f"{args.dataset}: {metrics['images']:.0f} images; protocol: {protocol.source}")
    if args.json is not None:
        write_json(plan_json(args), args.json, {"protocol": args.dataset, **metrics})
    return 0


def benchmark_parser(dataset: str, split: str | None,
                     description: str) -> argparse.ArgumentParser:
    """The parser of a benchmark example script (`examples/<dataset>.py`): `defocus evaluate
    --dataset DATASET`'s options (`--split` defaults to `split`; `--max-samples` and
    `--max-pixels` to the device's, `defocus.app.experiment.BENCHMARK_DEFAULTS`), and where
    the label-free method runs (`--device`, `--threads`)."""
    parser = argparse.ArgumentParser(description=description, allow_abbrev=False,
                                     conflict_handler="resolve")
    add_arguments(parser)
    parser.add_argument("--root", type=Path, required=True,
                        help="the dataset folder in its release layout (see the header)")
    parser.add_argument("--device", default="auto",
                        help="'auto' (CUDA when available), 'cpu', 'cuda', 'cuda:1', ...")
    parser.add_argument("--threads", type=int, default=0,
                        help="CPU threads of PyTorch (0: its default, one per core)")
    parser.set_defaults(dataset=dataset, split=split, max_pixels=None)
    return parser
