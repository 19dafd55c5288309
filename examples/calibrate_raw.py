"""Calibrate a camera from raw photo pairs, end to end.

With your own photos (see docs/tutorials/calibration.md for how to shoot them):

    python examples/calibrate_raw.py --pair sharp1.dng blurred1.dng 1.2 --pair ... --out fit.json

Without arguments it first writes synthetic Bayer DNG pairs of a textured plane (a 25 mm lens at
f/4 focused at 2 m, 5 um pixels, shot and read noise) into the output folder, then calibrates
from them, so the whole pipeline runs offline. It needs pidng (the ``test`` extra).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def synthetic_pairs(folder: Path, size: int = 96) -> list[list[str]]:
    sys.path.insert(0, str(ROOT / "tests"))
    from _synthetic_dng import synthetic_camera, write_pairs

    from optics import Disk

    folder.mkdir(parents=True, exist_ok=True)
    files = write_pairs(folder, synthetic_camera(Disk()), (1.2, 1.5, 4.0), size=size)
    return [[str(s), str(b), str(d)] for s, b, d in files]


def main(argv: list[str] | None = None) -> int:
    from defocus.cli import main as defocus

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pair", nargs=3, action="append", metavar=("SHARP", "BLURRED", "M"))
    parser.add_argument("--out", type=Path, default=Path("runs/calibrate/fit.json"))
    args, rest = parser.parse_known_args(argv)
    pairs = args.pair or synthetic_pairs(args.out.parent / "dng")
    command = ["calibrate", "--out", str(args.out)]
    for sharp, blurred, distance in pairs:
        command += ["--pair", sharp, blurred, distance]
    if not args.pair:
        command += ["--fit", "f_number"]  # the synthetic files state f/4: fit it anyway
    return defocus(command + rest)


if __name__ == "__main__":
    sys.exit(main())
