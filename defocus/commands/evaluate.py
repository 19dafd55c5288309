"""`defocus evaluate`: metrics of a trained checkpoint on a dataset or the motorcycle scene, or
of a method on a focal-stack benchmark with the benchmark's own protocol (`--data`).

Where the data's focused images are synthesised from its depth (`--focus synthesized`, the
default of every dataset but dslr, folder and lightfield), they are rendered with the camera
the checkpoint was trained for: a network learned its camera's blur, so a network trained on
one data set is scored on another (`--data rgbd`, `--data dslr --focus synthesized`,
`middlebury`, `synthetic`, ...) with that blur."""

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


def add_arguments(parser: argparse.ArgumentParser, focus: bool = True) -> None:
    """`defocus evaluate`'s options; `focus=False` leaves out `--focus` (a benchmark's focal
    stacks are real)."""
    parser.add_argument("checkpoint", type=Path, nargs="?", default=None,
                        help="checkpoint file (.pt) written by training; optional with a benchmark's "
                             "(then a label-free method is scored)")
    add_data_arguments(parser, extra_choices=("motorcycle", *BENCHMARKS), default="motorcycle",
                       data_help="; scored with the depth metrics, or a focal-stack benchmark "
                                 f"({', '.join(BENCHMARKS)}) in its release layout under --root, "
                                 "scored with its paper's own protocol and metrics",
                       focus=focus)
    parser.set_defaults(split=None)
    parser.add_argument("--method", choices=METHOD_NAMES, default="auto",
                        help="label-free method for --data without a checkpoint (auto: the "
                             "sweep with an all-in-focus photo, the relative blur without)")
    parser.add_argument("--max-samples", type=int, default=None,
                        help="--data: score at most this many samples")
    parser.add_argument("--last", type=int, default=None, metavar="N",
                        help="--data with a checkpoint: score only the last N samples of the "
                             "split, in its order (the examples' held-out scenes: "
                             "examples/dslr.py holds out the last 20 of its split by time)")
    parser.add_argument("--max-pixels", type=int, default=1_500_000,
                        help="--data: most pixels of the label-free method's working "
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
    tolerance = parser.add_argument_group(
        "a camera as built (synthesised focus: the checkpoint's camera off its design)")
    tolerance.add_argument("--perturb-focus", type=float, default=0.0, metavar="FRACTION",
                           help="every focus distance off by this share (0.02: 2 %% farther)")
    tolerance.add_argument("--perturb-f-stops", type=float, default=0.0, metavar="STOPS",
                           help="the f-number off by this many stops (0.333: a third smaller "
                                "iris)")
    tolerance.add_argument("--perturb-mask", type=float, default=0.0, metavar="SIGMA",
                           help="noise in a learned aperture mask's transmission (share of "
                                "its peak)")
    tolerance.add_argument("--robustness", action="store_true",
                           help="score the camera as designed and as built with focus +-2 %%, "
                                "f-number +-1/3 stop and (a learned mask) 5 %% mask noise")
    parser.add_argument("--json", type=Path, default=None, help="also write the metrics here")
    add_overwrite_argument(parser)


def plan_json(args: argparse.Namespace):
    """The checked plan of `--json` (`defocus.app.outputs.plan_json`), None without it: not the
    checkpoint nor a file of `--root`, no earlier result replaced without `--overwrite`."""
    from defocus.app.outputs import plan_json as plan_one

    return plan_one(args.json, args.overwrite, {"CHECKPOINT": args.checkpoint},
                    {"--root": args.root})


def request_of(args: argparse.Namespace):
    """The `EvaluateRequest` of the options, refused in one line naming the option that does
    not fit (`CommandError`); None for a benchmark without ground truth (nothing to score)."""
    from defocus.app.evaluate import EvaluateRequest
    from optics.checks import check_depth_bounds

    check_depth_bounds(args.min_depth, math.inf if args.depth_cap is None else args.depth_cap,
                       names=("--min-depth", "--depth-cap"))
    benchmark = args.data in BENCHMARKS
    for refused, message in (
            (not benchmark and args.checkpoint is None, "give a checkpoint file, or --data "
             "NAME --root FOLDER to score a label-free method on a focal-stack benchmark"),
            (benchmark and args.root is None, f"--data {args.data} needs --root, the "
             "dataset folder"),
            (benchmark and args.max_samples is not None and args.max_samples < 1,
             f"--max-samples must be >= 1, got {args.max_samples}"),
            (benchmark and args.max_pixels < 1024,
             f"--max-pixels must be >= 1024, got {args.max_pixels}"),
            (args.last is not None and (benchmark or args.last < 1),
             f"--last must be >= 1, with a checkpoint and --data of depth samples, got "
             f"--last {args.last} with --data {args.data}")):
        if refused:
            raise CommandError(message)
    focus = args.focus
    if args.data == "motorcycle" or benchmark:
        own = "synthesized" if args.data == "motorcycle" else "real"
        if focus not in (None, own):
            raise CommandError(f"--focus {focus}: --data {args.data} has "
                               + ("its focused images rendered from its depth" if own ==
                                  "synthesized" else "real focal stacks only")
                               + f"; it takes --focus {own}")
        focus = own
    else:
        from datasets.registry import focus_of

        focus = focus_of(args.data, focus)
    common = {"checkpoint": args.checkpoint, "report": say(args)}
    tolerance = tolerance_of(args)
    if (tolerance is not None or args.robustness) and (benchmark or focus != "synthesized"):
        raise CommandError("--perturb-* and --robustness change focused images rendered with "
                           "the checkpoint's camera: they need a checkpoint and --focus "
                           f"synthesized, got --data {args.data} with {focus} focus")
    if benchmark:
        from datasets.registry import build_stack_dataset
        from models.protocols import PROTOCOLS

        dataset = build_stack_dataset(args.data, args.root, split=args.split)
        if args.data not in PROTOCOLS:
            print(f"{args.data}: {len(dataset)} scenes read from {args.root}; it has no "
                  "ground-truth depth, so it is judged by eye: nothing is scored (see "
                  f"examples/{args.data}.py for the depth maps)")
            return None
        return EvaluateRequest(dataset, protocol=args.data, method=args.method,
                               max_samples=args.max_samples, max_pixels=args.max_pixels,
                               **common)
    if args.data == "motorcycle":
        from datasets.middlebury import motorcycle_sample

        samples = [motorcycle_sample(args.scale)]
    else:
        samples = dataset_from_options(args, split=args.split or "test", seed_offset=1_000)
        if args.last is not None:
            from torch.utils.data import Subset

            samples = Subset(samples, range(max(len(samples) - args.last, 0), len(samples)))
    return EvaluateRequest(samples, depth_cap=args.depth_cap, crop=args.crop,
                           median_scaling=args.median_scaling, min_depth=args.min_depth,
                           synthesize=focus == "synthesized", tolerance=tolerance, **common)


def tolerance_of(args: argparse.Namespace):
    """The `optics.CameraTolerance` of `--perturb-*` (None where none is given)."""
    from optics import CameraTolerance

    values = (args.perturb_focus, args.perturb_f_stops, args.perturb_mask)
    if not any(values):
        return None
    if args.robustness:
        raise CommandError("--robustness scores its own set of tolerances: give it without "
                           "--perturb-*")
    try:
        return CameraTolerance(*values)
    except ValueError as error:
        raise CommandError(f"--perturb-focus/--perturb-f-stops/--perturb-mask: {error}") \
            from None


def run(args: argparse.Namespace) -> int:
    from defocus.app.evaluate import run_evaluation
    from models.metrics import format_table
    from models.protocols import PROTOCOLS

    plan = plan_json(args)
    request = request_of(args)
    if request is None:
        return 0
    if args.robustness:
        return print_robustness(request, plan, args.json)
    result = run_evaluation(request)
    if request.protocol is None:
        print(format_table({result.name: result.metrics}))
        if result.warning is not None:
            print(f"warning: {result.warning}")
        extra = {}
    else:
        protocol = PROTOCOLS[request.protocol]
        print(format_table({result.name: result.metrics}, metrics=protocol.metrics,
                           number_format="{:.4g}"))
        print(f"{request.protocol}: {result.metrics['images']:.0f} images; protocol: "
              f"{protocol.source}")
        extra = {"protocol": request.protocol}
    if plan is not None:
        write_json(plan, args.json, {**extra, **result.metrics})
    return 0


def print_robustness(request, plan, json_path: Path | None) -> int:
    """`defocus evaluate --robustness`: the table of `defocus.app.evaluate.robustness`, each
    row's abs rel against the design's, and the warnings; the rows to `--json`."""
    from defocus.app.evaluate import robustness
    from models.metrics import format_table

    rows = robustness(request)
    metrics = {name: result.metrics for name, result in rows.items()}
    print(format_table(metrics))
    design = next(iter(rows.values())).metrics["abs_rel"]
    for name, result in rows.items():
        print(f"  {name}: abs rel {result.metrics['abs_rel'] / design:.2f}x the design's"
              + (f" (warning: {result.warning})" if result.warning else ""))
    if plan is not None:
        write_json(plan, json_path, metrics)
    return 0


def benchmark_parser(dataset: str, split: str | None,
                     description: str) -> argparse.ArgumentParser:
    """The parser of a benchmark example script (`examples/<dataset>.py`): `defocus evaluate
    --data DATASET`'s options (`--split` defaults to `split`; `--max-samples` and
    `--max-pixels` to the device's, `defocus.app.experiment.BENCHMARK_DEFAULTS`), and where
    the label-free method runs (`--device`, `--threads`)."""
    parser = argparse.ArgumentParser(description=description, allow_abbrev=False,
                                     conflict_handler="resolve")
    add_arguments(parser, focus=False)
    parser.add_argument("--root", type=Path, required=True,
                        help="the dataset folder in its release layout (see the header)")
    parser.add_argument("--device", default="auto",
                        help="'auto' (CUDA when available), 'cpu', 'cuda', 'cuda:1', ...")
    parser.add_argument("--threads", type=int, default=0,
                        help="CPU threads of PyTorch (0: its default, one per core)")
    parser.set_defaults(data=dataset, split=split, max_pixels=None)
    return parser
