"""`defocus evaluate`: metrics of a trained checkpoint on a dataset or the motorcycle scene."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .train import add_data_arguments, build_dataset


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=Path, help="checkpoint file (.pt) written by training")
    add_data_arguments(parser, extra_choices=("motorcycle",), default="motorcycle")
    parser.set_defaults(split="test")
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


def run(args: argparse.Namespace) -> int:
    from models.metrics import format_table
    from models.training import COLLAPSE_FRACTION, Trainer

    trainer = Trainer.from_checkpoint(args.checkpoint)
    if args.data == "motorcycle":
        from datasets.middlebury import motorcycle_sample

        test_set = [motorcycle_sample(args.scale)]
    else:
        test_set = build_dataset(args, split=args.split, seed_offset=1_000)
    metrics = trainer.evaluate(test_set, depth_cap=args.depth_cap, crop=args.crop,
                               median_scaling=args.median_scaling, min_depth=args.min_depth)
    print(format_table({args.checkpoint.parent.parent.name or "model": metrics}))
    if metrics["at_depth_limits"] >= COLLAPSE_FRACTION:
        config = trainer.config
        print(f"warning: {metrics['at_depth_limits']:.0%} of the predicted pixels sit at "
              f"depth_min ({config.depth_min} m) or depth_max ({config.depth_max} m): the "
              "network collapsed to its depth limits; these metrics mean little")
    if args.json:
        args.json.write_text(json.dumps(metrics, indent=2))
    return 0
