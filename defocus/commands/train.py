"""`defocus train`: train a depth network from a YAML config plus `key=value` overrides."""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

from datasets.registry import DATASET_NAMES
from defocus.cli import DefaultsOnceFormatter


def config_fields_help() -> str:
    """One line per `TrainConfig` field: name, default and the `#:`
    comment above it in the source (where the units are written)."""
    import dataclasses
    import inspect

    from models.training import TrainConfig

    comments: dict[str, str] = {}
    pending: list[str] = []
    for line in inspect.getsource(TrainConfig).splitlines():
        stripped = line.strip()
        if stripped.startswith("#:"):
            pending.append(stripped[2:].strip())
        elif pending and ":" in stripped:
            comments[stripped.split(":", 1)[0].strip()] = " ".join(pending)
            pending = []
    lines = ["TrainConfig fields (--config YAML keys and --set KEY=VALUE):"]
    for field in dataclasses.fields(TrainConfig):
        if field.default is not dataclasses.MISSING:
            default = field.default
        elif field.default_factory is not dataclasses.MISSING:
            default = field.default_factory()
        else:
            default = "(required)"
        lines.append(f"  {field.name} = {default!s}: {comments.get(field.name, '')}")
    return "\n".join(lines)


class _HelpFormatter(DefaultsOnceFormatter, argparse.RawDescriptionHelpFormatter):
    """Defaults after each option (once); the epilog (the config fields) kept line by line."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = _HelpFormatter
    parser.epilog = config_fields_help()
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="YAML file of TrainConfig fields (see the training tutorial)",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="config overrides, e.g. steps=500 lr=3e-4 input_mode=aif "
        "depth_min=1.5 depth_max=7 (depths in metres)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (logs, checkpoints, figures); overrides out_dir. A folder that "
        "holds another run (another config) is refused unless --resume or --overwrite",
    )
    existing = parser.add_mutually_exclusive_group()
    existing.add_argument(
        "--resume", action="store_true",
        help="continue the run in the output folder (also to a larger steps); refused if its "
        "config differs in anything else (resume=resume). Without --resume or --overwrite the "
        "run continues only when the config is the same (resume=auto)",
    )
    existing.add_argument(
        "--overwrite", action="store_true",
        help="start over: delete the output folder's previous run (config, logs, checkpoints, "
        "figures; other files stay) when training starts (resume=overwrite)",
    )
    add_data_arguments(parser)


def add_data_arguments(
    parser: argparse.ArgumentParser, extra_choices: tuple[str, ...] = (), default: str = "synthetic"
) -> None:
    parser.add_argument(
        "--data",
        choices=sorted([*DATASET_NAMES, *extra_choices]),
        default=default,
        help="dataset: synthetic scenes (embedded), the real motorcycle scene "
        "(evaluate) or a real-format folder given by --root",
    )
    parser.add_argument(
        "--root", type=Path, default=None, help="dataset folder (all but --data synthetic)"
    )
    parser.add_argument("--split", default="train", help="dataset split (folder datasets)")
    parser.add_argument(
        "--size",
        type=int,
        nargs=2,
        default=[48, 48],
        metavar=("H", "W"),
        help="image size in pixels (synthetic scenes; resize of real datasets)",
    )
    parser.add_argument(
        "--scenes", type=int, default=256, help="number of synthetic scenes (--data synthetic)"
    )
    parser.add_argument("--data-seed", type=int, default=0, help="seed of the synthetic scenes")


def build_dataset(args: argparse.Namespace, split: str | None = None, seed_offset: int = 0):
    """The dataset selected by `--data` (`split` overrides `--split`)."""
    from datasets.registry import build_dataset as build

    return build(args.data, args.root, split=split or args.split, size=tuple(args.size),
                 scenes=args.scenes, seed=args.data_seed + seed_offset)


def run(args: argparse.Namespace) -> int:
    from models.metrics import format_table
    from models.training import COLLAPSE_FRACTION, DepthCollapseWarning, TrainConfig, Trainer

    if args.config is not None and not args.config.is_file():
        raise FileNotFoundError(f"--config {args.config} does not exist or is not a file")
    cfg = TrainConfig.from_yaml(args.config) if args.config else TrainConfig()
    overrides = list(args.overrides) + ([f"out_dir={args.out}"] if args.out else [])
    if args.resume or args.overwrite:
        overrides.append(f"resume={'resume' if args.resume else 'overwrite'}")
    cfg = cfg.override(overrides)
    warnings.simplefilter("ignore", DepthCollapseWarning)  # printed in the summary instead
    trainer = Trainer(cfg, build_dataset(args))
    if trainer.is_main and trainer.resumed_from is not None:
        print(f"continuing the run in {cfg.out_dir} from step {trainer.step} of {cfg.steps}")
    trainer.fit()
    if trainer.is_main:
        last = f"; last loss {trainer.history[-1]['loss']:.4f}" if trainer.history else ""
        print(f"trained {trainer.step} steps{last}; checkpoint {trainer.checkpoints.last}")
        if args.data == "synthetic":
            val = build_dataset(args, seed_offset=1_000)
            val.num_scenes = min(len(val), 16)
            metrics = trainer.evaluate(val)
            print(format_table({"synthetic validation": metrics}))
            if metrics["at_depth_limits"] >= COLLAPSE_FRACTION:
                trainer.warnings.append(
                    f"{metrics['at_depth_limits']:.0%} of the predicted validation pixels sit at "
                    f"depth_min or depth_max: the network collapsed to its depth limits (often a "
                    f"too large lr, here {cfg.lr})")
        for message in dict.fromkeys(trainer.warnings):
            print(f"warning: {message}")
    return 0
