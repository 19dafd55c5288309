"""`defocus demo`: the README's main job.

1. Train the small depth-from-defocus network self-supervised (no depth labels in the loss) on the
   synthetic scenes of `datasets.synthetic` (camera `datasets.synthetic.SYNTHETIC_PRESET`:
   50 mm f/1.4 focused at 2 m and 6 m, effective pixel pitch 180 um).
2. Train the same network with supervised depth for the same number of steps.
3. Evaluate both on the real Middlebury motorcycle scene (never seen in training), downscaled by
   `--scale`, whose focused images are rendered from its real depth through the same camera;
   add the direct optimisation baseline (`models.direct.fit_depth_direct`), the sweep over
   depth that `defocus predict` runs without a model file (`models.sweep.SweepDepth`, no
   network) and the best constant depth (an oracle: the abs-rel-optimal constant of the ground
   truth).
4. Print the metrics table; write `metrics.json` and the figures under `--out`, among them
   `focus_sweep.png`: the motorcycle rendered at four focus distances (`defocus render`).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

METHODS = ("self_supervised", "supervised", "direct_optimisation", "sweep", "constant")


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


def run(args: argparse.Namespace) -> int:
    from datasets.middlebury import motorcycle_sample
    from datasets.synthetic import SYNTHETIC_PRESET, SyntheticScenes
    from defocus.commands.render import write_focus_sweep
    from models.experiment import compare_on_scene
    from models.metrics import format_table
    from models.plotting import plot_comparison, plot_prediction
    from models.training import TrainConfig

    if args.threads:
        torch.set_num_threads(args.threads)
    started = time.perf_counter()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    preset = SYNTHETIC_PRESET
    depth_range = (preset.min_depth, preset.depth_cap)
    train_set = SyntheticScenes(args.scenes, (args.size, args.size), preset, seed=args.seed)
    val_set = SyntheticScenes(8, (args.size, args.size), preset, seed=args.seed + 1)
    sample = motorcycle_sample(args.scale, preset)
    print(f"motorcycle scene at {tuple(sample['image'].shape[-2:])} pixels; training on "
          f"{args.scenes} synthetic {args.size}x{args.size} scenes")
    config = TrainConfig(
        steps=args.steps, batch_size=args.batch_size, lr=args.lr, network="small",
        input_mode="aif+focused", out_dir=out, seed=args.seed, depth_min=depth_range[0],
        depth_max=depth_range[1], n_focus=len(preset.focus_distances), width=args.width,
        resume=False, log_every=10, smoothness_weight=args.smoothness_weight,
    )
    results, predictions = compare_on_scene(config, train_set, val_set, sample,
                                            direct_steps=args.direct_steps)
    for method, depth in predictions.items():
        plot_prediction(out / f"motorcycle_{method}.png", sample["image"], depth,
                        sample["focused"], sample["depth"], sample["mask"],
                        title=f"motorcycle: {method}", depth_range=depth_range)
    plot_comparison(out / "motorcycle_comparison.png", sample, predictions, depth_range)
    (out / "metrics.json").write_text(json.dumps(results, indent=2))
    print(f"wrote {write_focus_sweep(out)} (the real scene through a thin lens at four focus "
          "distances)")
    constant = float(predictions["constant"].flatten()[0])
    print(f"\nReal motorcycle scene ({tuple(sample['image'].shape[-2:])} pixels, "
          f"best constant depth {constant:.2f} m):")
    print(format_table(results))
    ratio = results["self_supervised"]["abs_rel"] / results["constant"]["abs_rel"]
    print(f"\nself-supervised abs rel / best constant abs rel = {ratio:.2f} "
          f"(goal <= 0.5); {time.perf_counter() - started:.0f} s in all")
    print(f"wrote {out / 'metrics.json'} and figures under {out}")
    return 0
