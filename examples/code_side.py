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

``--sweep`` also finds each scene's depth without labels or a network: the label-free sweep
(`models.depth_from_photos.SweepDepth`, through the aperture, the signed blur for a code) from
the f/8 photo and the focused image with the training runs' sensor noise (read 0.004, shot
0.0004), scored against the true depth within 10 m (abs rel, and order: the rank
correlation). About 15 seconds a scene and aperture::

    python examples/code_side.py --root data/dfd_indoor --sweep

With two focus planes (``--focus-fraction 0.2 0.8``, the paper's) every aperture tells the
sides apart, and only the sweep is scored: what a code adds to a focus pair.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from datasets import DSLR
from models.checkpoints import load_checkpoint
from models.depth_from_photos import SweepDepth
from models.diagnostics import side_told
from models.metrics import depth_metrics, depth_order
from models.training import TrainConfig
from models.training.learned_camera import checkpoint_aperture
from optics import Aperture, Disk, Mask, add_noise, disk_mask, render_focal_stack
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


#: The depth range the label-free sweep searches, metres (the DSLR example's).
SWEPT = (0.5, 10.0)
#: Its photos carry the sensor noise of the training runs (`read_noise`, `shot_noise`).
TRAINING = TrainConfig()


def share_told(scenes: DSLR, aperture: Aperture, progress: bool, sweep: bool = False
               ) -> tuple[float, int, dict[str, float]]:
    """`side_told` over `scenes` (their own camera; one focus plane, else nothing counted),
    weighted by counted pixels, and with `sweep` the label-free sweep's mean abs rel and
    order over the scenes."""
    right = counted = 0.0
    scores: list[tuple[float, float]] = []
    for index in progress_bar(range(len(scenes)), desc="scenes", disable=not progress):
        sample = scenes.load(index)  # the f/8 photo, its depth and camera, nothing rendered
        settings = sample["camera"].to(dtype=torch.float64)
        image, depth = sample["image"][None].double(), sample["depth"][None].double()
        stack = render_focal_stack(image, depth, settings, aperture=aperture)
        if settings.n_shots == 1:
            coc = settings.shot(0, aperture).signed_coc_px(depth)
            share, count = side_told(image, stack[:, 0], aperture, coc, sample["mask"])
            if count:  # else share is NaN
                right, counted = right + share * count, counted + count
        if sweep:
            noisy = add_noise(stack, TRAINING.read_noise, TRAINING.shot_noise,
                              generator=torch.Generator().manual_seed(index)).clamp(0, 1)
            found = SweepDepth(aperture)(image, noisy, settings, *SWEPT)["depth"]
            truth = {"target": depth, "mask": sample["mask"][None], "max_depth": SWEPT[1]}
            scores.append((depth_metrics(pred=found, **truth)["abs_rel"],
                           depth_order(pred=found, **truth)))
    means = {"abs rel": sum(a for a, _ in scores) / len(scores),
             "order": sum(o for _, o in scores) / len(scores)} if scores else {}
    return right / max(counted, 1), int(counted), means


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, required=True, help="the release's dfd_indoor folder")
    parser.add_argument("--split", default="train", help="the release's split (default: train)")
    parser.add_argument("--val", type=int, default=20,
                        help="score the last this many scenes of --split (default: 20)")
    parser.add_argument("--focus-fraction", type=float, nargs="+", default=[0.2],
                        help="the focus plane, a fraction of the 10 m depth cap (default: "
                             "0.2); two: a focus pair (then only --sweep is scored)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random code")
    parser.add_argument("--checkpoint", type=Path, action="append", default=[],
                        help="also score the mask this checkpoint learned (repeatable)")
    parser.add_argument("--sweep", action="store_true",
                        help="also score the label-free sweep's depth through each aperture")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    try:
        count = len(DSLR(args.root, args.split).files)
        if not 0 < args.val <= count:
            raise ValueError(f"--val must be in 1..{count} (the split's scenes), got {args.val}")
        if len(args.focus_fraction) > 1 and not args.sweep:
            raise ValueError("with two or more --focus-fraction every aperture tells the "
                             "sides apart: give --sweep to score the label-free sweep")
        scenes = DSLR(args.root, args.split, scenes=range(count - args.val, count),
                      focus="synthesized", focus_fractions=args.focus_fraction)
        found = apertures(args.seed, args.checkpoint)
    except (ValueError, FileNotFoundError) as error:
        raise SystemExit(f"code_side: {error}") from None
    focus = scenes.load(0)["camera"].focus_distance.reshape(-1).tolist()  # nothing rendered
    planes = " and ".join(f"{d:g}" for d in focus)
    print(f"focused at {planes} m, {len(scenes)} scenes of {args.split}" + (
        ": the share of the pixels blurred over 1 px whose side the blur tells (0.5: chance)"
        if len(focus) == 1 else ""))
    for name, aperture in found.items():
        share, counted, sweep = share_told(scenes, aperture, not args.quiet, args.sweep)
        told = [f"{share:.3f} of {counted} pixels"] if counted else []
        print(f"  {name}: " + ", ".join(told + [f"label-free sweep {key} {value:.3f}"
                                                for key, value in sweep.items()]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
