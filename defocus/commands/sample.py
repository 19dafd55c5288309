"""`defocus sample`: write a small set of photos to try the other commands on
(`defocus.app.sample.write_sample_set`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from defocus.options import add_overwrite_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    # a string, not a Path: Path("") is the current folder, and an empty FOLDER is refused
    parser.add_argument("folder", type=str, nargs="?", default=Path("samples"), metavar="FOLDER",
                        help="where to write the photos (default: samples)")
    parser.add_argument("--scale", type=float, default=0.35,
                        help="size of the photos as a fraction of the scene's 741x500 pixels, "
                             "in (0, 1]; at least 0.0392 (29x19 pixels), the smallest that "
                             "`defocus predict` reads depth from")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the photos' noise (an integer >= 0)")
    add_overwrite_argument(parser)


def run(args: argparse.Namespace) -> int:
    from defocus.app.sample import SAMPLE_DEPTH_RANGE, write_sample_set

    sample = write_sample_set(args.folder, args.scale, args.seed, args.overwrite)
    near, far = SAMPLE_DEPTH_RANGE
    print(f"wrote {', '.join(path.name for path in sample.files)} under {sample.folder}")
    print(f"try: defocus predict --image {sample.folder / 'aif.png'} --focused "
          f"{sample.folder / 'near.png'} {sample.folder / 'far.png'} --camera "
          f"{sample.folder / 'camera.json'} --depth-range {near:g} {far:g} --out "
          f"{sample.folder / 'predict'} --overwrite")
    return 0
