"""`defocus train`: train a depth network from a YAML config plus `key=value` overrides."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from defocus.app.train import check_learned_optics, check_out_dir, config_fields_help
from defocus.options import DefaultsOnceFormatter, add_data_arguments, dataset_from_options, say


class _HelpFormatter(DefaultsOnceFormatter, argparse.RawDescriptionHelpFormatter):
    """Defaults after each option (once); the epilog (the config fields) kept line by line."""


def demo_training_help() -> str:
    """What `defocus demo` trains with, as `defocus train` options: the defaults of `train` are
    `TrainConfig`'s, not the demo's.

    Example:
        >>> "steps=500" in demo_training_help()
        True
    """
    import inspect

    from datasets.synthetic import SYNTHETIC_PRESET as preset
    from defocus.app.demo import run_demo

    ran = argparse.Namespace(**{name: parameter.default for name, parameter
                                in inspect.signature(run_demo).parameters.items()})
    focus = " and ".join(f"{distance:g}" for distance in preset.focus_distances)
    return (f"Its defaults are TrainConfig's own (below). `defocus demo` trains the small network "
            f"with\n  --set steps={ran.steps} batch_size={ran.batch_size} lr={ran.lr:g} "
            f"width={ran.width} smoothness_weight={ran.smoothness_weight:g} "
            f"input_mode=aif+focused\n  depth_min={preset.min_depth:g} "
            f"depth_max={preset.depth_cap:g} --scenes {ran.scenes} --size {ran.size} {ran.size}"
            f"\non the synthetic scenes ({preset.focal_length * 1000:g} mm "
            f"f/{float(preset.camera.f_number.reshape(-1)[0]):g}, focused at {focus} m).")


def add_arguments(parser: argparse.ArgumentParser, focus: bool = True) -> None:
    """`defocus train`'s options; `focus=False` leaves out `--focus` (an example script's
    recipe says how its data is read)."""
    parser.formatter_class = _HelpFormatter
    parser.epilog = config_fields_help()
    parser.description = f"{parser.description}.\n{demo_training_help()}" \
        if parser.description else demo_training_help()
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
    if focus:  # not for an example script (its recipe says these, and it evaluates on its data)
        parser.add_argument(
            "--learn-optics", default=None, metavar="WHAT",
            help="learn the camera with the network: any of focus, f-number, mask joined by "
            "commas (learn_optics); the focused images of each batch are rendered from the "
            "all-in-focus image and depth through the learned camera, so the data's focused "
            "images must be synthesised (--data synthetic, --focus synthesized), not real "
            "photos. The camera is saved in the checkpoint and as camera.json, mask.png and "
            "optics.png in the run folder")
        parser.add_argument(
            "--optics-lr", type=float, default=None, metavar="LR",
            help="learning rate of the learned optics (optics_lr; default 0.01; 0: the "
                 "starting camera rendered the same way, noise included, and not learned)")
        parser.add_argument(
            "--minutes", type=float, default=None,
            help="time budget of the training, minutes (minutes; default: none): it stops "
            "after the step that spends it and saves a checkpoint, as at the end")
    add_data_arguments(parser, focus=focus)


def recipe_parser(recipe: Path) -> argparse.ArgumentParser:
    """The parser of an example script: `defocus train`'s options (`--config` is the recipe
    `recipe`, `--set` changes its keys and the `TrainConfig` fields), no other vocabulary."""
    text = recipe.read_text(encoding="utf-8")
    parser = argparse.ArgumentParser(prog=f"{recipe.stem}.py", allow_abbrev=False)
    add_arguments(parser, focus=False)
    parser.description = text.splitlines()[0].lstrip("# ")  # the recipe's, not the demo's
    parser.epilog = f"The recipe {recipe.name} (--set KEY=VALUE changes a key):\n{text}\n" \
        f"{parser.epilog}"
    parser.set_defaults(config=recipe)
    return parser


def recipe_main(recipe: Path, argv: list[str] | None = None) -> None:
    """Run an example script: its recipe with `defocus train`'s options `argv`
    (`defocus.app.experiment.run_recipe`); bad input ends it in one line."""
    from defocus.app import request_from
    from defocus.app.experiment import ScriptRequest, run_recipe
    from defocus.errors import script_errors

    args = recipe_parser(recipe).parse_args(argv)
    with script_errors():
        run_recipe(request_from(ScriptRequest, args))


def run(args: argparse.Namespace) -> int:
    from defocus.app.train import train, training_config
    from models.metrics import format_table

    cfg = training_config(args.config, args.overrides, args.out, args.resume, args.overwrite,
                          minutes=args.minutes, learn_optics=args.learn_optics,
                          optics_lr=args.optics_lr)
    # before any data is read: a file, the dataset folder or a link is no run folder
    check_out_dir(cfg.out_dir, args.root, args.config, args.overwrite)
    check_learned_optics(cfg.learn_optics, args.data, args.focus)
    validation = None
    if args.data == "synthetic":
        def validation():
            val = dataset_from_options(args, seed_offset=1_000)
            val.num_scenes = min(len(val), 16)
            return val
    if args.quiet:
        cfg = dataclasses.replace(cfg, progress=False)
    # n_focus 0 (the default) follows the data: the trainer reads the first sample once
    result = train(cfg, dataset_from_options(args), validation, report=say(args))
    trainer = result.trainer
    if trainer.is_main:
        last = f"; last loss {trainer.history[-1]['loss']:.4f}" if trainer.history else ""
        print(f"trained {trainer.step} steps{last}; checkpoint {trainer.checkpoints.last}")
        if trainer.step_timer.split():
            print(f"a training step's time: {trainer.step_timer.summary()}")
        if result.metrics is not None:
            print(format_table({"synthetic validation": result.metrics}))
        for message in result.warnings:
            print(f"warning: {message}")
    return 0
