"""`defocus predict`: depth of your own photos.

The work is `defocus.app.predict.predict`. It reads the photos and the camera (options, `--camera fit.json` written by `defocus calibrate`,
or the photos' EXIF) and calls `models.depth_from_photos.estimate_depth`: with no model file the
label-free methods (no network, any camera): the sweep over depth with an all-in-focus photo
(`--image`), the relative blur between the focused photos without one, or depth from focus of a
stack (`--method focus`); with a checkpoint of `defocus train` that network (for the camera it
was trained with).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from defocus.options import add_overwrite_argument, say


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=Path, nargs="?", default=None,
                        help="model file, a checkpoint of `defocus train` (a network for the "
                             "camera it was trained with); without one, a sweep over depth "
                             "(no network, any camera; needs --focused photos and --depth-range)")
    parser.add_argument("--image", type=Path, default=None,
                        help="all-in-focus photo (raw file, TIFF, PNG or JPEG; small aperture, "
                             "e.g. f/11); without it the focused photos alone are compared "
                             "with each other")
    parser.add_argument("--image-f-number", type=float, default=None, metavar="N",
                        help="the --image photo's f-number where it is only nearly sharp (e.g. "
                             "8 beside f/2.8 shots): it then counts as one more shot with its "
                             "own blur, compared by the relative blur (default: the "
                             "reference_f_number of --camera where it has one, else a perfect "
                             "all-in-focus photo)")
    parser.add_argument("--image-focus-distance", type=float, default=None, metavar="M",
                        help="with --image-f-number: where --image was focused, metres "
                             "(default: as the first focused photo)")
    parser.add_argument("--focused", type=Path, nargs="*", default=[], metavar="PHOTO",
                        help="focused photos of the same view, each focused elsewhere (1 or "
                             "more with --image, 2 or more without)")
    parser.add_argument("--method", default="auto",
                        help="without a model file: 'sweep' (needs --image), 'relative-blur' "
                             "(the focused photos alone), 'focus' (depth from focus of a stack "
                             "of 3 or more) or 'auto' (the sweep with --image, else the "
                             "relative blur)")
    parser.add_argument("--focus-distance", type=float, nargs="*", default=[], metavar="M",
                        help="focus distance of each focused photo, metres (default: --camera, "
                             "else EXIF SubjectDistance where every photo states it)")
    parser.add_argument("--f-number", type=float, nargs="*", default=[], metavar="N",
                        help="f-number of each focused photo (one value is repeated; "
                             "default: --camera, else EXIF)")
    parser.add_argument("--focal-length", type=float, default=None, metavar="M",
                        help="focal length, metres, e.g. 0.05 for 50 mm (default: --camera, "
                             "else EXIF)")
    parser.add_argument("--pixel-pitch", type=float, default=None, metavar="M",
                        help="effective pixel pitch of the photos as stored, metres (sensor "
                             "pitch times the downscaling; default: --camera, else EXIF)")
    parser.add_argument("--linear", action="store_true",
                        help="the PNG, TIFF or JPEG photos store linear values (scientific "
                             "cameras, some 16-bit exports), not sRGB; raw files are always "
                             "read as linear")
    parser.add_argument("--camera", type=Path, default=None, metavar="JSON",
                        help="camera settings JSON written by `defocus calibrate` (default: "
                             "none)")
    parser.add_argument("--depth-range", type=float, nargs=2, default=None,
                        metavar=("NEAR", "FAR"),
                        help="nearest and farthest depth of the scene, metres (needed without "
                             "a model file); a range wider than the scene costs a second pass, "
                             "not resolution: the depth is computed again over the scene's own "
                             "range")
    parser.add_argument("--side", choices=("beyond", "before", "both"), default="both",
                        help="where the scene lies when every photo is focused at one distance "
                             "(one focus plane blurs a depth and its mirror image alike): "
                             "'beyond' the focus plane (you focused on the nearest thing), "
                             "'before' it, or 'both' (no statement: the depths that may lie "
                             "mirrored are hatched in figure.png); a blur only the other side "
                             "explains stays there and is counted")
    parser.add_argument("--aggregation", default="semi-global",
                        help="without a model file: how the sweep combines neighbouring "
                             "pixels' costs, along scan lines with depth edges kept at the "
                             "photo's edges ('semi-global') or sums over square windows "
                             "('windows')")
    parser.add_argument("--device", default="auto",
                        help="where to compute: 'auto' (the GPU when CUDA is available, else the "
                             "CPU), 'cpu' or 'cuda[:N]'")
    parser.add_argument("--out", type=Path, default=Path("runs/predict"),
                        help="output folder: depth.npy (metres), depth_mm.png (16-bit "
                             "millimetres), confidence.png, all_in_focus.png, figure.png; with "
                             "--overwrite an earlier run's files of these names that this run "
                             "does not write are removed (one run per folder)")
    add_overwrite_argument(parser)


def run(args: argparse.Namespace) -> int:
    from defocus.app import request_from
    from defocus.app.predict import PredictRequest, predict

    camera = ("focus_distance", "f_number", "focal_length", "pixel_pitch")
    request = request_from(PredictRequest, args, progress=not args.quiet,
                           camera_options={name: getattr(args, name) for name in camera})
    out = predict(request, report=say(args))
    from defocus.app.predict import LOW_CONFIDENCE
    from models.depth_from_photos.side import OTHER_SIDE
    from models.plotting import percentile_range

    depth = out["depth"]
    low, high = percentile_range(depth)
    doubt = "" if not out["low_confidence"] else \
        f"; {out['low_confidence']:.0%} of the pixels have low confidence (< {LOW_CONFIDENCE:g})"
    if "side" in out:
        side, share = out["side"], float(out["off_side"].float().mean())
        other = OTHER_SIDE[side]
        doubt += (f"; stated: the scene lies {side} the focus plane at {out['focus_plane']:g} m"
                  + (f", but {share:.1%} of the pixels are blurred more than any depth {side} "
                     f"it allows and lie {other} it (hatched in figure.png)" if share else
                     ", and no pixel contradicts it"))
    mirrored = out.get("mirrored_depths")
    if mirrored is not None:
        doubt += (f"; depths {mirrored[0]:.2f}-{mirrored[1]:.2f} m may lie mirrored across the "
                  "focus plane (hatched in figure.png)")
    removed = "" if not out["removed"] else \
        f"; removed {', '.join(out['removed'])} of the earlier run (this run writes none)"
    print(f"depth {float(depth.min()):.2f}-{float(depth.max()):.2f} m (most pixels {low:.2f}-"
          f"{high:.2f} m){doubt}; wrote {', '.join(out['written'])} and figure.png under "
          f"{args.out}{removed}")
    return 0
