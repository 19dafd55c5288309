"""Cross-dataset generalisation (Gur & Wolf 2019, claim 2): each network trained on one data set
and scored on the others, its focused images rendered with the camera it was trained for.

The paper's claim: a network trained through the PSF layer (self-supervised, no depth labels)
on one data set does better on other data sets than the same network trained with depth labels.
This script trains, on each source, the four networks of the claim (self- and
depth-supervised, each reading the all-in-focus image alone, ``aif``, or with the two focused
images, ``aif+focused``) and scores each of them on every target, beside the best constant
depth of the source's training depths (the abs-rel-optimal one; it orders nothing, depth order
0). It prints one matrix per metric (rows: source and method, columns: targets) and writes
every row with ``--json``.

The data sets, all RGB-D with focus synthesised the paper's way (`datasets.focus`):

- ``synthetic``: the procedural scenes (`datasets.SyntheticScenes`: 50 mm f/1.4 focused at 2 m
  and 6 m, 1.5-6 m), trained on one seed's scenes and scored on another's;
- ``dslr``: the DSLR set (DFD-indoor, ``--root`` the release's ``dfd_indoor`` folder) read the
  paper's way (`datasets.DSLR(focus="synthesized")`: the f/8 photo and its depth, rendered with
  the 35 mm f/2.8 lens focused at 2 m and 8 m, 0.5-10 m): the split's scenes in time order,
  the last ``--val`` scored; left out without ``--root``;
- ``middlebury``: the real motorcycle scene of scikit-image (Middlebury 2014, real disparity;
  `datasets.middlebury.motorcycle_sample`), scored only by default (as a source it is one
  scene, trained and scored on itself).

A target's focused images are rendered from its image and depth with the source's camera
(`datasets.SynthesizedFocus`, as ``defocus evaluate CKPT --data NAME`` does): a network learned
its camera's blur. Depths are scored up to the target's far end (its column's cap) with the
depth metrics (`models.metrics.METRIC_NAMES`) and the depth order (`depth_order`). Training is
`models.experiment.train_and_evaluate` (which also scores the source's own held-out scenes),
the other targets `models.evaluate` of the checkpoint it wrote.

Each row (printed and in the JSON) names its ``source``, ``target``, ``method``, what it reads
(``input``: ``aif``, ``aif+focused``, or ``none`` for the constant), how it learned
(``supervision``: ``self``, ``depth`` or ``none``), its ``seed`` (`TrainConfig.seed`) and its
``metrics``. The matrices show the mean over the seeds (and the spread with several).
``--set hint_weight=1`` trains the self-supervised networks with depth hints (the label-free
depth of each training scene, found once per source, `models.training.hints.attach_hints`);
their method names say so.

CPU (2 minutes per network: 8 networks, about 20 minutes on 2 cores; ``--quick``: small sets
and a few seconds per network, to see it run)::

    python examples/generalization.py --root data/dfd_indoor --json generalization.json
    python examples/generalization.py --quick

GPU, three seeds::

    python examples/generalization.py --root data/dfd_indoor --seeds 0 1 2 \\
        --set device=cuda steps=20000 crop=256 batch_size=8
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from dslr import NO_INPUT, order_of, table_row

#: the data sets: their depth range (metres: training range of a source, scoring cap of a
#: target) and what they are, in the matrices' order
DATASETS = {"synthetic": ((1.5, 6.0), "procedural scenes"),
            "dslr": ((0.5, 10.0), "DSLR, synthesised focus"),
            "middlebury": ((1.5, 6.0), "Middlebury motorcycle")}
#: the networks of the claim: (method, supervision, input mode)
NETWORKS = (("self-supervised, aif", "self", "aif"),
            ("depth-supervised, aif", "depth", "aif"),
            ("self-supervised, aif+focused", "self", "aif+focused"),
            ("depth-supervised, aif+focused", "depth", "aif+focused"))
#: the metrics of the matrices (all are in the JSON)
SHOWN = ("abs_rel", "delta1", "depth_order")
#: the sizes of a run: (synthetic training scenes, scored scenes, side in pixels; DSLR scenes
#: at most, scored, resize; motorcycle scale; CPU minutes per network; training crop)
SIZES = {"default": {"scenes": 128, "test_scenes": 16, "side": 96, "max_scenes": None,
                     "val": 20, "dslr_size": (216, 323), "scale": 0.25, "minutes": 2.0,
                     "crop": 128},
         "quick": {"scenes": 8, "test_scenes": 2, "side": 32, "max_scenes": 6, "val": 2,
                   "dslr_size": (54, 81), "scale": 0.08, "minutes": 0.05, "crop": 32}}


class Source:
    """One data set: its training samples (whole images), its scored samples (whole), its
    depth range (metres) and its camera (the first training sample's, once it trains)."""

    def __init__(self, name: str, train: Any, test: Any,
                 depth_range: tuple[float, float]) -> None:
        self.name, self.train, self.test, self.depth_range = name, train, test, depth_range
        self.camera: Any = None


def parser() -> argparse.ArgumentParser:
    names = tuple(DATASETS)
    parsed = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parsed.add_argument("--root", type=Path, default=None,
                        help="the DSLR release's dfd_indoor folder (without it the matrix has "
                             "no dslr row or column)")
    parsed.add_argument("--split", default="train", help="the DSLR split to read")
    parsed.add_argument("--sources", nargs="+", choices=names, default=["synthetic", "dslr"],
                        help="data sets to train on")
    parsed.add_argument("--targets", nargs="+", choices=names, default=list(names),
                        help="data sets to score on")
    parsed.add_argument("--seeds", nargs="+", type=int, default=[0],
                        help="training seeds (TrainConfig.seed): every network once per seed")
    parsed.add_argument("--quick", action="store_true",
                        help="small sets and budgets, a few minutes in all: to see it run, not "
                             "for results")
    parsed.add_argument("--minutes", type=float, default=None,
                        help="CPU minutes per network (default: 2, --quick 0.05); a GPU "
                             "trains --set steps=")
    parsed.add_argument("--set", dest="overrides", nargs="*", default=[], metavar="KEY=VALUE",
                        help="TrainConfig fields of every network, e.g. device=cuda steps=20000 "
                             "width=16, and crop=SIDE: the training crop, pixels (of the DSLR "
                             "scenes; the other sets train on whole images)")
    parsed.add_argument("--out", type=Path, default=Path("runs/generalization"),
                        help="folder of the runs (one per source, seed and network)")
    parsed.add_argument("--overwrite", action="store_true",
                        help="start the runs over and replace an earlier --json")
    parsed.add_argument("--json", type=Path, default=None,
                        help="write every row (source, target, method, input, supervision, "
                             "seed, metrics) here")
    parsed.add_argument("--threads", type=int, default=0,
                        help="CPU threads of PyTorch (0: its default)")
    return parsed


def load_source(name: str, args: argparse.Namespace, size: dict[str, Any]) -> Source:
    """The training and scored samples of data set `name`."""
    depth_range = DATASETS[name][0]
    if name == "synthetic":
        from datasets.synthetic import SyntheticScenes

        side = (size["side"], size["side"])
        return Source(name, SyntheticScenes(size["scenes"], side, seed=0),
                      SyntheticScenes(size["test_scenes"], side, seed=1000), depth_range)
    if name == "middlebury":
        from datasets.middlebury import motorcycle_sample

        scene = motorcycle_sample(size["scale"])  # its focus rendered with the synthetic camera
        return Source(name, [scene], [scene], depth_range)
    from datasets import DSLR

    count = len(DSLR(args.root, args.split).files)
    if size["max_scenes"] is not None:
        count = min(count, size["max_scenes"])
    if not 0 < size["val"] < count:
        raise SystemExit(f"dslr: {count} scenes leave none to train on beside {size['val']} "
                         "scored ones")
    kwargs = {"focus": "synthesized", "size": size["dslr_size"], "memory_cache_mb": 2048,
              "cache_dir": "auto"}
    return Source(name, DSLR(args.root, args.split, scenes=range(count - size["val"]), **kwargs),
                  DSLR(args.root, args.split, scenes=range(count - size["val"], count),
                       **kwargs), depth_range)


def training_config(args: argparse.Namespace, source: Source, size: dict[str, Any], seed: int,
                    supervision: str, input_mode: str, first: dict) -> Any:
    """A network's `TrainConfig`: the source's depth range, the budget (a CPU trains
    `size["minutes"]` or ``--minutes``; a GPU 20000 steps), ``--set`` over all."""
    from defocus.app.experiment import loss_window
    from defocus.options import device_kind
    from models.training import TrainConfig
    from models.training.config import parse_overrides

    given = parse_overrides(args.overrides)
    kind = device_kind(str(given.get("device", "auto")))
    defaults = {"depth_min": source.depth_range[0], "depth_max": source.depth_range[1],
                "device": kind, "seed": seed, "supervision": supervision,
                "input_mode": input_mode, "progress": False,
                "max_kernel_size": loss_window(first["image"].shape[-2:]),
                "out_dir": args.out / source.name / f"seed{seed}" / f"{supervision}-{input_mode}",
                "resume": "overwrite" if args.overwrite else "auto"}
    if kind == "cpu":
        defaults.update(steps=2000, minutes=args.minutes or size["minutes"])
    else:
        defaults["steps"] = 20000
    words = [word for word in args.overrides if not word.startswith("crop=")]
    return TrainConfig.load(None, words, **defaults)


def constant_rows(constant: float, targets: dict[str, Any]) -> dict[str, dict[str, float]]:
    """The metrics of `constant` metres on each target (depth order 0: it orders nothing)."""
    from models import evaluate

    rows = {}
    for name, samples in targets.items():
        metrics = evaluate(lambda sample: torch.full_like(sample["depth"], constant), samples,
                           "eigen", max_depth=DATASETS[name][0][1])
        rows[name] = {**metrics, "depth_order": 0.0}
    return rows


def network_on(checkpoint: Path, samples: Any, cap: float) -> dict[str, float]:
    """The metrics of the network of `checkpoint` on whole `samples`, depth up to `cap`."""
    from models import evaluate
    from models.evaluation import network_method
    from models.loading import load_model

    network, _ = load_model(checkpoint, "cpu" if not torch.cuda.is_available() else "cuda")
    return evaluate(network_method(network), samples, "eigen", max_depth=cap,
                    also=order_of(cap))


def run_source(args: argparse.Namespace, source: Source, targets: dict[str, Source],
               size: dict[str, Any]) -> list[dict[str, Any]]:
    """Train the four networks of `NETWORKS` on `source` once per seed and score each, and the
    best constant, on every target; the rows."""
    from datasets import JointAugment, SynthesizedFocus
    from defocus.app.experiment import training_crop
    from models.depth_from_photos.trained_network import camera_record, describe_camera
    from models.experiment import constant_from_training, train_and_evaluate
    from models.training.config import parse_overrides
    from models.training.hints import attach_hints

    source.camera = source.train[0]["camera"]
    print(f"\n== source {source.name} ({DATASETS[source.name][1]}): {len(source.train)} training "
          f"scenes, camera {describe_camera(camera_record(source.camera))}")
    # every target's scenes rendered once with the source's camera (the source's own as is)
    samples = {name: target.test if name == source.name else SynthesizedFocus(
        target.test, source.camera, keep=True) for name, target in targets.items()}
    crop = int(parse_overrides(args.overrides).get("crop", size["crop"]))
    whole = source.train  # random crops of a loader's scenes; other sets train whole
    crops = whole.with_augment(JointAugment(crop_size=training_crop([crop], whole, print),
                                            hflip=0.5, gain=0.1)) \
        if hasattr(whole, "with_augment") else whole
    constant = constant_from_training(whole)
    scored = constant_rows(constant, samples)
    # the depth hints (--set hint_weight=W) of the source's scenes, found once for every network
    crops = attach_hints(crops, training_config(args, source, size, 0, "self", "aif", crops[0]))
    rows = []
    for seed in args.seeds:
        rows += [{"source": source.name, "target": name,
                  "method": f"best constant depth ({constant:.2f} m)",
                  **table_row(metrics, NO_INPUT, "none", seed)}
                 for name, metrics in scored.items()]
        for method, supervision, input_mode in NETWORKS:
            config = training_config(args, source, size, seed, supervision, input_mode,
                                     crops[0])
            if supervision == "self" and config.hint_weight > 0:
                method = method.replace("self-supervised", "self-supervised with depth hints")
            print(f"-- {source.name}, seed {seed}: {method} ({config.out_dir})")
            own = train_and_evaluate(config, crops, source.test, constant_set=whole,
                                     report_every=0, report=print)
            ours = next(metrics for name, metrics in own.items() if name.startswith("ours"))
            checkpoint = config.out_dir / "checkpoints" / "last.pt"
            for name in samples:
                print(f"   scoring on {name}", flush=True)
                metrics = ours if name == source.name else network_on(
                    checkpoint, samples[name], DATASETS[name][0][1])
                rows.append({"source": source.name, "target": name, "method": method,
                             **table_row(metrics, input_mode, supervision, seed)})
    return rows


def matrix(rows: Sequence[dict[str, Any]], metric: str, targets: Sequence[str]) -> str:
    """A Markdown matrix of `metric`: one row per source and method, one column per target;
    the mean over the seeds (+- the standard deviation with several)."""
    from models.metrics import HIGHER_IS_BETTER, LABELS

    keys = list(dict.fromkeys((row["source"], row["method"]) for row in rows))
    arrow = "↑" if metric in HIGHER_IS_BETTER else "↓"
    header = [f"{LABELS.get(metric, metric)} {arrow}: source / method", *targets]
    lines = []
    for source, method in keys:
        cells = [f"{source} / {method}"]
        for target in targets:
            values = [row["metrics"][metric] for row in rows if (row["source"], row["method"],
                                                                  row["target"]) ==
                      (source, method, target) and math.isfinite(row["metrics"][metric])]
            spread = f" ± {statistics.stdev(values):.3f}" if len(values) > 1 else ""
            cells.append(f"{statistics.fmean(values):.3f}{spread}" if values else "-")
        lines.append(cells)
    widths = [max(len(line[i]) for line in [header, *lines]) for i in range(len(header))]

    def text(cells: Sequence[str]) -> str:
        return "| " + " | ".join([cells[0].ljust(widths[0]), *(c.rjust(w) for c, w in zip(
            cells[1:], widths[1:], strict=True))]) + " |"

    rule = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([text(header), rule, *(text(line) for line in lines)])


def main(argv: list[str] | None = None) -> int:
    from defocus.errors import script_errors

    with script_errors():
        return _main(argv)


def _main(argv: list[str] | None) -> int:
    from defocus.app.experiment import plan_json_option, truncation_warning_once
    from defocus.app.outputs import write_json

    args = parser().parse_args(argv)
    plan = plan_json_option(args.json, args.overwrite, args.root)
    if args.threads:
        torch.set_num_threads(args.threads)
    truncation_warning_once()
    size = SIZES["quick" if args.quick else "default"]
    wanted = list(dict.fromkeys([*args.sources, *args.targets]))
    if args.root is None and "dslr" in wanted:
        print("no --root: the DSLR set is left out (give --root the release's dfd_indoor "
              "folder)")
        wanted.remove("dslr")
    sets = {name: load_source(name, args, size) for name in wanted}
    sources = [name for name in args.sources if name in sets]
    targets = [name for name in args.targets if name in sets]
    if not sources or not targets:
        raise SystemExit("no source or no target left to run")
    for name, data in sets.items():
        print(f"{name} ({DATASETS[name][1]}): {len(data.train)} training and {len(data.test)} "
              f"scored scenes, depth {data.depth_range[0]:g}-{data.depth_range[1]:g} m")
    rows = []
    for name in sources:
        rows += run_source(args, sets[name], {t: sets[t] for t in targets}, size)
    print(f"\nscored on each target (columns) with the source's camera; seeds {args.seeds}; "
          "rows: source / method (input, supervision):")
    for metric in SHOWN:
        print(f"\n{matrix(rows, metric, targets)}")
    if plan is not None:
        write_json(plan, args.json, {
            "sources": sources, "targets": targets, "seeds": args.seeds,
            "cameras": {name: describe_camera_of(sets[name]) for name in sources},
            "rows": rows})
        print(f"rows -> {args.json}")
    return 0


def describe_camera_of(source: Source) -> str:
    """The source's camera in a few words."""
    from models.depth_from_photos.trained_network import camera_record, describe_camera

    return describe_camera(camera_record(source.camera))


if __name__ == "__main__":
    sys.exit(main())
