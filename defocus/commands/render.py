"""`defocus render`: a defocus sweep of the real motorcycle scene through a thin-lens camera."""

from __future__ import annotations

import argparse
from pathlib import Path

from defocus.options import add_overwrite_argument, aperture_argument, check_positive
from optics import LENS_APERTURE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    # a string, not a Path: Path("") is the current folder, and an empty --out is refused
    parser.add_argument("--out", type=str, default=Path("runs/render"), help="output folder")
    parser.add_argument("--focus-distance", type=float, nargs="+", default=[2.2, 3.0, 4.0, 5.0],
                        metavar="M",
                        help="focus distance of each rendered photo, metres (the scene spans "
                             "about 2.1-5.0 m)")
    parser.add_argument("--focal-length", type=float, default=0.085, help="focal length in metres")
    parser.add_argument("--f-number", type=float, default=1.4, help="f-number (dimensionless)")
    parser.add_argument("--aperture", type=aperture_argument, default=LENS_APERTURE,
                        help="PSF shape: gaussian[:SCALE], disk or polygon:N_BLADES[:ROTATION]")
    parser.add_argument("--mode", choices=["gather", "scatter", "layered"], default="scatter",
                        help="renderer semantics (see the rendering tutorial)")
    parser.add_argument("--scale", type=float, default=0.5,
                        help="downscale the scene by this factor first, in (0, 1] (1 = full 741x500 "
                             "pixels; at least 0.002, one pixel a side)")
    add_overwrite_argument(parser)


def run(args: argparse.Namespace) -> int:
    check_positive(args, "focus_distance", "focal_length", "f_number")
    from defocus.app.render import write_focus_sweep

    path = write_focus_sweep(args.out, args.focus_distance, args.focal_length, args.f_number,
                             args.aperture, args.mode, args.scale, args.overwrite)
    print(f"wrote {path}")
    return 0
