"""The paper's protocol on real defocus: the DSLR set (DFD-indoor) of Carvalho et al. 2018.

Data: "Deep Depth from Defocus: how can defocus blur improve 3D estimation using dense neural
networks?" (3DRW ECCV Workshop 2018), the indoor set of its public release (repository
marcelampc/d3net_depth_estimation, folder `dfd_datasets/dfd_indoor`), read as released by
`datasets.DSLR`: each scene at f/8 (the nearly sharp `image`) and f/2.8 (the real focused
photo), 645x432 JPEGs, with registered depth. Give ``--root`` the `dfd_indoor` folder.

What it does, on the split's scenes in time order (the last ``--val`` are the validation set,
never used to fit or train; with ``--eval-split test`` every scene of ``--split`` trains and the
other split is scored, the paper's protocol):

1. calibrates the camera on the training scenes (``defocus calibrate --dataset dslr``: the
   blur measured by depth, the thin lens with a floor, the exposure gain; skipped with
   ``--camera JSON``), then scales its blur to the one the training loss agrees with at the
   true depth of those scenes (`models.diagnostics.match_blur_scale`, ``camera_loss.json``;
   off with ``--no-blur-match``): the calibration fits the blur by its squared error, the
   paper's loss (SSIM, L1, sharpness) prefers about 1.2x that blur on this set;
2. trains three networks on the same scenes with the same budget: the self-supervised one (the
   f/8 photo rendered through the PSF layer at the predicted depth must reproduce the real f/2.8
   photo; no depth in the loss), its depth-supervised twin, and the paper's own setting (the
   network sees the f/8 photo alone, ``--input-mode aif``, trained through the PSF layer). The
   render models the pair as calibrated (`DSLR(relative=True)`): the f/2.8 photo registered onto
   the f/8 one (`datasets.pairs.register_focused`), the f/8 photo's own blur, the floor and the
   exposure gain;
3. one focus plane cannot tell near from far: the self-supervised networks put a blur that both
   sides explain on the side ``--side`` states (default ``beyond``: a prior, chosen on the
   training scenes, 22 % of whose pixels are nearer than the focus plane), and a blur above the
   far side's bound near (`models.networks.DepthHead`);
4. scores them on the held-out scenes beside the label-free `predict` (no training: the f/8
   photo as one more shot, `estimate_depth(image_settings=...)`, with the fitted camera) and the
   best constant depth of the training scenes, prints the table (``--json PATH`` writes it). A
   row marked ``bound:`` scores the true depth with its ambiguous blur put on ``--side``
   (`models.diagnostics.fold_to_side`): what a self-supervised network that found the loss's
   best everywhere would score under that prior. No training can do better on those scenes.

CPU (default: 2.5 minutes per network, about 10 minutes on 2 cores)::

    python examples/dslr.py --root data/dfd_indoor

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
from defocus.app.experiment import limit, loss_window, plan_json_option, training_crop
from defocus.app.outputs import write_json
from defocus.options import DEVICE_DEFAULTS, add_json_argument, device_kind, example_parser
from optics import DEFAULT_APERTURE

#: The scenes' depth lies within this range, metres (the release's depth: about 0.4 to 10 m).
DEPTH_RANGE = (0.5, 10.0)


def side_bound_row(val: DSLR, depth_range: tuple[float, float],
                   side: str) -> dict[str, dict[str, float]]:
    """The error that no self-supervised training removes under the side prior: each scored
    scene's true depth with its ambiguous blur put on `side` (`fold_to_side`), averaged."""
    from models.diagnostics import fold_to_side
    from models.evaluation import MeanMetrics
    from models.metrics import depth_metrics

    means = MeanMetrics()
    for index in range(len(val)):
        sample = val[index]
        focus = float(sample["camera"].focus_distance.reshape(-1)[0])
        folded = fold_to_side(sample["depth"], focus, depth_range, side)
        means.add(depth_metrics(pred=folded[None], target=sample["depth"][None],
                                mask=sample["mask"][None], max_depth=depth_range[1]))
    return {f"bound: the true depth through one focus plane, side {side}": means.mean()}


def label_free_rows(val: DSLR, depth_range: tuple[float, float], max_pixels: int,
                    side: str = "both", report=None) -> dict[str, dict[str, float]]:
    """`estimate_depth` on each scored scene (the f/8 photo as one more shot), averaged; with a
    side prior, over the depth range on that side of the fitted focus plane only."""
    from models.depth_from_photos import estimate_depth
    from models.evaluation import MeanMetrics
    from models.metrics import depth_metrics
    from optics.progress import progress_bar

    means = MeanMetrics()
    for index in progress_bar(range(len(val)), desc="label-free predict"):
        sample = val[index]
        settings = sample["camera"]
        reference = val.reference_settings(settings)
        focus = float(settings.focus_distance.reshape(-1)[0])
        span = {"beyond": (focus, depth_range[1]), "before": (depth_range[0], focus)}.get(
            side, depth_range)
        with torch.no_grad():
            depth = estimate_depth(sample["focused"], settings, span,
                                   image=sample["image"], image_settings=reference,
                                   all_in_focus=False, max_pixels=max_pixels,
                                   refine_range=side == "both")["depth"]
        means.add(depth_metrics(pred=depth, target=sample["depth"], mask=sample["mask"],
                                max_depth=depth_range[1]))
    prior = "" if side == "both" else f", side {side}"
    return {f"label-free predict (f/8 as a shot, fitted camera{prior})": means.mean()}


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


def match_loss_camera(args: argparse.Namespace, camera: Path, pair: dict[str, Any],
                      scenes: range) -> Path:
    """The camera JSON whose blur the training loss agrees with: its effective pixel pitch
    divided by the CoC scale at which the loss scores the true depth best on the calibration
    scenes (`models.diagnostics.write_blur_matched_camera`)."""
    from models.diagnostics import write_blur_matched_camera
    from models.losses import DefocusLoss

    every = scenes[::args.calibrate_every]
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "camera_loss.json"
    scale = write_blur_matched_camera(DSLR(args.root, args.split, scenes=every, **pair), camera,
                                      path, DefocusLoss())
    print(f"the loss prefers {scale:g}x the fitted blur on {len(every)} training scenes: the "
          f"networks train with {path}")
    return path


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = example_parser(__doc__.splitlines()[0], "runs/dslr")
    parser.add_argument("--split", default="train", help="the release's split to train on")
    parser.add_argument("--eval-split", default=None, metavar="SPLIT",
                        help="train on every scene of --split and score on this split of the "
                             "same release (the paper's protocol: --eval-split test); default: "
                             "score on the last --val scenes of --split")
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
                             "(default: the relative blur from it, with the fitted floor and "
                             "exposure gain)")
    parser.add_argument("--no-register", action="store_true",
                        help="train on the photos as loaded (default: the f/2.8 photo "
                             "registered onto the f/8 one)")
    parser.add_argument("--no-blur-match", action="store_true",
                        help="train with the fitted camera as it is (default: its blur scaled "
                             "to what the training loss prefers at the true depth of the "
                             "calibration scenes, models.diagnostics.match_blur_scale)")
    parser.add_argument("--no-paper-setting", action="store_true",
                        help="skip the network that sees the f/8 photo alone (--input-mode aif)")
    parser.add_argument("--predict-pixels", type=int, default=300_000,
                        help="working pixels of the label-free predict")
    parser.add_argument("--predict-side", choices=["both", "beyond", "before"], default="both",
                        help="the side prior of the label-free predict (on the training scenes "
                             "its depth range beyond the focus plane scored worse than the "
                             "whole range: abs rel 0.51 vs 0.47)")
    add_json_argument(parser, "write the table (method name -> metrics) to this JSON file")
    # the blur of this pair is linear in inverse depth and ambiguous about the focus plane: an
    # output even in depth starts far out, where the blur no longer changes (abs rel 2.3 vs 0.63)
    # a prior chosen on the training scenes: 22 % of their pixels are nearer than the fitted
    # focus plane; the true depth folded beyond it scores abs rel 0.23, folded before it 0.45
    parser.set_defaults(depth_spacing="inverse", side="beyond")
    args = parser.parse_args(argv)
    if args.minutes is None and args.steps is None and device_kind(args.device) == "cpu":
        args.minutes = 2.5  # each of the three networks: about 10 minutes in all on 2 cores
    if args.threads:
        torch.set_num_threads(args.threads)
    return args


def datasets(args: argparse.Namespace) -> tuple[DSLR, DSLR, DSLR, Path]:
    """The training and scored scenes (relative pairs), the scored scenes with the lens's own
    camera (for `predict`), and the camera JSON (fitted on the training scenes)."""
    count = len(DSLR(args.root, args.split).files)
    if args.max_scenes is not None:
        count = min(count, args.max_scenes)
    kwargs: dict[str, Any] = {"size": None if args.size is None else tuple(args.size),
                              "memory_cache_mb": args.memory_cache_mb}
    if args.eval_split is None:
        if not 0 < args.val < count:
            raise SystemExit(f"--val must leave training scenes: 0 < --val < {count}, got "
                             f"{args.val}")
        fit_on, scored = range(0, count - args.val), (args.split, range(count - args.val, count))
    else:
        fit_on, scored = range(0, count), (args.eval_split, None)
    train = DSLR(args.root, args.split, scenes=fit_on, **kwargs)
    camera = args.camera or calibrate(args, train)
    pair = {"camera": camera, "relative": not args.no_relative,
            "register": False if args.no_register else None, **kwargs}
    if not args.no_blur_match:
        pair["camera"] = match_loss_camera(args, camera, pair, fit_on)
    train = DSLR(args.root, args.split, scenes=fit_on, **pair)
    val = DSLR(args.root, scored[0], scenes=scored[1], **pair)
    lens = DSLR(args.root, scored[0], scenes=scored[1], camera=camera, **kwargs)
    return train, val, lens, camera


#: the networks of the table: (label, supervision, input mode, whether the side prior applies)
NETWORKS = (("self-supervised", "self", "aif+focused", True),
            ("depth-supervised", "depth", "aif+focused", False),
            ("self-supervised, f/8 photo alone (the paper's setting)", "self", "aif", True))


def train_and_evaluate(name: str, args: argparse.Namespace, train_set, test_set,
                       depth_range: tuple[float, float], constant_set) -> dict:
    """Train the network of `args` (`TrainConfig.load`) within its budget and score it on
    whole `test_set` images (`models.experiment.train_and_evaluate`)."""
    from models.experiment import train_and_evaluate as run
    from models.metrics import format_table
    from models.training import TrainConfig

    kind = device_kind(args.device)
    train_set, test_set = limit(train_set, args.max_train), limit(test_set, args.max_test)
    first = train_set[0]
    focus = float(first["camera"].focus_distance.reshape(-1)[0]) if args.side != "both" else 0.0
    config = TrainConfig.load(None, [], **{
        "steps": args.steps or DEVICE_DEFAULTS[kind]["steps"] or 10 ** 9,
        "minutes": args.minutes or 0.0, "batch_size": args.batch_size, "lr": args.lr,
        "network": args.network, "input_mode": args.input_mode, "out_dir": args.out,
        "seed": args.seed, "supervision": args.supervision, "depth_spacing": args.depth_spacing,
        "side": args.side, "focus_distance": focus, "depth_min": depth_range[0],
        "depth_max": depth_range[1], "device": kind if args.device == "auto" else args.device,
        "width": args.width, "progress": not args.no_progress, "workers": args.workers,
        "max_kernel_size": loss_window(first["image"].shape[-2:]), "precision": args.precision,
        "compile": args.compile, "smoothness_weight": args.smoothness_weight})
    print(f"{name}: {len(train_set)} training samples and {len(test_set)} whole test samples; "
          f"device {kind}")
    rows = run(config, train_set, test_set, constant_set=limit(constant_set, args.max_train),
               report_every=None if config.progress else 0, report=print)
    print(format_table(rows))
    return rows


def network_rows(args: argparse.Namespace, train: DSLR, val: DSLR,
                 depth_range: tuple[float, float]) -> dict[str, dict[str, float]]:
    """Train each network of `NETWORKS` on `train` and score it on `val`."""
    from optics.progress import progress_bar

    if train.register and args.memory_cache_mb > 0:  # register each pair once, before timing
        for index in progress_bar(range(len(train)), desc="registering the training pairs",
                                  disable=args.no_progress):
            train[index]
    crop = training_crop(args.crop or [DEVICE_DEFAULTS[device_kind(args.device)]["crop"]], train,
                         print)
    augmented = train.with_augment(JointAugment(crop_size=crop, hflip=0.5, gain=0.1))
    rows: dict[str, dict[str, float]] = {}
    out, side, mode = args.out, args.side, args.input_mode
    for label, supervision, input_mode, sided in NETWORKS:
        if input_mode == "aif" and args.no_paper_setting:
            continue
        folder = supervision if input_mode == mode else f"{supervision}-{input_mode}"
        args.supervision, args.out, args.input_mode = supervision, out / folder, input_mode
        args.side = side if sided else "both"
        found = train_and_evaluate(f"DSLR ({label})", args, augmented, val, depth_range, train)
        prior = f", side {side}" if sided and side != "both" else ""
        for name, row in found.items():
            rows[name if name.startswith("best constant") else f"{name} [{label}{prior}]"] = row
    args.out, args.side, args.input_mode = out, side, mode
    return rows


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    # --json is checked before any work: not the camera JSON, not a file of --root, no earlier
    # table replaced without --overwrite
    plan = plan_json_option(args, "table", [
        ("--camera", args.camera), ("camera JSON of this run", args.out / "camera.json"),
        ("loss-matched camera JSON of this run", args.out / "camera_loss.json")])
    train, val, lens, camera = datasets(args)
    scored = "validation" if args.eval_split is None else f"{args.eval_split} split"
    print(f"DSLR: {len(train)} training scenes, {len(val)} {scored} scenes "
          f"({val.ids[0]} to {val.ids[-1]}), camera {json.loads(Path(camera).read_text())}")
    depth_range = DEPTH_RANGE if args.depth_range is None else tuple(args.depth_range)
    rows = network_rows(args, train, val, depth_range)
    if args.side != "both":
        rows.update(side_bound_row(val, depth_range, args.side))
    rows.update(label_free_rows(lens, depth_range, args.predict_pixels, args.predict_side))
    from models.metrics import METRIC_NAMES, format_table

    constant = next(row for name, row in rows.items() if name.startswith("best constant"))
    print(f"\nDSLR {scored} ({len(val)} scenes, never used to fit or train; order: the rank "
          "correlation of a network's depth with the true depth, mean over the scenes):")
    print(format_table(rows, metrics=(*METRIC_NAMES, "depth_order")))
    for name, row in rows.items():
        print(f"  {name}: abs rel {row['abs_rel'] / constant['abs_rel']:.2f}x the constant's")
    if plan is not None:
        write_json(plan, args.json, rows)
        print(f"table -> {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
