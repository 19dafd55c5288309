"""Does an aperture tell near from far with one focus plane? Measured on the DSLR set's scenes.

One focus distance blurs a depth and its mirror across the focus plane by circles of the same
size; through a point-symmetric aperture (the disk, a Gaussian) they blur alike, and through a
code without point symmetry they do not: a thin lens images the aperture turned by 180 degrees
on one side of the plane (`optics.Aperture.oriented`). For each scored scene (the f/8 photo and
its depth, the last ``--val`` scenes of ``--split``) the focused image is rendered at one focus
plane (``--focus-fraction`` of the 10 m depth cap) through each aperture, and
`models.diagnostics.side_told` asks, pixel by pixel, whether the blur at the true
side matches better than at the mirrored one, given the blur's size: 0.5 is chance (a tie
counts half), 1 tells every pixel.

Apertures: the open disk, a seeded random code in the disk (``--seed``), and the mask learned
by each ``--checkpoint`` (a `defocus train --learn-optics mask` or example run). CPU, about a
minute for the 20 scenes and two apertures::

    python examples/code_side.py --root data/dfd_indoor
    python examples/code_side.py --root data/dfd_indoor --checkpoint runs/code/depth/checkpoints/last.pt
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from datasets import DSLR
from models.checkpoints import load_checkpoint
from models.diagnostics import side_told
from models.training.learned_camera import checkpoint_aperture
from optics import Aperture, Disk, Mask, disk_mask, render_focal_stack
from optics.progress import progress_bar


def apertures(seed: int, checkpoints: list[Path]) -> dict[str, Aperture]:
    """The disk, a random code in it (`seed`) and each checkpoint's learned mask, by name."""
    code = torch.rand(16, 16, generator=torch.Generator().manual_seed(seed),
                      dtype=torch.float64) * disk_mask(16)
    found: dict[str, Aperture] = {"open disk": Disk(), f"random code (seed {seed})": Mask(code)}
    for path in checkpoints:
        learned = checkpoint_aperture(load_checkpoint(path, mmap=True))
        if learned is None:
            raise SystemExit(f"--checkpoint {path}: it learned no aperture mask")
        found[f"learned mask of {path}"] = learned
    return found


def share_told(scenes: DSLR, aperture: Aperture, progress: bool) -> tuple[float, int]:
    """`side_told` over `scenes` (their own one-plane camera), weighted by counted pixels."""
    right = counted = 0.0
    for index in progress_bar(range(len(scenes)), desc="scenes", disable=not progress):
        sample = scenes.load(index)  # the f/8 photo, its depth and camera, nothing rendered
        settings = sample["camera"].to(dtype=torch.float64)
        image, depth = sample["image"][None].double(), sample["depth"][None].double()
        focused = render_focal_stack(image, depth, settings, aperture=aperture)[:, 0]
        coc = settings.shot(0, aperture).signed_coc_px(depth)
        share, count = side_told(image, focused, aperture, coc, sample["mask"])
        if count:
            right, counted = right + share * count, counted + count
    return right / max(counted, 1), int(counted)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, required=True, help="the release's dfd_indoor folder")
    parser.add_argument("--split", default="train", help="the release's split (default: train)")
    parser.add_argument("--val", type=int, default=20,
                        help="score the last this many scenes of --split (default: 20)")
    parser.add_argument("--focus-fraction", type=float, default=0.2,
                        help="the focus plane, a fraction of the 10 m depth cap (default: 0.2)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random code")
    parser.add_argument("--checkpoint", type=Path, action="append", default=[],
                        help="also score the mask this checkpoint learned (repeatable)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    try:
        count = len(DSLR(args.root, args.split).files)
        if not 0 < args.val <= count:
            raise ValueError(f"--val must be in 1..{count} (the split's scenes), got {args.val}")
        scenes = DSLR(args.root, args.split, scenes=range(count - args.val, count),
                      focus="synthesized", focus_fractions=[args.focus_fraction])
        found = apertures(args.seed, args.checkpoint)
    except (ValueError, FileNotFoundError) as error:
        raise SystemExit(f"code_side: {error}") from None
    focus = float(scenes.load(0)["camera"].focus_distance.reshape(-1)[0])  # nothing rendered
    print(f"one focus plane at {focus:g} m, {len(scenes)} scenes of {args.split}: the share of "
          "the pixels blurred over 1 px whose side the blur tells (0.5: chance)")
    for name, aperture in found.items():
        share, counted = share_told(scenes, aperture, not args.quiet)
        print(f"  {name}: {share:.3f} of {counted} pixels")
    return 0


if __name__ == "__main__":
    sys.exit(main())
