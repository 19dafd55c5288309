"""`defocus render`: a defocus sweep of the real motorcycle scene through a thin-lens camera."""

from __future__ import annotations

import argparse
from pathlib import Path


def aperture_argument(text: str) -> str:
    """An argparse type: a PSF spec of `optics.aperture_spec` (checked, returned as written)."""
    from optics import parse_aperture

    try:
        parse_aperture(text)
    except (TypeError, ValueError) as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("runs/render"), help="output folder")
    parser.add_argument("--focus", type=float, nargs="+", default=[2.2, 3.0, 4.0, 5.0],
                        help="focus distances in metres (the scene spans about 2.1-5.0 m)")
    parser.add_argument("--focal-length", type=float, default=0.085, help="focal length in metres")
    parser.add_argument("--f-number", type=float, default=1.4, help="f-number (dimensionless)")
    parser.add_argument("--aperture", type=aperture_argument, default="disk",
                        help="PSF shape: gaussian[:SCALE], disk or polygon:N_BLADES[:ROTATION]")
    parser.add_argument("--mode", choices=["gather", "scatter", "layered"], default="scatter",
                        help="renderer semantics (see the rendering tutorial)")
    parser.add_argument("--scale", type=float, default=0.5,
                        help="downscale the scene by this factor first (1 = full 741x500 pixels)")


def write_focus_sweep(out: Path, focus_distances=(2.2, 3.0, 4.0, 5.0), focal_length=0.085,
                      f_number=1.4, aperture="disk", mode="scatter", scale=0.5) -> Path:
    """Render the sweep (`datasets.middlebury.motorcycle_focus_sweep`) and save
    `out/focus_sweep.png` (`optics.plotting.plot_focus_sweep`)."""
    from datasets.middlebury import motorcycle_focus_sweep
    from optics.plotting import plot_focus_sweep

    sweep = motorcycle_focus_sweep(focus_distances, focal_length, f_number, aperture, mode, scale)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "focus_sweep.png"
    plot_focus_sweep(sweep["image"], sweep["depth"], sweep["renders"], sweep["coc_px"],
                     sweep["settings"], path)
    return path


def run(args: argparse.Namespace) -> int:
    path = write_focus_sweep(args.out, args.focus, args.focal_length, args.f_number,
                             args.aperture, args.mode, args.scale)
    print(f"wrote {path}")
    return 0
