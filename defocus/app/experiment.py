"""Train and evaluate on a dataset, or score a label-free method on a focal-stack benchmark: the
work of the scripts under `examples/`.

A training example is a recipe (`examples/<name>.yaml`: `RECIPE_KEYS` and `TrainConfig`
fields) run by `run_recipe` with `defocus train`'s options (`--root`, `--set KEY=VALUE`, ...):
the network trains on random crops of the full-resolution samples within the time budget
(`TrainConfig.minutes`) and is evaluated on whole test images next to the best constant depth
(`models.experiment.train_and_evaluate`). The benchmark examples take `defocus evaluate`'s
options (`defocus.commands.evaluate.benchmark_parser`).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import Dataset, Subset

from defocus.app import silent
from defocus.options import device_kind

Report = Callable[[str], None]


def loss_window(size: Sequence[int], largest: int = 63) -> int:
    """The loss's largest PSF window (odd, pixels) for training inputs of `size = (H, W)`:
    `largest`, or less for inputs smaller than that, where a wider window adds only work.

    Example:
        >>> loss_window((128, 128)), loss_window((12, 18))
        (63, 11)
    """
    side = min(int(size[0]), int(size[1]), largest)
    return max(side - 1 + side % 2, 3)


def limit(dataset: Dataset, count: int | None) -> Dataset:
    """The first `count` samples of `dataset` (all of them for None): a `DepthDataset`'s
    view (`first`: it keeps its augmentation and takes hints), else a `Subset`."""
    if count is None or count >= len(dataset):
        return dataset
    return dataset.first(count) if hasattr(dataset, "first") else Subset(dataset, range(count))


def truncation_warning_once() -> None:
    """Show the renderer's "PSFs are truncated" warning once, not at every training step
    whose predicted depths reach the ends of the depth range."""
    original = warnings.showwarning
    seen = [False]

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ANN001
        if "PSFs are truncated" in str(message):
            if seen[0]:
                return
            seen[0] = True
            message = UserWarning(f"{message} (shown once; predictions near the ends of the "
                                  "depth range blur the most)")
        original(message, category, filename, lineno, file, line)

    warnings.showwarning = show


@dataclasses.dataclass(frozen=True)
class ScriptRequest:
    """What an example script asks (the options of `defocus.commands.train.recipe_parser` or
    `defocus.commands.evaluate.benchmark_parser`), built from them by
    `defocus.app.request_from`."""

    config: Path | None = None  # the recipe (YAML)
    overrides: Sequence[str] = ()  # `--set KEY=VALUE` words
    root: Path | None = None
    size: Sequence[int] | None = None
    out: Path | None = None
    resume: bool = False
    overwrite: bool = False
    split: str | None = None
    json: Path | None = None
    method: str = "auto"
    device: str = "auto"
    threads: int = 0
    max_samples: int | None = None
    max_pixels: int | None = None


#: Keys of an example's recipe (`examples/*.yaml`) beside the `TrainConfig` fields, with their
#: defaults; `--set KEY=VALUE` changes either kind.
RECIPE_KEYS = {
    "name": "the dataset",  # as the report names it
    "data": "synthetic",  # `datasets.registry.DATASET_NAMES`
    "dataset": {},  # more keyword arguments of the dataset class
    "splits": ["train", "test"],  # training and test split (the same: test on training data;
    # "lists": train and test with the folder's train.txt, else "all" for both)
    "size": None,  # resize whole images to [H, W] first (the blur in pixels shrinks too)
    "eval_crop": None,  # evaluation crop: "eigen", "garg" or fractions
    "has_depth": True,  # false: the table holds reconstruction losses
    "crop": None,  # random training crops [H] or [H, W] (0: whole images; default per device)
    "max_train": None,  # at most this many training samples
    "max_test": None,  # at most this many test samples
    "max_epochs": 200.0,  # with a time budget: at most this many passes over the pixels
    "cache": True,  # keep synthesised focal stacks in the per-user cache
    "memory_cache_mb": 2048.0,  # MiB of full-resolution samples kept in memory
    "threads": 0,  # CPU threads of PyTorch (0: its default)
    "cpu_minutes": 10.0,  # the time budget on a CPU when neither steps nor minutes is given
}
#: Defaults per device kind of the training examples: crop side (pixels), steps (None: the
#: `max_epochs` passes within the CPU's time budget).
DEVICE_DEFAULTS = {"cpu": {"crop": 128, "steps": None}, "cuda": {"crop": 256, "steps": 20000}}
#: Defaults per device kind of the benchmark examples: samples scored, working pixels.
BENCHMARK_DEFAULTS = {"cpu": {"max_samples": 8, "max_pixels": 250_000},
                      "cuda": {"max_samples": None, "max_pixels": 1_500_000}}


def read_recipe(args: ScriptRequest, keys: dict[str, Any] = RECIPE_KEYS,
                ) -> tuple[dict[str, Any], dict[str, Any], set[str]]:
    """(the experiment's `keys` with their values, the `TrainConfig` fields, the fields the user
    gave) of the recipe `--config` with `--set` overrides; a bad value ends the script in one
    line (`ValueError`)."""
    from models.training.config import parse_overrides, read_yaml_mapping

    try:
        given = {**read_yaml_mapping(args.config), **parse_overrides(args.overrides)}
    except ValueError as error:
        raise ValueError(f"{args.config}: {error}") from None
    experiment = {key: given.pop(key, value) for key, value in keys.items()}
    crop = experiment["crop"]
    crop = crop if isinstance(crop, list) else [crop] if crop is not None else None
    if crop is not None and (len(crop) > 2 or not all(isinstance(c, int) and c >= 0
                                                      for c in crop)):
        raise ValueError(f"crop takes one or two sizes in pixels (0: whole images), got {crop}")
    experiment["crop"] = crop
    if experiment["splits"] == "lists":  # the split lists of the folder, else all for both
        lists = args.root is not None and (Path(args.root) / "train.txt").is_file()
        experiment["splits"] = ["train", "test"] if lists else ["all", "all"]
    return experiment, given, set(given)


def _dataset(experiment: dict[str, Any], args: ScriptRequest, split: str) -> Dataset:
    from datasets.registry import build_dataset

    size = args.size or experiment["size"]
    kwargs = dict(experiment["dataset"], memory_cache_mb=experiment["memory_cache_mb"])
    if experiment["data"] != "lightfield":  # real refocusing: nothing to cache
        kwargs["cache_dir"] = "auto" if experiment["cache"] else None
    root = None if str(args.root) == "builtin" else args.root  # a scene shipped with a package
    return build_dataset(experiment["data"], root, split=split,
                         size=None if size is None else tuple(size), **kwargs)


def run_recipe(args: ScriptRequest, report: Report = print) -> dict[str, dict[str, float]]:
    """An example script: train on the dataset of the recipe `args.config` under `--root` with
    `defocus train`'s options (`defocus.commands.train.recipe_parser`) and evaluate on whole
    test images (`models.experiment.train_and_evaluate`); returns
    the table's rows. Training takes random crops (flips and gains) of the whole training
    samples, which also choose the best constant depth."""
    from datasets import JointAugment
    from defocus.app.train import check_learned_optics
    from models.experiment import keep_freed_memory, train_and_evaluate
    from models.metrics import format_table
    from models.training.hints import attach_hints

    experiment, fields, given = read_recipe(args)
    check_learned_optics(fields.get("learn_optics") or "", experiment["data"],
                         experiment["dataset"].get("focus"))
    if experiment["threads"]:
        torch.set_num_threads(int(experiment["threads"]))
    keep_freed_memory()
    truncation_warning_once()
    whole = _dataset(experiment, args, experiment["splits"][0])
    crop = recipe_crop(experiment, fields, whole, report)
    fit_on = limit(whole, experiment["max_train"])  # hints found only for the scenes trained on
    crops = fit_on.with_augment(JointAugment(crop_size=crop, hflip=0.5, gain=0.1))
    test_set = whole if experiment["splits"][1] == experiment["splits"][0] else \
        _dataset(experiment, args, experiment["splits"][1])
    test_set = limit(test_set, experiment["max_test"])
    first = crops[0]
    config = recipe_config(args, experiment, fields, given, whole, first)
    train_set = attach_hints(crops, config, config.progress)
    kind = device_kind(config.device)
    crop_text = (f"random {tuple(first['image'].shape[-2:])} crops of" if crop else "whole")
    report(f"{experiment['name']}: {len(train_set)} training samples ({crop_text} "
           f"{tuple(whole[0]['image'].shape[-2:])} pixels) and {len(test_set)} whole test "
           f"samples, {int(first['focused'].shape[0])} focused images each; device {kind}")
    rows = train_and_evaluate(config, train_set, test_set, crop=experiment["eval_crop"],
                              has_depth=experiment["has_depth"],
                              constant_set=fit_on if experiment["has_depth"] else None,
                              report_every=None if config.progress else 0, report=report)
    if not experiment["has_depth"]:
        report("no ground-truth depth: self-supervised reconstruction losses on the test set")
    report(format_table(rows, metrics=tuple(next(iter(rows.values()))))
           if not experiment["has_depth"] else format_table(rows))
    return rows


def recipe_crop(experiment: dict[str, Any], fields: dict[str, Any], whole: Dataset,
                report: Report = silent) -> tuple[int, int] | None:
    """The training crop of a recipe (`training_crop`): its `crop`, else the device's."""
    kind = device_kind(str(fields.get("device", "auto")))
    return training_crop(experiment["crop"] or [DEVICE_DEFAULTS[kind]["crop"]], whole, report)


def recipe_config(args: ScriptRequest, experiment: dict[str, Any], fields: dict[str, Any],
                  given: set[str], whole: Dataset, first: dict) -> Any:
    """The `TrainConfig` of a recipe (`read_recipe`) and `defocus train`'s options: its fields
    over the defaults of the device (a CPU trains within `cpu_minutes` unless `steps` or
    `minutes` is given, a GPU 20000 steps), the run folder `--out` and `--resume`/`--overwrite`;
    `first` is the first training sample (the loss's window)."""
    from models.training import TrainConfig

    kind = device_kind(str(fields.get("device", "auto")))
    defaults = {"out_dir": args.out or f"runs/{Path(args.config).stem}", "device": kind,
                "max_kernel_size": loss_window(first["image"].shape[-2:])}
    if "minutes" not in given and "steps" not in given and kind == "cpu":
        defaults["minutes"] = experiment["cpu_minutes"]
    defaults["steps"] = DEVICE_DEFAULTS[kind]["steps"] or _epoch_steps(
        experiment["max_epochs"], fields.get("batch_size", TrainConfig.batch_size), whole, first)
    fields = dict(fields)
    if args.out is not None:
        fields.pop("out_dir", None)
    if args.resume or args.overwrite:
        fields["resume"] = "resume" if args.resume else "overwrite"
    try:
        return TrainConfig.load(None, [], **{**defaults, **fields})
    except ValueError as error:
        raise ValueError(f"{args.config}: {error}") from None


def _epoch_steps(max_epochs: float, batch_size: int, whole: Dataset, first: dict) -> int:
    """The most steps of `max_epochs` passes over the training pixels of `whole`."""
    dataset_pixels = len(whole) * int(whole[0]["image"][0].numel())
    step_pixels = batch_size * int(first["image"][0].numel())
    return max(10, math.ceil(max_epochs * dataset_pixels / step_pixels))


def training_crop(crop: Sequence[int], probe: Dataset,
                  report: Report = silent) -> tuple[int, int] | None:
    """The training crop `[H]` or `[H, W]` (0: whole images), made to fit inside `probe[0]`
    (the unaugmented training set): a crop larger than the image becomes the whole image side."""
    if crop[0] == 0:
        return None
    crop = (crop[0], crop[-1])
    h, w = probe[0]["image"].shape[-2:]
    fitted = (min(crop[0], h), min(crop[1], w))
    if fitted != crop:
        report(f"crop {crop[0]}x{crop[1]} does not fit the {h}x{w} images: using {fitted[0]}x"
               f"{fitted[1]}")
    return None if fitted == (h, w) else fitted


def plan_json_option(path: Path | None, overwrite: bool, root: Path | None,
                     what: str = "metrics JSON", inputs: Any = None,
                     option: str = "--json") -> Any:
    """The checked plan of an example's JSON output `path` (`option`), None without one, made
    before any work: not an existing file of `root` (`--root`) nor one of `inputs` (`(name,
    path)` pairs), no earlier result replaced without `overwrite`
    (`defocus.app.outputs.plan_json`); a refusal is one of `defocus.errors.USER_ERRORS`.

    Example:
        >>> plan_json_option(None, False, None) is None
        True
    """
    from .outputs import plan_json

    return plan_json(path, overwrite, inputs, {"--root": root}, what, option)


def run_benchmark_example(name: str, args: ScriptRequest, dataset: Dataset,
                          protocol: str | None, report: Report = silent) -> dict[str, float] | None:
    """Score `args.method` on `dataset` with `protocol` (`models.protocols.PROTOCOLS`) and report
    the paper-style table; with no protocol (no ground truth) report the depth range of each
    scene instead. Returns the metrics; `--json` is planned before any sample is scored and
    written through the output policy (`plan_json_option`)."""
    from models.evaluation import label_free_method
    from models.metrics import format_table
    from models.protocols import PROTOCOLS

    from .outputs import write_json

    plan = plan_json_option(args.json, args.overwrite, args.root)
    if args.threads:
        torch.set_num_threads(args.threads)
    kind = device_kind(args.device)
    defaults = BENCHMARK_DEFAULTS[kind]
    device = kind if args.device == "auto" else args.device
    count = args.max_samples if args.max_samples is not None else defaults["max_samples"]
    count = len(dataset) if count is None else min(count, len(dataset))
    method = label_free_method(dataset.depth_range, args.method, device=device,
                               max_pixels=args.max_pixels or defaults["max_pixels"])
    report(f"{name}: scoring {count} of {len(dataset)} samples with the {method.name} method on "
           f"{device}")
    samples = (dataset[i] for i in range(count))
    if protocol is None:
        for i, sample in enumerate(samples):
            depth = method(sample)
            report(f"  {sample['id']}: depth {float(depth.min()):.3g}-{float(depth.max()):.3g} m "
                   f"({i + 1}/{count}); no ground truth: judge the depth maps by eye")
        return None
    metrics = score_benchmark(samples, method, protocol, count, report)
    report(format_table({f"{method.name} (label-free)": metrics},
                        metrics=PROTOCOLS[protocol].metrics, number_format="{:.4g}"))
    report(f"protocol: {PROTOCOLS[protocol].source}")
    if plan is not None:
        write_json(plan, args.json, metrics)
    return metrics


def score_benchmark(samples, method, protocol: str, count: int,
                    report: Report = silent) -> dict[str, float]:
    """`models.evaluate` of `method` on `count` samples with `protocol`, reporting each
    sample's abs rel as it is scored."""
    from models import evaluate

    def each(index: int, sample_id: str, values: dict[str, float]) -> None:
        report(f"  {index + 1}/{count} {sample_id}: abs rel {values['abs_rel']:.4g}")

    return evaluate(samples=samples, predict=method, protocol=protocol, report=each)
