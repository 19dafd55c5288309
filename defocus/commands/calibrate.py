"""`defocus calibrate`: fit a camera from photo pairs (sharp reference, defocused shot).

Each `--pair SHARP BLURRED DISTANCE` names a sharp reference raw file, the defocused shot of the
same planar target and the target's distance in metres. All defocused shots share the camera
setting being calibrated. Known values come from the options, else from the defocused files'
metadata; everything else is fitted.

`--data NAME --root DIR` fits instead the camera a dataset of real aperture pairs with depth
was shot with (e.g. `dslr`: f/8 and f/2.8 photos and registered depth), from its samples
(`datasets.calibration.calibrate_dataset`): the blur measured by depth and the thin lens with a
floor fitted to it; the focal length and f-number are the dataset's stated ones.

Writes a camera JSON (`predict --camera`, the loaders' `camera=`) and a figure.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from defocus.errors import CommandError
from defocus.options import add_overwrite_argument, aperture_argument, check_positive
from optics import LENS_APERTURE

KNOWN = ("focal_length", "f_number", "pixel_pitch", "focus_distance", "psf_scale")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--pair", nargs=3, action="append", default=None,
        metavar=("SHARP", "BLURRED", "DISTANCE"),
        help="sharp reference raw file, defocused raw file, target distance in metres (repeat)",
    )
    parser.add_argument("--data", default=None,
                        help="instead of --pair: a dataset of real pairs with depth, e.g. dslr")
    parser.add_argument("--root", type=Path, default=None, help="the --data's folder")
    parser.add_argument("--split", default="train", help="the --data's split")
    parser.add_argument("--scenes", default=None, metavar="START:STOP",
                        help="the --data's samples to fit on, a Python slice of the split "
                             "(e.g. 0:61; default: all)")
    parser.add_argument("--out", type=Path, default=Path("fit.json"), help="JSON of the fit")
    parser.add_argument("--figure", type=Path, default=None,
                        help="figure path (default: the JSON path with .png)")
    parser.add_argument("--aperture", "--psf", dest="aperture", type=aperture_argument,
                        default=LENS_APERTURE, metavar="SPEC",
                        help="PSF spec: disk, gaussian (scale fitted), gaussian:SCALE or "
                             "polygon:N_BLADES[:ROTATION]")
    parser.add_argument("--focal-length", type=float, help="known focal length, metres "
                        "(default: the metadata's)")
    parser.add_argument("--f-number", type=float, help="known f-number (default: the metadata's)")
    parser.add_argument("--pixel-pitch", type=float,
                        help="known sensor pixel pitch, metres (default: the metadata's EXIF "
                        "focal-plane resolution); binning multiplies it")
    parser.add_argument("--focus-distance", type=float, help="known focus distance, metres")
    parser.add_argument("--psf-scale", type=float, help="known Gaussian sigma per CoC diameter")
    parser.add_argument("--fit", action="append", default=[], choices=KNOWN[1:4],
                        help="fit this parameter even if the metadata gives it (repeatable)")
    parser.add_argument("--binning", type=int, default=1,
                        help="shrink the raw images by this factor (2: half-size Bayer binning)")
    parser.add_argument("--white-balance", choices=["camera", "daylight", "none"],
                        default="camera", help="white balance of the decoded images")
    parser.add_argument("--margin", type=int, default=None, help="border left out, pixels")
    parser.add_argument("--adam-steps", type=int, default=60, help="Adam iterations")
    parser.add_argument("--lbfgs-steps", type=int, default=40, help="L-BFGS iterations")
    add_overwrite_argument(parser)


#: Options of the --pair mode that --data ignores, with their defaults.
PAIR_ONLY = {"--focal-length": ("focal_length", None), "--f-number": ("f_number", None),
             "--pixel-pitch": ("pixel_pitch", None), "--psf-scale": ("psf_scale", None),
             "--fit": ("fit", []), "--binning": ("binning", 1),
             "--white-balance": ("white_balance", "camera"), "--margin": ("margin", None),
             "--adam-steps": ("adam_steps", 60), "--lbfgs-steps": ("lbfgs_steps", 40)}
#: Options of the --data mode that --pair ignores, with their defaults.
DATASET_ONLY = {"--root": ("root", None), "--split": ("split", "train"),
                "--scenes": ("scenes", None)}


def check_mode_options(args: argparse.Namespace) -> None:
    """Refuse options that the chosen mode (--pair or --data) would ignore."""
    mode, ignored = ("--data", PAIR_ONLY) if args.data is not None \
        else ("--pair", DATASET_ONLY)
    given = [option for option, (name, default) in ignored.items()
             if getattr(args, name) != default]
    if given:
        why = (" (the focal length and f-number are the dataset's stated ones)"
               if mode == "--data" else "")
        raise CommandError(f"{', '.join(given)} do(es) nothing with {mode}{why}; leave "
                           f"{'it' if len(given) == 1 else 'them'} out")


def run_dataset(args: argparse.Namespace, plan=None) -> int:
    from defocus.app.calibrate import calibrate_from_dataset
    from optics import plot_depth_calibration

    fit, count = calibrate_from_dataset(args.data, args.root, args.split, args.scenes,
                                        args.aperture, args.focus_distance, not args.quiet)
    values = fit.settings.to_dict()
    print(f"{args.data}: {count} samples of {args.split!r}")
    for name in ("focus_distance", "pixel_pitch", "f_number", "focal_length", "aperture"):
        print(f"  {name}: {values[name]}")
    for name, value in fit.extras().items():
        print(f"  {name}: {value}")
    return _write(args, fit.to_json, lambda path: plot_depth_calibration(fit, path), plan)


def run(args: argparse.Namespace) -> int:
    from defocus.app.calibrate import calibrate_from_pairs
    from optics import plot_calibration

    if (args.pair is None) == (args.data is None):
        raise CommandError("give either --pair SHARP BLURRED DISTANCE (repeat) or --data NAME "
                           "--root DIR")
    check_positive(args, "focal_length", "f_number", "pixel_pitch", "focus_distance", "psf_scale")
    check_mode_options(args)
    plan = _plan(args)
    if args.data is not None:
        return run_dataset(args, plan)
    known = {"focal_length": args.focal_length, "f_number": args.f_number,
             "pixel_pitch": args.pixel_pitch, "focus_distance": args.focus_distance,
             "psf_scale": args.psf_scale}
    result, sources = calibrate_from_pairs(
        args.pair, known, fit=args.fit, aperture=args.aperture, binning=args.binning,
        white_balance=args.white_balance, margin_px=args.margin, adam_steps=args.adam_steps,
        lbfgs_steps=args.lbfgs_steps, progress=not args.quiet)
    for name, source in sources.items():
        print(f"{name}: from the {source}")
    print(result.table())
    return _write(args, result.save, lambda path: plot_calibration(result, path), plan)


def _plan(args: argparse.Namespace):
    from defocus.app.calibrate import plan_fit_outputs

    return plan_fit_outputs(args.out, args.figure, args.overwrite, args.pair or (),
                            args.root)[0]


def _write(args: argparse.Namespace, save, plot, plan=None) -> int:
    from defocus.app.calibrate import write_fit

    figure = write_fit(args.out, args.figure, save, plot, plan)
    print(f"wrote {args.out} and {figure}")
    return 0
