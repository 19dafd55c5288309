"""`defocus predict`: depth of your own photos.

With no model file it sweeps over depth (`models.sweep.SweepDepth`: no network, any camera). A
model file is a checkpoint of `defocus train` (a network for the camera it was trained with) or
the weights of `defocus pretrain` (the camera-general network: it reads the blur of each focused
photo in pixels and solves the thin lens of your camera). Camera values not given are read from
`--camera fit.json` (written by `defocus calibrate`) or from the photos' EXIF.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=Path, nargs="?", default=None,
                        help="model file: a checkpoint of `defocus train` or the weights of "
                             "`defocus pretrain` (camera-general); default: no network, a "
                             "sweep over depth (needs --focused photos and --depth-range)")
    parser.add_argument("--image", type=Path, required=True,
                        help="all-in-focus photo (raw file, TIFF, PNG or JPEG; small aperture, "
                             "e.g. f/11)")
    parser.add_argument("--focused", type=Path, nargs="*", default=[],
                        help="focused photos of the same view (2-5, each focused elsewhere)")
    parser.add_argument("--focus-distance", type=float, nargs="*", default=[],
                        help="focus distance of each focused photo, metres (default: --camera, "
                             "else EXIF SubjectDistance where every photo states it)")
    parser.add_argument("--f-number", type=float, nargs="*", default=[],
                        help="f-number of each focused photo (one value is repeated; "
                             "default: --camera, else EXIF)")
    parser.add_argument("--focal-length", type=float, default=None,
                        help="focal length, metres, e.g. 0.05 for 50 mm (default: --camera, "
                             "else EXIF)")
    parser.add_argument("--pixel-pitch", type=float, default=None,
                        help="effective pixel pitch of the photos as stored, metres (sensor "
                             "pitch times the downscaling; default: --camera, else EXIF)")
    parser.add_argument("--camera", type=Path, default=None,
                        help="camera settings JSON written by `defocus calibrate`")
    parser.add_argument("--depth-range", type=float, nargs=2, default=None,
                        metavar=("NEAR", "FAR"),
                        help="nearest and farthest depth of the scene, metres (camera-general "
                             "model); a range wider than the scene costs a second pass, not "
                             "resolution: the depth is computed again over the scene's own range")
    parser.add_argument("--aggregation", default=None,
                        help="without a model file: how the sweep combines neighbouring "
                             "pixels' costs, 'semi-global' (default: along scan lines, depth "
                             "edges kept at the photo's edges) or 'windows' (sums over square "
                             "windows, the sweep before 2026-11-23)")
    parser.add_argument("--device", default="auto",
                        help="where to compute: 'auto' (the GPU when CUDA is available, else the "
                             "CPU), 'cpu' or 'cuda[:N]'")
    parser.add_argument("--out", type=Path, default=Path("runs/predict"),
                        help="output folder: depth.npy (metres), depth_mm.png (16-bit "
                             "millimetres), confidence.png, figure.png")


def run(args: argparse.Namespace) -> int:
    import warnings

    import numpy as np
    import torch
    from PIL import Image

    from datasets.photos import describe_settings, photo_settings, read_photo
    from defocus.cli import CommandError
    from models.plotting import plot_prediction
    from models.pretrained import is_weights_file, load_weights
    from models.sweep import SweepDepth
    from models.training import Trainer, check_device, select_device
    from optics import CameraSettings

    try:
        check_device(args.device)
    except ValueError as error:
        raise CommandError(f"--device: {error}") from None
    device = select_device(args.device)
    # the model first: a file that is no model is refused before any photo is read
    if args.aggregation is not None and args.checkpoint is not None:
        raise CommandError("--aggregation chooses how the sweep works: give it without a model "
                           f"file (got {args.checkpoint})")
    if args.checkpoint is None:
        options = {} if args.aggregation is None else {"aggregation": args.aggregation}
        try:
            model = SweepDepth(progress=True, **options)
        except ValueError as error:
            raise CommandError(f"--aggregation: {error}") from None
        general = True
    elif is_weights_file(args.checkpoint):
        model, general = load_weights(args.checkpoint).to(device), True
    else:
        model, general = Trainer.from_checkpoint(args.checkpoint, device=str(device)), False
    image, image_info = read_photo(args.image)
    photos = [read_photo(path) for path in args.focused]
    for path, (photo, _) in zip(args.focused, photos, strict=True):
        if photo.shape != image.shape:
            raise CommandError(f"{path} is {tuple(photo.shape[-2:])} pixels but {args.image} is "
                               f"{tuple(image.shape[-2:])}; all photos must have one size")
        if torch.equal(photo, image):
            warnings.warn(f"{path} is identical to {args.image}: there is no defocus to read",
                          stacklevel=1)
    focused = torch.stack([p for p, _ in photos]) if photos else None
    calibration = CameraSettings.from_json(args.camera) if args.camera else None
    sources: dict[str, str] = {}
    settings = photo_settings([info for _, info in photos], args.focus_distance,
                              args.f_number, args.focal_length, args.pixel_pitch,
                              calibration, sources=sources) if photos else None
    if settings is not None:
        print(describe_settings(settings, sources))
    if general:
        depth, confidence, depth_range = _camera_general(
            args, model, image.to(device), focused.to(device) if photos else None, settings,
            [image_info, *(info for _, info in photos)])
    else:
        depth, confidence, depth_range = _checkpoint(model, image, focused, settings)
    if not bool(torch.isfinite(depth).all()):
        raise CommandError("the prediction is not finite; nothing written")
    args.out.mkdir(parents=True, exist_ok=True)
    np.save(args.out / "depth.npy", depth[0].numpy().astype(np.float32))
    millimetres = np.clip(np.round(depth[0].numpy() * 1000), 0, 65535).astype(np.uint16)
    Image.fromarray(millimetres).save(args.out / "depth_mm.png")
    written = ["depth.npy", "depth_mm.png"]
    if confidence is not None:
        Image.fromarray((confidence[0].clamp(0, 1).numpy() * 255).astype(np.uint8)).save(
            args.out / "confidence.png")
        written.append("confidence.png")
    plot_prediction(args.out / "figure.png", image, depth,
                    None if focused is None else focused, title=str(args.image.name),
                    depth_range=depth_range, confidence=confidence)
    print(f"depth {float(depth.min()):.2f}-{float(depth.max()):.2f} m; wrote "
          f"{', '.join(written)} and figure.png under {args.out}")
    return 0


def _camera_general(args, model, image, focused, settings, infos):
    import warnings

    from datasets.photos import compression_warning
    from defocus.cli import CommandError
    from models.blur import predict_depth

    if focused is None or len(focused) < 1:
        raise CommandError("depth from defocus needs --focused photos (2 or more, each "
                           "focused at its own --focus-distance)")
    if args.depth_range is None:
        raise CommandError("give --depth-range NEAR FAR (metres): the thin lens has two depths "
                           "for each blur, the range picks the right one")
    near, far = args.depth_range
    out = predict_depth(model, image, focused, settings.to(image.dtype), near, far)
    moved = ", ".join(f"({dy:+.1f}, {dx:+.1f}, x{zoom:.4f}, {turn:+.2f} deg)"
                      for (dy, dx), zoom, turn in zip(out["shifts"].tolist(), out["zooms"].tolist(),
                                                      out["rotations"].tolist(), strict=True))
    swept = out["depth_range"]
    if tuple(swept) != (near, far):
        print(f"the scene lies within {swept[0]:.2f}-{swept[1]:.2f} m of the stated "
              f"{near:g}-{far:g} m: depth computed again over that range, at a finer resolution")
    print(f"working resolution {out['scale']:.3f} x the photos; focused photos aligned: moved by "
          f"{moved} (pixels down, right; magnification; rotation, clockwise)")
    jpeg = compression_warning(infos, out["scale"])
    if jpeg is not None:
        warnings.warn(jpeg, stacklevel=1)
    return out["depth"].cpu(), out["confidence"].cpu(), tuple(swept)  # the figure's colours


def _checkpoint(trainer, image, focused, settings):
    from defocus.cli import CommandError

    config = trainer.config
    if config.input_mode == "aif+focused":
        n = 0 if focused is None else len(focused)
        if n != config.n_focus:
            raise CommandError(f"this network needs {config.n_focus} --focused photos, got {n}")
        depth = trainer.predict(image[None], focused[None], settings.to(image.dtype))[0]
    else:
        depth = trainer.predict(image[None])[0]
    return depth.cpu(), None, (config.depth_min, config.depth_max)
