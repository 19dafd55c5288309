"""The paper's protocol on real defocus: the DSLR set (DFD-indoor) of Carvalho et al. 2018.

Data: "Deep Depth from Defocus: how can defocus blur improve 3D estimation using dense neural
networks?" (3DRW ECCV Workshop 2018), the indoor set of its public release (repository
marcelampc/d3net_depth_estimation, folder `dfd_datasets/dfd_indoor`), read as released by
`datasets.DSLR`: each scene at f/8 (the nearly sharp `image`) and f/2.8 (the real focused
photo), 645x432 JPEGs, with registered depth. Give ``--root`` the `dfd_indoor` folder.

The recipe is ``examples/dslr.yaml``; ``--set KEY=VALUE`` changes any of its keys (the
protocol's: ``val``, ``eval_split``, ``camera``, ``calibrate_every``, ...) or of the
`TrainConfig` fields (the options of ``defocus train``).

What it does, on the split's scenes in time order (the last ``val`` are the validation set,
never used to fit or train; with ``--set eval_split=test`` every scene of ``--split`` trains and
the other split is scored, the paper's protocol):

1. calibrates the camera on the training scenes (``defocus calibrate --data dslr``: the
   blur measured by depth, the thin lens with a floor, the exposure gain; skipped with
   ``camera=JSON``), then scales its blur to the one the training loss agrees with at the
   true depth of those scenes (`models.diagnostics.match_blur_scale`, ``camera_loss.json``;
   off with ``blur_match=false``): the calibration fits the blur by its squared error, the
   paper's loss (SSIM, L1, sharpness) prefers about 1.2x that blur on this set;
2. trains three networks on the same scenes with the same budget: the self-supervised one (the
   f/8 photo rendered through the PSF layer at the predicted depth must reproduce the real f/2.8
   photo; no depth in the loss), its depth-supervised twin, and the paper's own setting (the
   network sees the f/8 photo alone, ``input_mode=aif``, trained through the PSF layer). The
   render models the pair as calibrated (`DSLR(relative=True)`): the f/2.8 photo registered onto
   the f/8 one (`datasets.pairs.register_focused`), the f/8 photo's own blur, the floor and the
   exposure gain;
3. one focus plane cannot tell near from far: the self-supervised networks put a blur that both
   sides explain on the side ``side`` states (default ``beyond``: a prior, chosen on the
   training scenes, 22 % of whose pixels are nearer than the focus plane), and a blur above the
   far side's bound near (`models.networks.DepthHead`);
4. scores them on the held-out scenes beside the label-free `predict` (no training: the f/8
   photo as one more shot, `estimate_depth(image_settings=...)`, with the fitted camera) and the
   best constant depth of the training scenes, prints the table (``json=PATH`` writes it). A
   row marked ``bound:`` scores the true depth with its ambiguous blur put on ``side``
   (`models.diagnostics.fold_to_side`): what a self-supervised network that found the loss's
   best everywhere would score under that prior. No training can do better on those scenes.

CPU (default: 2.5 minutes per network, about 10 minutes on 2 cores)::

    python examples/dslr.py --root data/dfd_indoor

GPU, the paper's protocol (Gur & Wolf 2019: ResNet-50 + dense ASPP + attention network, Adam lr
2e-5, Gaussian PSF sigma = CoC/2, real f/2.8 and f/8 photos; 256x256 crops, batch 8)::

    python examples/dslr.py --root data/dfd_indoor --set device=cuda network=paper lr=2e-5 \\
        steps=20000 crop=256 batch_size=8
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import torch

from datasets import DSLR, JointAugment
from defocus.app import request_from
from defocus.app.experiment import (
    RECIPE_KEYS,
    ScriptRequest,
    limit,
    plan_json_option,
    read_recipe,
    recipe_config,
    recipe_crop,
)
from defocus.app.outputs import write_json
from defocus.commands.train import recipe_parser
from defocus.errors import script_errors
from optics import DEFAULT_APERTURE

#: The recipe: the protocol's keys (with their defaults) beside `RECIPE_KEYS` and the
#: `TrainConfig` fields.
RECIPE = Path(__file__).with_suffix(".yaml")


def side_bound_row(val: DSLR, depth_range: tuple[float, float],
                   side: str) -> dict[str, dict[str, float]]:
    """The error that no self-supervised training removes under the side prior: each scored
    scene's true depth with its ambiguous blur put on `side` (`fold_to_side`), averaged."""
    from models import evaluate
    from models.diagnostics import fold_to_side

    def bound(sample: dict) -> torch.Tensor:
        focus = float(sample["camera"].focus_distance.reshape(-1)[0])
        return fold_to_side(sample["depth"], focus, depth_range, side)

    return {f"bound: the true depth through one focus plane, side {side}": evaluate(
        bound, (val[i] for i in range(len(val))), "eigen", max_depth=depth_range[1])}


def label_free_rows(val: DSLR, depth_range: tuple[float, float], max_pixels: int,
                    side: str = "both") -> dict[str, dict[str, float]]:
    """`estimate_depth` on each scored scene (the f/8 photo as one more shot), averaged; with a
    side prior, over the depth range on that side of the fitted focus plane only."""
    from models import evaluate
    from models.depth_from_photos import estimate_depth
    from optics.progress import progress_bar

    def label_free(sample: dict) -> torch.Tensor:
        settings = sample["camera"]
        focus = float(settings.focus_distance.reshape(-1)[0])
        span = {"beyond": (focus, depth_range[1]), "before": (depth_range[0], focus)}.get(
            side, depth_range)
        with torch.no_grad():
            return estimate_depth(sample["focused"], settings, span, image=sample["image"],
                                  image_settings=val.reference_settings(settings),
                                  all_in_focus=False, max_pixels=max_pixels,
                                  refine_range=side == "both")["depth"]

    samples = (val[i] for i in progress_bar(range(len(val)), desc="label-free predict"))
    prior = "" if side == "both" else f", side {side}"
    return {f"label-free predict (f/8 as a shot, fitted camera{prior})": evaluate(
        label_free, samples, "eigen", max_depth=depth_range[1])}


def calibrate(proto: dict[str, Any], out: Path, train: DSLR, progress: bool) -> Path:
    from datasets.calibration import calibrate_dataset
    from optics import plot_depth_calibration

    every = list(range(0, len(train), proto["calibrate_every"]))
    fit = calibrate_dataset(train, every, aperture=DEFAULT_APERTURE, progress=progress)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "camera.json"
    fit.to_json(path)
    plot_depth_calibration(fit, path.with_suffix(".png"))
    print(f"camera fitted on {len(every)} training scenes: focus {fit.fit.focus_distance:.2f} m, "
          f"pitch {float(fit.settings.pixel_pitch[0]) * 1e6:.1f} um, floor {fit.floor_px:.2f} px "
          f"-> {path}")
    return path


def match_loss_camera(args: ScriptRequest, proto: dict[str, Any], out: Path, camera: Path,
                      pair: dict[str, Any], scenes: range) -> Path:
    """The camera JSON whose blur the training loss agrees with: its effective pixel pitch
    divided by the CoC scale at which the loss scores the true depth best on the calibration
    scenes (`models.diagnostics.write_blur_matched_camera`)."""
    from models.diagnostics import write_blur_matched_camera
    from models.losses import DefocusLoss

    every = scenes[::proto["calibrate_every"]]
    out.mkdir(parents=True, exist_ok=True)
    path = out / "camera_loss.json"
    scale = write_blur_matched_camera(DSLR(args.root, args.split, scenes=every, **pair), camera,
                                      path, DefocusLoss())
    print(f"the loss prefers {scale:g}x the fitted blur on {len(every)} training scenes: the "
          f"networks train with {path}")
    return path


def datasets(args: ScriptRequest, proto: dict[str, Any], out: Path,
             progress: bool) -> tuple[DSLR, DSLR, DSLR, Path]:
    """The training and scored scenes (relative pairs), the scored scenes with the lens's own
    camera (for `predict`), and the camera JSON (fitted on the training scenes)."""
    count = len(DSLR(args.root, args.split).files)
    if proto["max_scenes"] is not None:
        count = min(count, proto["max_scenes"])
    size = args.size or proto["size"]
    kwargs: dict[str, Any] = {"size": None if size is None else tuple(size),
                              "memory_cache_mb": proto["memory_cache_mb"]}
    if proto["eval_split"] is None:
        if not 0 < proto["val"] < count:
            raise SystemExit(f"val must leave training scenes: 0 < val < {count}, got "
                             f"{proto['val']}")
        fit_on = range(0, count - proto["val"])
        scored = (args.split, range(count - proto["val"], count))
    else:
        fit_on, scored = range(0, count), (proto["eval_split"], None)
    train = DSLR(args.root, args.split, scenes=fit_on, **kwargs)
    camera = Path(proto["camera"]) if proto["camera"] else calibrate(proto, out, train, progress)
    pair = {"camera": camera, "relative": proto["relative"],
            "register": None if proto["register"] else False, **kwargs}
    if proto["blur_match"]:
        pair["camera"] = match_loss_camera(args, proto, out, camera, pair, fit_on)
    train = DSLR(args.root, args.split, scenes=fit_on, **pair)
    val = DSLR(args.root, scored[0], scenes=scored[1], **pair)
    lens = DSLR(args.root, scored[0], scenes=scored[1], camera=camera, **kwargs)
    return train, val, lens, camera


#: the networks of the table: (label, supervision, input mode, whether the side prior applies)
NETWORKS = (("self-supervised", "self", "aif+focused", True),
            ("depth-supervised", "depth", "aif+focused", False),
            ("self-supervised, f/8 photo alone (the paper's setting)", "self", "aif", True))


def network_rows(config: Any, proto: dict[str, Any], train: DSLR, augmented: Any,
                 val: DSLR) -> dict[str, dict[str, float]]:
    """Train each network of `NETWORKS` (`config` with its supervision, input and side) on
    `augmented` within its budget and score it on whole `val` images beside the best constant
    depth of `train` (`models.experiment.train_and_evaluate`)."""
    from models.experiment import train_and_evaluate
    from models.metrics import format_table

    train_set, test_set = limit(augmented, proto["max_train"]), limit(val, proto["max_test"])
    rows: dict[str, dict[str, float]] = {}
    for label, supervision, input_mode, sided in NETWORKS:
        if input_mode == "aif" and not proto["paper_setting"]:
            continue
        folder = supervision if input_mode == config.input_mode else f"{supervision}-{input_mode}"
        side = config.side if sided else "both"
        run = dataclasses.replace(config, supervision=supervision, input_mode=input_mode,
                                  side=side,
                                  focus_distance=config.focus_distance if sided else 0.0,
                                  out_dir=config.out_dir / folder)
        print(f"DSLR ({label}): {len(train_set)} training samples and {len(test_set)} whole test "
              f"samples; device {run.device}")
        found = train_and_evaluate(run, train_set, test_set,
                                   constant_set=limit(train, proto["max_train"]),
                                   report_every=None if run.progress else 0, report=print)
        print(format_table(found))
        prior = f", side {config.side}" if sided and config.side != "both" else ""
        for name, row in found.items():
            rows[name if name.startswith("best constant") else f"{name} [{label}{prior}]"] = row
    return rows


def main(argv: list[str] | None = None) -> int:
    with script_errors():
        return _main(argv)


def _main(argv: list[str] | None) -> int:
    from models.metrics import METRIC_NAMES, format_table
    from models.training import TrainConfig
    from models.training.config import read_yaml_mapping
    from optics.progress import progress_bar

    args = request_from(ScriptRequest, recipe_parser(RECIPE).parse_args(argv))
    names = {field.name for field in dataclasses.fields(TrainConfig)}
    keys = {**RECIPE_KEYS, **{key: value for key, value in read_yaml_mapping(RECIPE).items()
                              if key not in names and key not in RECIPE_KEYS}}
    proto, fields, given = read_recipe(args, keys)
    if proto["threads"]:
        torch.set_num_threads(int(proto["threads"]))
    out, progress = Path(args.out or fields.get("out_dir", "runs/dslr")), fields.get(
        "progress", True)
    camera = Path(proto["camera"]) if proto["camera"] else None
    # the table JSON is checked before any work: not the camera JSON, not a file of --root, no
    # earlier table replaced without --overwrite
    plan = plan_json_option(proto["json"], args.overwrite, args.root, "table", [
        ("camera", camera), ("camera JSON of this run", out / "camera.json"),
        ("loss-matched camera JSON of this run", out / "camera_loss.json")], "--set json")
    train, val, lens, camera = datasets(args, proto, out, progress)
    if train.register and proto["memory_cache_mb"] > 0:  # register each pair once, first
        for index in progress_bar(range(len(train)), desc="registering the training pairs",
                                  disable=not progress):
            train[index]
    augmented = train.with_augment(JointAugment(
        crop_size=recipe_crop(proto, fields, train, print), hflip=0.5, gain=0.1))
    first = augmented[0]
    focus = float(first["camera"].focus_distance.reshape(-1)[0])  # the side prior's plane
    config = recipe_config(args, proto, {
        "focus_distance": 0.0 if fields.get("side", "both") == "both" else focus, **fields,
        "out_dir": out}, given, train, first)
    scored = "validation" if proto["eval_split"] is None else f"{proto['eval_split']} split"
    print(f"DSLR: {len(train)} training scenes, {len(val)} {scored} scenes "
          f"({val.ids[0]} to {val.ids[-1]}), camera {json.loads(Path(camera).read_text())}")
    depth_range = (config.depth_min, config.depth_max)
    rows = network_rows(config, proto, train, augmented, val)
    if config.side != "both":
        rows.update(side_bound_row(val, depth_range, config.side))
    rows.update(label_free_rows(lens, depth_range, proto["predict_pixels"],
                                proto["predict_side"]))
    constant = next(row for name, row in rows.items() if name.startswith("best constant"))
    print(f"\nDSLR {scored} ({len(val)} scenes, never used to fit or train; order: the rank "
          "correlation of a network's depth with the true depth, mean over the scenes):")
    print(format_table(rows, metrics=(*METRIC_NAMES, "depth_order")))
    for name, row in rows.items():
        print(f"  {name}: abs rel {row['abs_rel'] / constant['abs_rel']:.2f}x the constant's")
    if plan is not None:
        write_json(plan, Path(proto["json"]), rows)
        print(f"table -> {proto['json']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
