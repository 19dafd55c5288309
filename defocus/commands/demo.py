"""``defocus demo``: the README's main job.

1. Train the small depth-from-defocus network self-supervised (no depth labels in the loss) on the
   synthetic scenes of :mod:`datasets.synthetic` (camera :data:`~datasets.synthetic.SYNTHETIC_PRESET`:
   50 mm f/1.4 focused at 2 m and 6 m, effective pixel pitch 180 um).
2. Train the same network with supervised depth for the same number of steps.
3. Evaluate both on the real Middlebury motorcycle scene (never seen in training), downscaled by
   ``--scale``, whose focused images are rendered from its real depth through the same camera;
   add the direct optimisation baseline (:func:`~models.direct.fit_depth_direct`) and the best
   constant depth (an oracle: the abs-rel-optimal constant of the ground truth).
4. Print the metrics table; write ``metrics.json`` and the figures under ``--out``, among them
   ``focus_sweep.png``: the motorcycle rendered at four focus distances (``defocus render``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
import torch.nn.functional as F

METHODS = ("self_supervised", "supervised", "direct_optimisation", "constant")


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


def motorcycle_sample(scale: float = 0.25, preset=None) -> dict:
    """The real motorcycle scene in the sample format, downscaled by ``scale``, with focused
    images rendered from its real depth through ``preset`` (the synthetic preset by default).

    Depth is area-averaged over known pixels; a pixel stays valid only if all of its source
    pixels had known disparity.
    """
    from datasets.focus import render_focal_stack
    from datasets.middlebury import load_motorcycle
    from datasets.synthetic import SYNTHETIC_PRESET

    preset = preset or SYNTHETIC_PRESET
    scene = load_motorcycle()
    known = scene["mask"].to(scene["depth"].dtype)
    if scale != 1:
        image = F.interpolate(scene["image"], scale_factor=scale, mode="area")
        coverage = F.interpolate(known, scale_factor=scale, mode="area")
        depth = F.interpolate(scene["depth"] * known, scale_factor=scale, mode="area")
        depth = depth / coverage.clamp_min(1e-6)
        mask = coverage > 0.999
    else:
        image, depth, mask = scene["image"], scene["depth"], scene["mask"].bool()
    fill = depth[mask].max()
    depth = torch.where(mask, depth, fill)
    settings = preset.settings()
    with torch.no_grad():
        focused = render_focal_stack(image, depth, settings).clamp(0, 1)
    return {"image": image[0], "focused": focused, "camera": settings, "depth": depth[0],
            "mask": mask[0], "dataset": "middlebury", "id": "motorcycle"}


def plot_comparison(path: Path, sample: dict, predictions: dict, depth_range) -> Path:
    """One figure: the input, the ground truth and every method's depth and error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from models.figures import linear_to_srgb

    target, mask = sample["depth"][0], sample["mask"][0]
    n = len(predictions) + 1
    fig, axes = plt.subplots(2, n, figsize=(3.0 * n, 4.6), constrained_layout=True)
    axes[0, 0].imshow(linear_to_srgb(sample["image"]).permute(1, 2, 0).numpy())
    axes[0, 0].set_title("all in focus", fontsize=9)
    cmap = matplotlib.colormaps["magma_r"].with_extremes(bad="0.6")
    shown = axes[1, 0].imshow(torch.where(mask, target, torch.nan).numpy(), cmap=cmap,
                              vmin=depth_range[0], vmax=depth_range[1])
    axes[1, 0].set_title("ground truth (m)", fontsize=9)
    fig.colorbar(shown, ax=axes[1, 0], shrink=0.8)
    for i, (name, depth) in enumerate(predictions.items(), start=1):
        d = depth.reshape(target.shape)
        im = axes[0, i].imshow(d.numpy(), cmap=cmap, vmin=depth_range[0], vmax=depth_range[1])
        axes[0, i].set_title(f"{name} (m)", fontsize=9)
        error = torch.where(mask, (d - target).abs() / target, torch.nan)
        err = axes[1, i].imshow(error.numpy(), vmin=0, vmax=0.5,
                                cmap=matplotlib.colormaps["viridis"].with_extremes(bad="0.6"))
        axes[1, i].set_title(f"abs rel error, mean {float(error.nanmean()):.3f}", fontsize=9)
    fig.colorbar(im, ax=axes[0, 1:].tolist(), shrink=0.8)
    fig.colorbar(err, ax=axes[1, 1:].tolist(), shrink=0.8)
    for ax in axes.flat:
        ax.axis("off")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def run(args: argparse.Namespace) -> int:
    from datasets.synthetic import SYNTHETIC_PRESET, SyntheticScenes
    from defocus.commands.render import write_focus_sweep
    from models.direct import fit_depth_direct
    from models.figures import plot_prediction
    from models.metrics import best_constant_depth, depth_metrics, format_table
    from models.training import TrainConfig, Trainer

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
    batch = {k: v[None] for k, v in sample.items() if k in ("image", "focused")}
    camera = {k: v[None] for k, v in sample["camera"].items()}
    target, mask = sample["depth"][None], sample["mask"][None]
    print(f"motorcycle scene at {tuple(sample['image'].shape[-2:])} pixels; training on "
          f"{args.scenes} synthetic {args.size}x{args.size} scenes")

    results: dict[str, dict[str, float]] = {}
    predictions: dict[str, torch.Tensor] = {}
    for method, supervision in (("self_supervised", "self"), ("supervised", "depth")):
        cfg = TrainConfig(
            steps=args.steps, batch_size=args.batch_size, lr=args.lr, network="small",
            input_mode="aif+focused", supervision=supervision, out_dir=out / method,
            seed=args.seed, depth_min=depth_range[0], depth_max=depth_range[1],
            n_focus=len(preset.focus_distances), width=args.width, resume=False,
            log_every=10, smoothness_weight=args.smoothness_weight,
        )
        print(f"\n[{method}] training {cfg.steps} steps ({'no depth labels' if supervision == 'self' else 'depth labels'})")
        trainer = Trainer(cfg, train_set, val_set)
        trainer.fit()
        results[method] = trainer.evaluate([sample])
        predictions[method] = trainer.predict(batch["image"], batch["focused"], camera)[0]

    print(f"\n[direct_optimisation] fitting the motorcycle's depth, {args.direct_steps} steps")
    direct = fit_depth_direct(batch["image"], batch["focused"], camera, *depth_range,
                              steps=args.direct_steps, progress=True)
    results["direct_optimisation"] = depth_metrics(direct, target, mask)
    predictions["direct_optimisation"] = direct[0]

    constant = best_constant_depth(target, mask)
    predictions["constant"] = torch.full_like(target[0], constant)
    results["constant"] = depth_metrics(predictions["constant"][None], target, mask)

    for method, depth in predictions.items():
        plot_prediction(out / f"motorcycle_{method}.png", sample["image"], depth,
                        sample["focused"], sample["depth"], sample["mask"],
                        title=f"motorcycle: {method}", depth_range=depth_range)
    plot_comparison(out / "motorcycle_comparison.png", sample, predictions, depth_range)
    (out / "metrics.json").write_text(json.dumps(results, indent=2))
    print(f"wrote {write_focus_sweep(out)} (the real scene through a thin lens at four focus distances)")
    print(f"\nReal motorcycle scene ({tuple(sample['image'].shape[-2:])} pixels, "
          f"best constant depth {constant:.2f} m):")
    print(format_table(results))
    ratio = results["self_supervised"]["abs_rel"] / results["constant"]["abs_rel"]
    print(f"\nself-supervised abs rel / best constant abs rel = {ratio:.2f} "
          f"(goal <= 0.5); {time.perf_counter() - started:.0f} s in all")
    print(f"wrote {out / 'metrics.json'} and figures under {out}")
    return 0
