"""``defocus render``: a defocus sweep of the real motorcycle scene through a thin-lens camera."""

from __future__ import annotations

import argparse
from pathlib import Path

import torch


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("runs/render"), help="output folder")
    parser.add_argument(
        "--focus",
        type=float,
        nargs="+",
        default=[2.2, 3.0, 4.0, 5.0],
        help="focus distances in metres (the scene spans about 2.1-5.0 m)",
    )
    parser.add_argument("--focal-length", type=float, default=0.085, help="focal length in metres")
    parser.add_argument("--f-number", type=float, default=1.4, help="f-number (dimensionless)")
    parser.add_argument(
        "--aperture", choices=["gaussian", "disk", "hexagon"], default="disk", help="PSF shape"
    )
    parser.add_argument(
        "--mode",
        choices=["gather", "scatter", "layered"],
        default="scatter",
        help="renderer semantics (see the rendering tutorial)",
    )
    parser.add_argument(
        "--scale",
        type=float,
        default=0.5,
        help="downscale the scene by this factor first (1 = full 741x500 pixels)",
    )


def focus_sweep(focus_distances, focal_length, f_number, aperture, mode, scale):
    """Render the motorcycle at each focus distance; returns the scene and the renders."""
    import torch.nn.functional as F

    from datasets.middlebury import load_motorcycle
    from optics import Camera, Disk, Gaussian, Polygon, Sensor, ThinLens

    scene = load_motorcycle()
    image, depth = scene["image"], scene["depth"]
    calib = scene["calib"]
    if scale != 1:
        image = F.interpolate(image, scale_factor=scale, mode="area")
        depth = F.interpolate(depth, scale_factor=scale, mode="nearest")
    # The pixel pitch that makes this focal length match the scene's calibrated focal length.
    pixel_pitch = focal_length / calib["focal_length_px"]
    psf = {"gaussian": Gaussian(), "disk": Disk(), "hexagon": Polygon(6)}[aperture]
    renders = []
    for focus in focus_distances:
        camera = Camera(
            ThinLens(focal_length, f_number, focus), Sensor(pixel_pitch, downsample=1 / scale), psf
        )
        with torch.no_grad():
            renders.append((focus, camera.render(image, depth, mode=mode), camera.coc_px(depth)))
    return image, depth, renders


def run(args: argparse.Namespace) -> int:
    path = write_focus_sweep(
        args.out, args.focus, args.focal_length, args.f_number, args.aperture, args.mode, args.scale
    )
    print(f"wrote {path}")
    return 0


def write_focus_sweep(
    out: Path,
    focus_distances=(2.2, 3.0, 4.0, 5.0),
    focal_length: float = 0.085,
    f_number: float = 1.4,
    aperture: str = "disk",
    mode: str = "scatter",
    scale: float = 0.5,
) -> Path:
    """Render the focus sweep and save ``out/focus_sweep.png`` (scene, renders, CoC maps)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from models.figures import linear_to_srgb

    image, depth, renders = focus_sweep(
        focus_distances, focal_length, f_number, aperture, mode, scale
    )
    out.mkdir(parents=True, exist_ok=True)
    n = len(renders) + 1
    fig, axes = plt.subplots(2, n, figsize=(3.2 * n, 5.0), constrained_layout=True)

    def show_rgb(ax, linear):
        ax.imshow(linear_to_srgb(linear[0]).permute(1, 2, 0).numpy())
        ax.axis("off")

    show_rgb(axes[0, 0], image)
    axes[0, 0].set_title("all in focus")
    im = axes[1, 0].imshow(depth[0, 0].numpy(), cmap="magma_r")
    axes[1, 0].set_title("depth (m)")
    axes[1, 0].axis("off")
    fig.colorbar(im, ax=axes[1, 0], shrink=0.8)
    coc_max = max(float(c.max()) for _, _, c in renders)
    for i, (focus, render, coc) in enumerate(renders, start=1):
        show_rgb(axes[0, i], render)
        axes[0, i].set_title(f"focus {focus:g} m, f/{f_number:g}")
        im = axes[1, i].imshow(coc[0, 0].numpy(), cmap="viridis", vmin=0, vmax=coc_max)
        axes[1, i].set_title("CoC diameter (px)")
        axes[1, i].axis("off")
    fig.colorbar(im, ax=axes[1, 1:].tolist(), shrink=0.8)
    path = out / "focus_sweep.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
