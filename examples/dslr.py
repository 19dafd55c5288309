"""The paper's protocol on real defocus: the DSLR set (DFD-indoor) of Carvalho et al. 2018.

Data: "Deep Depth from Defocus: how can defocus blur improve 3D estimation using dense neural
networks?" (3DRW ECCV Workshop 2018), the indoor set of its public release (repository
marcelampc/d3net_depth_estimation, folder `dfd_datasets/dfd_indoor`), read as released by
`datasets.DSLR`: each scene at f/8 (the nearly sharp `image`) and f/2.8 (the real focused
photo), 645x432 JPEGs, with registered depth. Give ``--root`` the `dfd_indoor` folder.

What it does, on the split's scenes in time order (the last ``--val`` are the validation set,
never used to fit or train):

1. calibrates the camera on the training scenes (``defocus calibrate --dataset dslr``: the
   blur measured by depth, the thin lens with a floor; skipped with ``--camera JSON``);
2. trains the self-supervised network (the f/8 photo rendered through the PSF layer at the
   predicted depth must reproduce the real f/2.8 photo; no depth in the loss) and its
   depth-supervised twin on the same scenes with the same budget; the render models the pair
   as calibrated (`DSLR(relative=True)`: the f/8 photo's own blur and the floor);
3. scores both on the validation scenes beside the label-free `predict` (no training: the f/8
   photo as one more shot, `estimate_depth(image_settings=...)`, with the fitted camera) and the
   best constant depth of the training scenes, and prints the table.

CPU (default; about 10 minutes on 2 cores)::

    python examples/dslr.py --root ../shared/data/real/dfd_indoor

GPU, the paper's protocol (Gur & Wolf 2019: ResNet-50 + dense ASPP + attention network, Adam lr
2e-5, Gaussian PSF sigma = CoC/2, real f/2.8 and f/8 photos; 256x256 crops, batch 8)::

    python examples/dslr.py --root data/dfd_indoor --device cuda --network paper --lr 2e-5 \\
        --steps 20000 --crop 256 --batch-size 8
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import torch

from datasets import DSLR, JointAugment
from defocus.app.experiment import train_and_evaluate, training_crop
from defocus.options import device_kind, example_parser
from optics import DEFAULT_APERTURE

#: The scenes' depth lies within this range, metres (the release's depth: about 0.4 to 10 m).
DEPTH_RANGE = (0.5, 10.0)


def label_free_rows(val: DSLR, depth_range: tuple[float, float],
                    max_pixels: int) -> dict[str, dict[str, float]]:
    """`estimate_depth` on each validation scene (the f/8 photo as one more shot), averaged."""
    from models.depth_from_photos import estimate_depth
    from models.metrics import depth_metrics
    from optics.progress import progress_bar

    totals: dict[str, float] = {}
    for index in progress_bar(range(len(val)), desc="label-free predict"):
        sample = val[index]
        settings = sample["camera"]
        reference = val.reference_settings(settings)
        with torch.no_grad():
            depth = estimate_depth(sample["focused"], settings, depth_range,
                                   image=sample["image"], image_settings=reference,
                                   all_in_focus=False, max_pixels=max_pixels)["depth"]
        values = depth_metrics(pred=depth, target=sample["depth"], mask=sample["mask"],
                               max_depth=depth_range[1])
        for key, value in values.items():
            totals[key] = totals.get(key, 0.0) + value / len(val)
    return {"label-free predict (f/8 as a shot, fitted camera)": totals}


def calibrate(args: argparse.Namespace, train: DSLR) -> Path:
    from datasets.calibration import calibrate_dataset
    from optics import plot_depth_calibration

    every = list(range(0, len(train), args.calibrate_every))
    fit = calibrate_dataset(train, every, aperture=DEFAULT_APERTURE, progress=not args.no_progress)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "camera.json"
    fit.to_json(path)
    plot_depth_calibration(fit, path.with_suffix(".png"))
    print(f"camera fitted on {len(every)} training scenes: focus {fit.fit.focus_distance:.2f} m, "
          f"pitch {float(fit.settings.pixel_pitch[0]) * 1e6:.1f} um, floor {fit.floor_px:.2f} px "
          f"-> {path}")
    return path


def main(argv: list[str] | None = None) -> int:
    parser = example_parser(__doc__.splitlines()[0], "runs/dslr")
    parser.add_argument("--split", default="train", help="the release's split to use")
    parser.add_argument("--val", type=int, default=20,
                        help="the last this many scenes (by time) are the validation set")
    parser.add_argument("--max-scenes", type=int, default=None,
                        help="use only the first this many scenes of the split (a quick run)")
    parser.add_argument("--camera", type=Path, default=None, metavar="JSON",
                        help="a fitted camera JSON (default: calibrate on the training scenes)")
    parser.add_argument("--calibrate-every", type=int, default=3,
                        help="calibrate on every this many training scenes")
    parser.add_argument("--no-relative", action="store_true",
                        help="train with the lens's own camera and the f/8 photo taken as sharp "
                             "(default: the relative blur from it, with the fitted floor)")
    parser.add_argument("--predict-pixels", type=int, default=300_000,
                        help="working pixels of the label-free predict")
    # the blur of this pair is linear in inverse depth and ambiguous about the focus plane: an
    # output even in depth starts far out, where the blur no longer changes (abs rel 2.3 vs 0.63)
    parser.set_defaults(depth_spacing="inverse")
    args = parser.parse_args(argv)
    if args.minutes is None and args.steps is None and device_kind(args.device) == "cpu":
        args.minutes = 3.5  # each of the two networks: about 10 minutes in all on 2 cores
    if args.threads:
        torch.set_num_threads(args.threads)
    count = len(DSLR(args.root, args.split).files)
    if args.max_scenes is not None:
        count = min(count, args.max_scenes)
    if not 0 < args.val < count:
        raise SystemExit(f"--val must leave training scenes: 0 < --val < {count}, got {args.val}")
    kwargs: dict[str, Any] = {"size": None if args.size is None else tuple(args.size)}
    train = DSLR(args.root, args.split, scenes=range(0, count - args.val), **kwargs)
    camera = args.camera or calibrate(args, train)
    relative = not args.no_relative
    train = DSLR(args.root, args.split, scenes=range(0, count - args.val), camera=camera,
                 relative=relative, **kwargs)
    val = DSLR(args.root, args.split, scenes=range(count - args.val, count), camera=camera,
               relative=relative, **kwargs)
    lens = DSLR(args.root, args.split, scenes=range(count - args.val, count), camera=camera,
                **kwargs)
    print(f"DSLR: {len(train)} training scenes, {len(val)} validation scenes "
          f"({val.ids[0]} to {val.ids[-1]}), camera {json.loads(Path(camera).read_text())}")
    depth_range = DEPTH_RANGE if args.depth_range is None else tuple(args.depth_range)
    crop = training_crop(args, train, print)
    augmented = train.with_augment(JointAugment(crop_size=crop, hflip=0.5, gain=0.1))
    rows: dict[str, dict[str, float]] = {}
    out = args.out
    for supervision in ("self", "depth"):
        args.supervision, args.out = supervision, out / supervision
        found = train_and_evaluate(f"DSLR ({supervision}-supervised)", args, augmented, val,
                                   depth_range=depth_range, constant_set=train,
                                   report=print)
        for name, row in found.items():
            label = name if name.startswith("best constant") else \
                f"{name} [{'self-supervised' if supervision == 'self' else 'depth-supervised'}]"
            rows[label] = row
    args.out = out
    rows.update(label_free_rows(lens, depth_range, args.predict_pixels))
    from models.metrics import format_table

    constant = next(row for name, row in rows.items() if name.startswith("best constant"))
    print(f"\nDSLR validation ({len(val)} scenes, never used to fit or train):")
    print(format_table(rows))
    for name, row in rows.items():
        print(f"  {name}: abs rel {row['abs_rel'] / constant['abs_rel']:.2f}x the constant's")
    return 0


if __name__ == "__main__":
    sys.exit(main())
