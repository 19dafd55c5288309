"""`defocus demo`: the README's main job (`defocus.app.demo.run_demo`): train, fit and evaluate
every method on the real motorcycle scene and print the table."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from defocus.options import add_overwrite_argument, say


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("runs/demo"), help="output folder")
    parser.add_argument("--steps", type=int, default=500,
                        help="training steps of each network (self-supervised and supervised)")
    parser.add_argument("--batch-size", type=int, default=8, help="training scenes per step")
    parser.add_argument("--lr", type=float, default=2e-3, help="Adam learning rate")
    parser.add_argument("--width", type=int, default=24,
                        help="channels of the small network's first scale")
    parser.add_argument("--scenes", type=int, default=256, help="number of synthetic scenes")
    parser.add_argument("--size", type=int, default=48,
                        help="height and width of the synthetic scenes, pixels")
    parser.add_argument("--scale", type=float, default=0.25,
                        help="downscale factor of the motorcycle scene (1 = 741x500 pixels); the "
                             "camera's 180 um effective pixel pitch refers to this resolution")
    parser.add_argument("--direct-steps", type=int, default=150,
                        help="Adam steps of the direct optimisation baseline")
    parser.add_argument("--smoothness-weight", type=float, default=0.01,
                        help="weight of the edge-aware depth smoothness in the self-supervised "
                             "loss (the paper: 0.001; 0.01 fills textureless regions better here)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (scenes, weights)")
    parser.add_argument("--threads", type=int, default=1,
                        help="CPU threads for torch (0: torch's default); the work is many small "
                             "operations, so one thread is about as fast and never oversubscribes")
    add_overwrite_argument(parser)


def run(args: argparse.Namespace) -> int:
    from defocus.app.demo import run_demo
    from models.metrics import format_table

    if args.threads:
        torch.set_num_threads(args.threads)
    started = time.perf_counter()
    result = run_demo(args.out, steps=args.steps, batch_size=args.batch_size, lr=args.lr,
                      width=args.width, scenes=args.scenes, size=args.size, scale=args.scale,
                      direct_steps=args.direct_steps, smoothness_weight=args.smoothness_weight,
                      seed=args.seed, progress=not args.quiet, overwrite=args.overwrite,
                      report=say(args))
    print(f"\nReal motorcycle scene ({result.scene_size} pixels, "
          f"best constant depth {result.constant_depth:.2f} m):")
    print(format_table(result.metrics))
    print(f"\nself-supervised abs rel / best constant abs rel = {result.ratio:.2f} "
          f"(lower is better; 1 is no better than one depth everywhere); "
          f"{time.perf_counter() - started:.0f} s in all")
    print(f"wrote {result.metrics_path} and figures under {args.out}")
    return 0
