"""`defocus predict`: depth of your own photos.

It reads the photos and the camera (options, `--camera fit.json` written by `defocus calibrate`,
or the photos' EXIF) and calls `models.depth_from_photos.estimate_depth`: with no model file the
label-free methods (no network, any camera): the sweep over depth with an all-in-focus photo
(`--image`), the relative blur between the focused photos without one, or depth from focus of a
stack (`--method focus`); with a checkpoint of `defocus train` that network (for the camera it
was trained with).
"""

from __future__ import annotations

import argparse
from pathlib import Path


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
                        help="focused photos of the same view, each focused elsewhere (1-5 "
                             "with --image, 2 or more without)")
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
                             "millimetres), confidence.png, all_in_focus.png, figure.png")


def run(args: argparse.Namespace) -> int:
    import warnings

    import numpy as np
    import torch
    from PIL import Image

    from datasets.photos import describe_settings, photo_settings, read_photo, save_photo
    from defocus.cli import CommandError
    from models.depth_from_photos import METHODS, TrainedNetwork, choose_method, estimate_depth
    from models.depth_from_photos.cost_volume import AGGREGATIONS
    from models.plotting import plot_prediction
    from models.pretrained import is_weights_file, load_weights
    from models.training import check_device, load_model, select_device
    from optics import CameraSettings

    try:
        check_device(args.device)
    except ValueError as error:
        raise CommandError(f"--device: {error}") from None
    device = select_device(args.device)
    # the model first: a file that is no model is refused before any photo is read
    model = None
    if args.aggregation not in AGGREGATIONS:
        raise CommandError(f"--aggregation must be one of {', '.join(AGGREGATIONS)}, got "
                           f"{args.aggregation!r}")
    if args.method not in ("auto", *METHODS):
        raise CommandError(f"--method must be auto or one of {', '.join(METHODS)}, got "
                           f"{args.method!r}")
    if args.checkpoint is not None:
        if args.aggregation != "semi-global" or args.method != "auto":
            raise CommandError("--aggregation and --method choose how the label-free methods "
                               f"work: give them without a model file (got {args.checkpoint})")
        if is_weights_file(args.checkpoint):  # the experimental camera-general network
            model = load_weights(args.checkpoint).to(device)
        else:
            network, config = load_model(args.checkpoint, device)
            model = TrainedNetwork(network, config.input_mode, config.n_focus,
                                   (config.depth_min, config.depth_max))
    if args.image is None and (model is not None or len(args.focused) < 2):
        raise CommandError("give --image (an all-in-focus photo), or 2 or more --focused photos "
                           f"focused at different distances (got {len(args.focused)})")
    calibration, extra = CameraSettings.read_json(args.camera) if args.camera else (None, {})
    if args.image is not None and args.image_f_number is None and model is None \
            and args.method in ("auto", "relative-blur"):
        # a camera fitted with references that were not sharp (e.g. f/8 beside f/2.8)
        reference = extra.get("reference_f_number")
        if reference is not None:
            args.image_f_number = float(reference)
            print(f"--image counts as an f/{args.image_f_number:g} shot (reference_f_number of "
                  f"{args.camera}); --method sweep takes it as all-in-focus instead")
    if args.image_focus_distance is not None and args.image_f_number is None:
        raise CommandError("--image-focus-distance goes with --image-f-number (the --image "
                           "photo as one more shot)")
    if args.image_f_number is not None and (args.image is None or model is not None
                                            or args.method in ("sweep", "focus")):
        raise CommandError("--image-f-number makes --image one more shot of the relative blur: "
                           "give --image, no model file, and --method auto or relative-blur")
    if args.image is None and args.method == "sweep":
        raise CommandError("--method sweep compares the focused photos with an all-in-focus "
                           "photo: give --image")
    encoding = "linear" if args.linear else "srgb"
    image, image_info = read_photo(args.image, encoding=encoding) if args.image else (None, None)
    photos = [read_photo(path, encoding=encoding) for path in args.focused]
    first_path, first = (args.image, image) if image is not None \
        else (args.focused[0], photos[0][0])
    for path, (photo, _) in zip(args.focused, photos, strict=True):
        if photo.shape != first.shape:
            raise CommandError(f"{path} is {tuple(photo.shape[-2:])} pixels but {first_path} is "
                               f"{tuple(first.shape[-2:])}; all photos must have one size")
        if path != first_path and torch.equal(photo, first):
            warnings.warn(f"{path} is identical to {first_path}: there is no defocus to read",
                          stacklevel=1)
    del first
    # without focused photos only a network that reads the all-in-focus photo alone runs
    focused = torch.stack([p for p, _ in photos]) if photos else image[None]
    photos = [(None, info) for _, info in photos]  # one copy of the pixels (memory)
    sources: dict[str, str] = {}
    settings = photo_settings([info for _, info in photos], args.focus_distance,
                              args.f_number, args.focal_length, args.pixel_pitch,
                              calibration, sources=sources) if photos else None
    if settings is not None:
        print(describe_settings(settings, sources))
    if model is None or not isinstance(model, TrainedNetwork):
        if not photos:
            raise CommandError("depth from defocus needs --focused photos (2 or more, each "
                               "focused at its own --focus-distance)")
        if args.depth_range is None:
            raise CommandError("give --depth-range NEAR FAR (metres): the thin lens has two "
                               "depths for each blur, the range picks the right one")
        depth_range = tuple(args.depth_range)
    else:
        depth_range = model.depth_range
        if model.input_mode == "aif+focused" and len(photos) != model.n_focus:
            raise CommandError(f"this network needs {model.n_focus} --focused photos, got "
                               f"{len(photos)}")
    image_settings = None
    if args.image_f_number is not None:
        focus = args.image_focus_distance or float(settings.focus_distance.reshape(-1)[0])
        image_settings = settings.select_shots([0]).replace(
            f_number=torch.tensor([args.image_f_number], dtype=torch.float64),
            focus_distance=torch.tensor([focus], dtype=torch.float64))
    method = args.method if args.method != "auto" or model is not None \
        else choose_method(image is not None and image_settings is None,
                           len(photos) + (image_settings is not None))
    options = {"aggregation": args.aggregation} if method in ("sweep", "relative-blur") \
        and model is None else None
    out = estimate_depth(focused.to(device), settings, depth_range,
                         image=None if image is None else image.to(device),
                         image_settings=image_settings, method=method,
                         model=model, options=options, progress=True)
    infos = ([] if image_info is None else [image_info]) + [info for _, info in photos]
    if image_settings is not None:
        print(f"--image is one more shot: f/{args.image_f_number:g}, focused at "
              f"{float(image_settings.focus_distance[0]):g} m")
    if "shifts" in out:
        _report_working_resolution(out, depth_range, infos, method)
    depth = out["depth"].cpu()
    confidence = None if out["confidence"] is None else out["confidence"].cpu()
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
    fused = out["all_in_focus"].cpu()
    save_photo(args.out / "all_in_focus.png", fused)
    written.append("all_in_focus.png")
    plot_prediction(args.out / "figure.png", fused, depth, focused if photos else None,
                    title=str(first_path.name), depth_range=tuple(out["depth_range"]),
                    confidence=confidence, image_label="all in focus (input)" if image is not None
                    else "all in focus (fused)")
    print(f"depth {float(depth.min()):.2f}-{float(depth.max()):.2f} m; wrote "
          f"{', '.join(written)} and figure.png under {args.out}")
    return 0


def _report_working_resolution(out, depth_range, infos, method) -> None:
    import warnings

    from datasets.photos import compression_warning

    near, far = depth_range
    moved = ", ".join(f"({dy:+.1f}, {dx:+.1f}, x{zoom:.4f}, {turn:+.2f} deg)"
                      for (dy, dx), zoom, turn in zip(out["shifts"].tolist(), out["zooms"].tolist(),
                                                      out["rotations"].tolist(), strict=True))
    swept = out["depth_range"]
    if tuple(swept) != (near, far):
        print(f"the scene lies within {swept[0]:.2f}-{swept[1]:.2f} m of the stated "
              f"{near:g}-{far:g} m: depth computed again over that range, at a finer resolution")
    onto = "the all-in-focus photo" if method == "sweep" else "the first"
    print(f"method {method}; working resolution {out['scale']:.3f} x the photos; focused photos "
          f"aligned onto {onto}: moved by {moved} (pixels down, right; magnification; "
          "rotation, clockwise)")
    jpeg = compression_warning(infos, out["scale"])
    if jpeg is not None:
        warnings.warn(jpeg, stacklevel=1)
