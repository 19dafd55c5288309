"""The paper's protocol on real defocus: the DSLR set (DFD-indoor) of Carvalho et al. 2018.

Data: "Deep Depth from Defocus: how can defocus blur improve 3D estimation using dense neural
networks?" (3DRW ECCV Workshop 2018), the indoor set of its public release (repository
marcelampc/d3net_depth_estimation, folder `dfd_datasets/dfd_indoor`), read as released by
`datasets.DSLR`: each scene at f/8 (the nearly sharp `image`) and f/2.8 (the real focused
photo), 645x432 JPEGs, with registered depth. Give ``--root`` the `dfd_indoor` folder.

The recipe is ``examples/dslr.yaml``; ``--set KEY=VALUE`` changes any of its keys (the
protocol's: ``val``, ``eval_split``, ``focus``, ``camera``, ``calibrate_every``, ...) or of the
`TrainConfig` fields (the options of ``defocus train``); ``--focus`` and ``--eval-split`` are
the keys ``focus`` and ``eval_split`` as options.

What it does, on the split's scenes in time order (the last ``val`` are the validation set,
never used to fit or train; with ``--eval-split test`` every scene of ``--split`` trains and
the other split is scored, the paper's protocol):

1. calibrates the camera on the training scenes (``defocus calibrate --data dslr``: the
   blur measured by depth, the thin lens with a floor, the exposure gain; skipped with
   ``camera=JSON``), then scales its blur to the one the training loss agrees with at the
   true depth of those scenes (`models.diagnostics.match_blur_scale`, ``camera_loss.json``;
   off with ``blur_match=false``): the calibration fits the blur by its squared error, the
   paper's loss (SSIM, L1, sharpness) prefers about 1.2x that blur on this set;
2. trains four networks on the same scenes with the same budget: the self-supervised one (the
   f/8 photo rendered through the PSF layer at the predicted depth must reproduce the real f/2.8
   photo; no depth in the loss), its depth-supervised twin, and the paper's own setting (the
   network sees the f/8 photo alone, ``input_mode=aif``), trained through the PSF layer and
   with depth labels (``inputs=[aif+focused]`` leaves these two out, ``inputs=[aif]`` the first
   two). The render models the
   pair as calibrated (`DSLR(relative=True)`): the f/2.8 photo registered onto the f/8 one
   (`datasets.pairs.register_focused`), the f/8 photo's own blur, the floor and the exposure
   gain;
3. one focus plane cannot tell near from far: the self-supervised networks put a blur that both
   sides explain on the side ``side`` states (default ``beyond``: a prior, chosen on the
   training scenes, 22 % of whose pixels are nearer than the focus plane), and a blur above the
   far side's bound near (`models.depth_head.DepthHead`);
4. scores them on the held-out scenes beside the label-free `predict` (no training: the f/8
   photo as one more shot, `estimate_depth(image_settings=...)`, with the fitted camera) and the
   best constant depth of the training scenes, prints the table (``json=PATH`` writes it). A
   row marked ``bound:`` scores the true depth of the scored scenes (the validation scenes, or
   the ``eval_split``'s) with its ambiguous blur put on ``side``
   (`models.depth_from_photos.side.fold_to_side`): what a self-supervised network that found the loss's
   best everywhere would score under that prior; no training can do better on those scenes.
   With ``side=both`` (no prior) the table shows the bound of each side: a network without a
   prior must tell near from far by other cues (the image's content) to do better than the
   better of the two. ``predict_side`` is the side the label-free `predict` is told
   (`defocus predict --side`), ``predict_pixels`` its working resolution and
   ``predict_smoothing`` the strength of its edge-aware smoothing (the method's ``smoothing``);
5. ``scored=beyond`` (or ``before``) scores only the held-out scenes that lie on that side of
   their focus plane, chosen by the bound alone (each scene's true depth folded to that side
   scores abs rel <= ``side_tolerance``, 0.1), as a photographer's statement would be made:
   before any training, from where the scene is. One focus plane then tells the depth::

    python examples/dslr.py --root data/dfd_indoor --set scored=beyond predict_side=beyond

   ``trained=beyond`` (or ``before``) trains on the training scenes chosen by the same rule:
   the statement made for each training photo too, so that the side prior holds at every
   pixel the networks learn from.

``hint_weight=W`` trains the self-supervised networks with depth hints (`TrainConfig.hint_weight`):
each training scene's label-free depth, found once as `predict` finds it (the photos as taken,
the lens's camera, ``predict_side``, ``predict_pixels``, ``predict_smoothing``), pulls the
network's depth where it renders the training photos better than the network's depth does. No
depth label is read.

``--focus synthesized`` reads the set the paper's way (Gur & Wolf 2019), as an RGB-D set: the
f/8 photo is the all-in-focus image and the two focused images are rendered from it and the
registered depth through the PSF layer at the paper's focus settings, 0.2 and 0.8 of the far
end of the depth range (2 m and 8 m), with the DSLR camera (35 mm, the preset's f/2.8 and pixel
pitch, or those of ``camera=JSON``; `DSLR(focus="synthesized")`). Two focus planes tell near
from far, so nothing is calibrated, matched or registered and no side prior applies (``side``
is ``both``; setting ``side``, ``calibrate_every``, ``relative``, ``register``,
``blur_match``, ``predict_side`` or ``scored`` is refused); the label-free `predict` reads the two rendered
images with the rendering camera, and there is no ``bound:`` row.

Every row of the table and of the JSON file (``json=PATH``: method name -> ``metrics``,
``input``, ``supervision``, ``seed``) says what the method reads (``input``: ``aif``, the f/8
photo alone; ``aif+focused``, with the focused photo(s); ``none``: no image, the constant depth
and the bounds) and how it learned (``supervision``: ``self``, through the PSF layer; ``depth``,
from depth labels; ``none``: no training), with the run's ``seed`` (`TrainConfig.seed`).
Its ``metrics`` are the depth metrics (`models.metrics.METRIC_NAMES`) and ``depth_order``
(the rank correlation with the true depth; a constant depth scores 0).

CPU (default: 2.5 minutes per network, about 12 minutes on 2 cores)::

    python examples/dslr.py --root data/dfd_indoor
    python examples/dslr.py --root data/dfd_indoor --focus synthesized --eval-split test \\
        --set json=dslr_synthesized.json

GPU, the paper's protocol (Gur & Wolf 2019: ResNet-50 + dense ASPP + attention network, Adam lr
2e-5, Gaussian PSF sigma = CoC/2, real f/2.8 and f/8 photos; 256x256 crops, batch 8)::

    python examples/dslr.py --root data/dfd_indoor --set device=cuda network=paper lr=2e-5 \\
        steps=20000 crop=256 batch_size=8
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Sequence
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
#: The recipe keys of the real f/2.8 photos (calibration, registration, the side prior), which
#: ``--focus synthesized`` does not use: setting one there is refused.
REAL_FOCUS_KEYS = ("side", "calibrate_every", "relative", "register", "blur_match",
                   "predict_side", "scored", "trained")
#: What a method reads (a row's ``input``) where it reads no image: the constant, the bounds.
NO_INPUT = "none"

Row = dict[str, Any]


def table_row(metrics: dict[str, float], input_mode: str, supervision: str, seed: int) -> Row:
    """A row of the table's JSON: the method's `metrics` (the counts `images` and `skipped`
    of `models.evaluate` left out), what it reads (`input`: ``"aif"``, ``"aif+focused"`` or
    ``"none"``), how it learned (`supervision`: ``"self"``, ``"depth"`` or ``"none"``) and the
    run's `seed`.

    Example:
        >>> table_row({"abs_rel": 0.2, "images": 3}, "aif", "self", 0)
        {'metrics': {'abs_rel': 0.2}, 'input': 'aif', 'supervision': 'self', 'seed': 0}
    """
    kept = {key: value for key, value in metrics.items() if key not in ("images", "skipped")}
    return {"metrics": kept, "input": input_mode, "supervision": supervision, "seed": int(seed)}


def order_of(depth_cap: float):
    """An `also` of `models.evaluate`: each scene's `depth_order` (ground truth up to
    `depth_cap` metres)."""
    from models.metrics import depth_order

    def also(depth: torch.Tensor, sample: dict) -> dict[str, float]:
        return {"depth_order": depth_order(pred=depth, target=sample["depth"],
                                           mask=sample.get("mask"), max_depth=depth_cap)}

    return also


def side_bound_row(val: DSLR, depth_range: tuple[float, float],
                   side: str) -> dict[str, dict[str, float]]:
    """The error that no self-supervised training removes under the side prior: each scored
    scene's true depth with its ambiguous blur put on `side` (`fold_to_side`), averaged."""
    from models import evaluate
    from models.depth_from_photos.side import fold_to_side

    def bound(sample: dict) -> torch.Tensor:
        focus = float(sample["camera"].focus_distance.reshape(-1)[0])
        return fold_to_side(sample["depth"], focus, depth_range, side)

    return {f"bound: the true depth through one focus plane, side {side}": evaluate(
        bound, (val[i] for i in range(len(val))), "eigen", max_depth=depth_range[1],
        also=order_of(depth_range[1]))}


def bound_rows(val: DSLR, depth_range: tuple[float, float],
               side: str) -> dict[str, dict[str, float]]:
    """The `side_bound_row` of the scored scenes under the prior `side`; with ``"both"`` (no
    prior) that of each side. None with synthesised focus at two planes or more (they tell the
    sides)."""
    if val.focus == "synthesized" and len(val.focus_fractions) > 1:
        return {}
    rows: dict[str, dict[str, float]] = {}
    for each in (("beyond", "before") if side == "both" else (side,)):
        rows.update(side_bound_row(val, depth_range, each))
    return rows


def label_free_rows(val: DSLR, depth_range: tuple[float, float], max_pixels: int,
                    side: str = "both", options: dict[str, Any] | None = None,
                    ) -> dict[str, dict[str, float]]:
    """`estimate_depth` on each scored scene, averaged: the f/8 photo as one more shot beside
    the real f/2.8 one, with the fitted camera (with a side stated, `estimate_depth`'s `side`:
    what `defocus predict --side` does); with synthesised focus, the rendered images with
    the rendering camera and the f/8 photo as the all-in-focus image. `options`: the method's
    (`estimate_depth`'s `options`)."""
    from models import evaluate
    from models.training.hints import label_free_depth
    from optics.progress import progress_bar

    real = val.focus == "real"

    def label_free(sample: dict) -> torch.Tensor:
        return label_free_depth(sample, depth_range, max_pixels,
                                val.reference_settings if real else None, side, options)

    samples = (val[i] for i in progress_bar(range(len(val)), desc="label-free predict"))
    prior = "" if side == "both" else f", side {side}"
    name = f"label-free predict (f/8 as a shot, fitted camera{prior})" if real else \
        "label-free predict (the rendered images, the rendering camera)"
    return {name: evaluate(label_free, samples, "eigen", max_depth=depth_range[1],
                           also=order_of(depth_range[1]))}


def scenes_on_side(scored: DSLR, depth_range: tuple[float, float], side: str,
                   tolerance: float) -> list[int]:
    """The positions of the `scored` scenes that lie on `side` of their focus plane, chosen by
    the bound alone (each scene's `side_bound_row`: its true depth with the ambiguous blur put
    on `side` scores abs rel <= `tolerance`), as a user's statement would be made: before any
    training, from where the scene is, not from what a method makes of it."""
    from models.depth_from_photos.side import fold_to_side

    kept = []
    for index in range(len(scored)):
        sample = scored[index]
        depth, valid = sample["depth"], sample["mask"].bool()
        focus = float(sample["camera"].focus_distance.reshape(-1)[0])
        folded = fold_to_side(depth, focus, depth_range, side)
        if float(((folded - depth).abs() / depth)[valid].mean()) <= tolerance:
            kept.append(index)
    return kept


#: the recipe keys that state a side for scenes, and which scenes each states it for
STATED_SCENES = {"trained": "training", "scored": "held-out"}


def stated_scenes(root: Path, split: str, positions: Sequence[int] | None, key: str,
                  side: str, depth_range: tuple[float, float], tolerance: float,
                  **options: Any) -> list[int]:
    """The positions of `split`'s scenes at `positions` (None: all) that lie on `side` of their
    focus plane (`scenes_on_side`, read with `options`, e.g. the lens's ``camera``), as the
    recipe's `key` (`STATED_SCENES`) states; the run stops when none does."""
    scenes = DSLR(root, split, scenes=positions, **options)
    every = list(range(len(scenes))) if positions is None else list(positions)
    on_side = scenes_on_side(scenes, depth_range, side, tolerance)
    if not on_side:
        raise SystemExit(f"{key}={side}: none of the {len(scenes)} {STATED_SCENES[key]} "
                         f"scenes lies {side} its focus plane within side_tolerance={tolerance}")
    return [every[i] for i in on_side]


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


def datasets(args: ScriptRequest, proto: dict[str, Any], out: Path, progress: bool,
             depth_range: tuple[float, float]) -> tuple[DSLR, DSLR, DSLR, Path | None, DSLR]:
    """The training and scored scenes, the scored scenes of the label-free `predict`, the
    camera JSON of the training (None: the preset's) and the training scenes as `predict`
    reads them (their depth hints', ``hint_weight``). Real focus: relative pairs, the lens's
    own camera for `predict`, the camera fitted on the training scenes; synthesised focus: the
    scenes rendered with the preset's or ``camera``'s lens, for training and `predict` alike."""
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
    if proto["focus"] == "synthesized":
        camera = Path(proto["camera"]) if proto["camera"] else None
        rendered = {"focus": "synthesized", "camera": camera,
                    "focus_fractions": proto["focus_fractions"],
                    "cache_dir": "auto" if proto["cache"] else None, **kwargs}
        train = DSLR(args.root, args.split, scenes=fit_on, **rendered)
        val = DSLR(args.root, scored[0], scenes=scored[1], **rendered)
        return train, val, val, camera, train
    train = DSLR(args.root, args.split, scenes=fit_on, **kwargs)
    camera = Path(proto["camera"]) if proto["camera"] else calibrate(proto, out, train, progress)
    pair = {"camera": camera, "relative": proto["relative"],
            "register": None if proto["register"] else False, **kwargs}
    if proto["blur_match"]:
        pair["camera"] = match_loss_camera(args, proto, out, camera, pair, fit_on)
    stated = {"depth_range": depth_range, "tolerance": proto["side_tolerance"],
              "camera": camera, **kwargs}
    if proto["trained"] != "all":  # the training scenes on the stated side, by the bound alone
        fit_on = stated_scenes(args.root, args.split, fit_on, "trained", proto["trained"],
                               **stated)
    train = DSLR(args.root, args.split, scenes=fit_on, **pair)
    if proto["scored"] != "all":  # the held-out scenes on the stated side, by the bound alone
        scored = (scored[0], stated_scenes(args.root, *scored, "scored", proto["scored"],
                                           **stated))
    lens = DSLR(args.root, scored[0], scenes=scored[1], camera=camera, **kwargs)
    val = DSLR(args.root, scored[0], scenes=scored[1], **pair)
    return train, val, lens, camera, DSLR(args.root, args.split, scenes=fit_on, camera=camera,
                                          **kwargs)


#: the networks of the table: (label, supervision, input mode, whether the side prior applies)
NETWORKS = (("self-supervised", "self", "aif+focused", True),
            ("depth-supervised", "depth", "aif+focused", False),
            ("self-supervised, f/8 photo alone (the paper's setting)", "self", "aif", True),
            ("depth-supervised, f/8 photo alone (the paper's setting)", "depth", "aif", False))


def network_rows(config: Any, proto: dict[str, Any], train: DSLR, augmented: Any,
                 val: DSLR) -> dict[str, Row]:
    """Train each network of `NETWORKS` (`config` with its supervision, input and side) on
    `augmented` within its budget and score it on whole `val` images beside the best constant
    depth of `train` (`models.experiment.train_and_evaluate`); the rows of `table_row`."""
    from models.experiment import train_and_evaluate
    from models.metrics import format_table

    train_set, test_set = augmented, limit(val, proto["max_test"])
    rows: dict[str, Row] = {}
    for label, supervision, input_mode, sided in NETWORKS:
        if input_mode not in proto["inputs"]:
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
                                   constant_set=train,
                                   report_every=None if run.progress else 0, report=print)
        print(format_table(found))
        prior = f", side {config.side}" if sided and config.side != "both" else ""
        prior += ", depth hints" if supervision == "self" and config.hint_weight > 0 else ""
        for name, metrics in found.items():
            if name.startswith("best constant"):  # a constant map orders nothing: 0
                rows[name] = table_row({**metrics, "depth_order": 0.0}, NO_INPUT, "none",
                                       config.seed)
            else:
                rows[f"{name} [{label}{prior}]"] = table_row(metrics, input_mode, supervision,
                                                             config.seed)
    return rows


def parser():
    """`defocus train`'s options (`recipe_parser`) and the recipe keys ``focus`` and
    ``eval_split`` as options."""
    parsed = recipe_parser(RECIPE)
    parsed.add_argument("--focus", choices=("real", "synthesized"), default=None,
                        help="the focused images: the real f/2.8 photos, or rendered from the "
                             "f/8 photo and the depth at 0.2 and 0.8 of the depth cap (the "
                             "recipe key focus; default: the recipe's, real)")
    parsed.add_argument("--eval-split", default=None, metavar="SPLIT",
                        help="train on every scene of --split and score this split, e.g. test "
                             "(the recipe key eval_split; default: the recipe's, the last val "
                             "scenes of --split)")
    return parsed


def keys_as_options(options: Any) -> Any:
    """`options` with ``--focus`` and ``--eval-split`` as ``--set`` words; the same key given
    both ways is refused (which one was meant is unknown)."""
    from models.training.config import parse_overrides

    given = parse_overrides(options.overrides)
    words = list(options.overrides)
    for key, option in (("focus", "--focus"), ("eval_split", "--eval-split")):
        value = getattr(options, key)
        if value is None:
            continue
        if key in given:
            raise ValueError(f"{option} {value} and --set {key}={given[key]} both set {key}: "
                             f"give only {option}")
        words.append(f"{key}={value}")
    options.overrides = words
    return options


def main(argv: list[str] | None = None) -> int:
    with script_errors():
        return _main(argv)


def recipe_keys() -> dict[str, Any]:
    """The recipe's keys beside the `TrainConfig` fields, with their defaults."""
    from models.training import TrainConfig
    from models.training.config import read_yaml_mapping

    names = {field.name for field in dataclasses.fields(TrainConfig)}
    return {**RECIPE_KEYS, **{key: value for key, value in read_yaml_mapping(RECIPE).items()
                              if key not in names and key not in RECIPE_KEYS}}


def check_recipe(args: ScriptRequest, proto: dict[str, Any], fields: dict[str, Any]) -> None:
    """Refuse, before any work, an unknown ``focus``, ``scored`` or ``inputs``, a bad
    ``side_tolerance`` or ``predict_smoothing``, learned optics or ``focus_fractions`` with the
    real photos; with ``synthesized``, a key of the real photos that the user set
    (`REAL_FOCUS_KEYS`, ``side`` other than both), and make ``side`` both."""
    from defocus.app.train import check_learned_optics
    from models.networks import INPUT_MODES
    from models.training.config import parse_overrides

    if proto["focus"] not in ("real", "synthesized"):
        raise ValueError(f"focus must be real or synthesized, got {proto['focus']!r}")
    if {proto["scored"], proto["trained"]} - {"all", "beyond", "before"} or not (
            isinstance(proto["side_tolerance"], (int, float)) and proto["side_tolerance"] > 0):
        raise ValueError(f"--set scored=all|beyond|before, trained=all|beyond|before and "
                         f"side_tolerance=a positive abs rel, got scored={proto['scored']!r}, "
                         f"trained={proto['trained']!r}, "
                         f"side_tolerance={proto['side_tolerance']!r}")
    inputs = proto["inputs"]
    if not (isinstance(inputs, list) and inputs and set(inputs) <= set(INPUT_MODES)):
        raise ValueError(f"--set inputs must list aif+focused, aif or both (each network's "
                         f"input), got {inputs!r}")
    smoothing = proto["predict_smoothing"]
    if isinstance(smoothing, bool) or not isinstance(smoothing, (int, float)) \
            or not 0 <= smoothing < float("inf"):
        raise ValueError(f"--set predict_smoothing must be a finite number >= 0, got "
                         f"{smoothing!r}")
    check_learned_optics(fields.get("learn_optics") or "", "dslr", proto["focus"])
    given = parse_overrides(args.overrides)
    if proto["focus"] != "synthesized":
        if "focus_fractions" in given:
            raise ValueError(f"--set focus_fractions={given['focus_fractions']}: where the "
                             "synthesised focused images are focused; it takes --focus "
                             "synthesized (the real photos are focused where they were taken)")
        return
    refused = [f"{key}={given[key]}" for key in REAL_FOCUS_KEYS if key in given
               and not (key in ("side", "predict_side") and given[key] == "both")]
    if refused:
        raise ValueError(f"--set {' '.join(refused)}: the real f/2.8 photos' calibration, "
                         "registration and side prior; --focus synthesized renders two focus "
                         "planes, which tell near from far (side both)")
    fields["side"] = "both"
    proto["predict_side"] = "both"


def _main(argv: list[str] | None) -> int:
    from models.depth_from_photos.trained_network import camera_record, describe_camera
    from models.metrics import METRIC_NAMES, format_table
    from models.training.hints import attach_hints
    from optics.progress import progress_bar

    args = request_from(ScriptRequest, keys_as_options(parser().parse_args(argv)))
    proto, fields, given = read_recipe(args, recipe_keys())
    check_recipe(args, proto, fields)
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
    train, val, lens, camera, hint_source = datasets(args, proto, out, progress,
                                                     (fields["depth_min"], fields["depth_max"]))
    train, hint_source = limit(train, proto["max_train"]), limit(hint_source, proto["max_train"])
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
    if train.focus == "synthesized":
        what = f"focused images rendered with {describe_camera(camera_record(first['camera']))}"
    else:
        what = f"camera {json.loads(Path(camera).read_text())}"
    print(f"DSLR: {len(train)} training scenes, {len(val)} {scored} scenes "
          f"({val.ids[0]} to {val.ids[-1]}), {what}")
    depth_range = (config.depth_min, config.depth_max)
    # the label-free `predict` of the table's row and of the depth hints
    predict = {"max_pixels": proto["predict_pixels"], "side": proto["predict_side"],
               "options": {"smoothing": proto["predict_smoothing"]}}
    augmented = attach_hints(  # real pairs: the photos as `predict` reads them, on `side`
        augmented, config, progress, hint_source, **predict,
        image_settings=None if train.focus == "synthesized" else hint_source.reference_settings)
    rows = network_rows(config, proto, train, augmented, val)
    rows.update({name: table_row(metrics, NO_INPUT, "none", config.seed)
                 for name, metrics in bound_rows(val, depth_range, config.side).items()})
    rows.update({name: table_row(metrics, "aif+focused", "none", config.seed)
                 for name, metrics in label_free_rows(lens, depth_range, **predict).items()})
    metrics = {name: row["metrics"] for name, row in rows.items()}
    constant = next(row for name, row in metrics.items() if name.startswith("best constant"))
    print(f"\nDSLR {scored} ({len(val)} scenes, never used to fit or train; {train.focus} "
          f"focus; seed {config.seed}; order: the rank correlation of a network's depth with the "
          "true depth, mean over the scenes):")
    print(format_table(metrics, metrics=(*METRIC_NAMES, "depth_order")))
    for name, row in rows.items():
        print(f"  {name} (input {row['input']}, supervision {row['supervision']}): abs rel "
              f"{row['metrics']['abs_rel'] / constant['abs_rel']:.2f}x the constant's")
    if plan is not None:
        write_json(plan, Path(proto["json"]), rows)
        print(f"table -> {proto['json']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
