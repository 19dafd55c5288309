"""`defocus predict`: depth of your own photos with a trained checkpoint."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=Path, help="checkpoint file (.pt) written by training")
    parser.add_argument("--image", type=Path, required=True,
                        help="all-in-focus photo (sRGB PNG/JPEG; small aperture, e.g. f/8)")
    parser.add_argument("--focused", type=Path, nargs="*", default=[],
                        help="focused photos of the same view (needed by 'aif+focused' networks)")
    parser.add_argument("--focus-distance", type=float, nargs="*", default=[],
                        help="focus distance of each focused photo, metres")
    parser.add_argument("--f-number", type=float, nargs="*", default=[],
                        help="f-number of each focused photo (one value is repeated)")
    parser.add_argument("--focal-length", type=float, default=None,
                        help="focal length, metres (e.g. 0.05 for 50 mm)")
    parser.add_argument("--pixel-pitch", type=float, default=None,
                        help="effective pixel pitch of the photos as given, metres (sensor pitch "
                             "times the downscaling from sensor to photo)")
    parser.add_argument("--out", type=Path, default=Path("runs/predict"),
                        help="output folder: depth.npy (metres) and depth.png")


def run(args: argparse.Namespace) -> int:
    import numpy as np
    import torch

    from datasets.io import read_rgb
    from defocus.cli import CommandError
    from models.plotting import plot_prediction
    from models.training import Trainer
    from optics import CameraSettings

    trainer = Trainer.from_checkpoint(args.checkpoint)
    image = read_rgb(args.image)[None]
    focused = settings = None
    if trainer.config.input_mode == "aif+focused":
        n = len(args.focused)
        if n != trainer.config.n_focus:
            raise CommandError(f"this network needs {trainer.config.n_focus} --focused photos, "
                             f"got {n}")
        if len(args.focus_distance) != n or len(args.f_number) not in (1, n) \
                or args.focal_length is None or args.pixel_pitch is None:
            raise CommandError("give --focus-distance (one per focused photo), --f-number, "
                             "--focal-length and --pixel-pitch")
        focused = torch.stack([read_rgb(p) for p in args.focused])[None]
        f_numbers = args.f_number * n if len(args.f_number) == 1 else args.f_number
        settings = CameraSettings(args.focal_length, f_numbers, args.focus_distance,
                                  args.pixel_pitch).to(torch.float32)
    depth = trainer.predict(image, focused, settings)[0].cpu()
    args.out.mkdir(parents=True, exist_ok=True)
    np.save(args.out / "depth.npy", depth[0].numpy())
    plot_prediction(args.out / "depth.png", image[0], depth,
                    None if focused is None else focused[0], title=str(args.image.name),
                    depth_range=(trainer.config.depth_min, trainer.config.depth_max))
    print(f"depth {float(depth.min()):.2f}-{float(depth.max()):.2f} m; wrote "
          f"{args.out / 'depth.npy'} and {args.out / 'depth.png'}")
    return 0
