"""`defocus calibrate`: fit a camera from photo pairs (sharp reference, defocused shot).

Each `--pair SHARP BLURRED DISTANCE` names a sharp reference raw file, the defocused shot of the
same planar target and the target's distance in metres. All defocused shots share the camera
setting being calibrated. Known values come from the options, else from the defocused files'
metadata; everything else is fitted.

`--dataset NAME --root DIR` fits instead the camera a dataset of real aperture pairs with depth
was shot with (e.g. `dslr`: f/8 and f/2.8 photos and registered depth), from its samples
(`datasets.calibration.calibrate_dataset`): the blur measured by depth and the thin lens with a
floor fitted to it; the focal length and f-number are the dataset's stated ones.

Writes a camera JSON (`predict --camera`, the loaders' `camera=`) and a figure.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from defocus.commands.render import aperture_argument

KNOWN = ("focal_length", "f_number", "pixel_pitch", "focus_distance", "psf_scale")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--pair", nargs=3, action="append", default=None,
        metavar=("SHARP", "BLURRED", "DISTANCE"),
        help="sharp reference raw file, defocused raw file, target distance in metres (repeat)",
    )
    parser.add_argument("--dataset", default=None,
                        help="instead of --pair: a dataset of real pairs with depth, e.g. dslr")
    parser.add_argument("--root", type=Path, default=None, help="the --dataset's folder")
    parser.add_argument("--split", default="train", help="the --dataset's split")
    parser.add_argument("--scenes", default=None, metavar="START:STOP",
                        help="the --dataset's samples to fit on, a Python slice of the split "
                             "(e.g. 0:61; default: all)")
    parser.add_argument("--out", type=Path, default=Path("fit.json"), help="JSON of the fit")
    parser.add_argument("--figure", type=Path, default=None,
                        help="figure path (default: the JSON path with .png)")
    parser.add_argument("--psf", type=aperture_argument, default="disk",
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
    parser.add_argument("--progress", action="store_true", help="show progress bars")


def _distance(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"a --pair distance must be a number of metres, got {text!r}") from None
    if not value > 0:
        raise ValueError(f"a --pair distance must be > 0 metres, got {text!r}")
    return value


def _slice(text: str | None, length: int) -> list[int]:
    if text is None:
        return list(range(length))
    try:
        parts = [int(p) if p else None for p in text.split(":")]
        indices = list(range(length))[slice(*parts)]
    except (ValueError, TypeError):
        raise ValueError(f"--scenes must be a slice START:STOP[:STEP] of sample indices, got "
                         f"{text!r}") from None
    if not indices:
        raise ValueError(f"--scenes {text!r} selects none of the {length} samples")
    return indices


def run_dataset(args: argparse.Namespace) -> int:
    from datasets.calibration import calibrate_dataset
    from datasets.registry import dataset_classes
    from optics import plot_depth_calibration

    if args.root is None:
        raise ValueError("--dataset needs --root, the dataset's folder")
    classes = dataset_classes()
    if args.dataset not in classes or args.dataset == "synthetic":
        raise ValueError(f"--dataset must be a dataset of real photos with depth, one of "
                         f"{sorted(set(classes) - {'synthetic'})}, got {args.dataset!r}")
    dataset = classes[args.dataset](args.root, split=args.split)  # full resolution
    indices = _slice(args.scenes, len(dataset))
    psf = "gaussian:0.5" if args.psf == "gaussian" else args.psf
    fit = calibrate_dataset(dataset, indices, aperture=psf,
                            focus_distance=args.focus_distance, progress=args.progress)
    values = fit.settings.to_dict()
    print(f"{args.dataset}: {len(indices)} samples of {args.split!r}")
    for name in ("focus_distance", "pixel_pitch", "f_number", "focal_length", "psf"):
        print(f"  {name}: {values[name]}")
    for name, value in fit.extras().items():
        print(f"  {name}: {value}")
    return _write(args, fit.to_json, lambda path: plot_depth_calibration(fit, path))


def run(args: argparse.Namespace) -> int:
    from defocus.cli import CommandError
    from optics import CalibrationPair, calibrate, plot_calibration, read_raw

    if (args.pair is None) == (args.dataset is None):
        raise CommandError("give either --pair SHARP BLURRED DISTANCE (repeat) or --dataset NAME "
                           "--root DIR")
    if args.dataset is not None:
        return run_dataset(args)
    pairs, meta = [], None
    for sharp_path, blurred_path, distance_text in args.pair:
        distance = _distance(distance_text)
        options = {"binning": args.binning, "white_balance": args.white_balance}
        sharp, _ = read_raw(sharp_path, **options)
        blurred, meta = read_raw(blurred_path, **options)
        if sharp.shape != blurred.shape:
            raise ValueError(
                f"{sharp_path} is {tuple(sharp.shape[-2:])} pixels but {blurred_path} is "
                f"{tuple(blurred.shape[-2:])}; a pair must have one size"
            )
        pairs.append(CalibrationPair(sharp, blurred, distance, name=Path(blurred_path).stem))
    given = {
        "focal_length": args.focal_length,
        "f_number": args.f_number,
        "pixel_pitch": None if args.pixel_pitch is None else args.pixel_pitch * args.binning,
        "focus_distance": args.focus_distance,
        "psf_scale": args.psf_scale,
    }
    from_metadata = {"focal_length": meta.focal_length, "f_number": meta.f_number,
                     "pixel_pitch": meta.effective_pixel_pitch}
    sources = {}
    for name in ("focal_length", "f_number", "pixel_pitch"):
        if given[name] is not None:
            sources[name] = "option"
        elif name not in args.fit and from_metadata[name] is not None:
            given[name] = from_metadata[name]
            sources[name] = "metadata"
    if given["focal_length"] is None:
        raise CommandError("the focal length is unknown: the files do not state it; pass "
                           "--focal-length in metres")
    result = calibrate(
        pairs, psf=args.psf, margin_px=args.margin, adam_steps=args.adam_steps,
        lbfgs_steps=args.lbfgs_steps, progress=args.progress, **given,
    )
    for name, source in sources.items():
        print(f"{name}: from the {source}")
    print(result.table())
    return _write(args, result.save, lambda path: plot_calibration(result, path))


def _write(args: argparse.Namespace, save, plot) -> int:
    """Save the fit's JSON at `--out` and its figure beside it (or at `--figure`)."""
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save(args.out)
    figure = args.figure or args.out.with_suffix(".png")
    plot(figure)
    print(f"wrote {args.out} and {figure}")
    return 0
