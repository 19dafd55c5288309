"""Option groups shared by the subcommands, and the help formatter.

Each `add_*` function adds one group of options to an `argparse` parser; the subcommands
(`defocus.commands`) build their parsers from these, and the scripts under `examples/` take
the subcommands' own options (`defocus.commands.train.recipe_parser`,
`defocus.commands.evaluate.benchmark_parser`), so an option is spelled, checked and documented
in one place.
"""

from __future__ import annotations

import argparse
from pathlib import Path

#: Label-free methods (`models.depth_from_photos.METHODS`, listed here so that the help is
#: built without importing the models) and "auto".
METHOD_NAMES = ("auto", "sweep", "relative-blur", "focus")
#: How a dataset's focused images come (`datasets.registry.FOCUS`; `--focus`).
FOCUS_MODES = ("real", "synthesized")


class DefaultsOnceFormatter(argparse.HelpFormatter):
    """Help that ends each option with its default once: not where the help text already says
    what the default is, and not for defaults that mean "not given" (None, an empty list, an
    unset flag)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        unset = action.default is None or action.default is False or action.default == [] \
            or action.default is argparse.SUPPRESS
        if unset or "default" in text.lower() or not (action.option_strings or action.nargs
                                                      in (argparse.OPTIONAL, argparse.ZERO_OR_MORE)):
            return text
        return f"{text} (default: %(default)s)"


def aperture_argument(text: str) -> str:
    """An argparse type: a PSF spec of `optics.aperture_spec` (checked, returned as written).

    Example:
        >>> aperture_argument("polygon:6")
        'polygon:6'
    """
    from optics import parse_aperture

    try:
        parse_aperture(text)
    except (TypeError, ValueError) as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


#: The largest value a camera option takes (metres, f-numbers): far beyond any lens, and small
#: enough that float32 arithmetic on it stays finite.
MAX_OPTION_VALUE = 1e9


def check_positive(args: argparse.Namespace, *names: str) -> None:
    """Refuse option values that are not finite numbers > 0 (at most `MAX_OPTION_VALUE`),
    naming the option as typed (`--f-number -8.3: must be a finite number > 0`); `names` are
    `args` attributes, unset
    (None, empty) ones are skipped. `args` is any object with those attributes (a parsed
    command line, `defocus.app.predict.PredictRequest`).

    Example:
        >>> check_positive(argparse.Namespace(f_number=[-8.3]), "f_number")
        Traceback (most recent call last):
        ...
        ValueError: --f-number -8.3: must be a finite number > 0
    """
    for name in names:
        value = getattr(args, name)
        values = value if isinstance(value, (list, tuple)) else [value]
        for item in values:
            if item is not None and not 0 < item <= MAX_OPTION_VALUE:
                option = "--" + name.replace("_", "-")
                largest = f" and at most {MAX_OPTION_VALUE:g}" \
                    if MAX_OPTION_VALUE < item < float("inf") else ""
                raise ValueError(f"{option} {item:g}: must be a finite number > 0{largest}")


def say(args: argparse.Namespace):
    """The `report` callback of a command: `print` (flushed, so that progress lines show at once
    in a log), or nothing with `--quiet`."""
    if getattr(args, "quiet", False):
        return lambda text: None
    return lambda text: print(text, flush=True)


def add_overwrite_argument(parser: argparse.ArgumentParser) -> None:
    """`--overwrite`: replace the results of an earlier run (the output policy,
    `defocus.app.outputs`: without it an existing output file is refused; inputs are never
    written, with or without it)."""
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the files of an earlier run (without it an existing output "
                             "file is refused; an input is never written)")


def add_data_arguments(
    parser: argparse.ArgumentParser, extra_choices: tuple[str, ...] = (), default: str = "synthetic",
    data_help: str = "", focus: bool = True,
) -> None:
    """`--data`, `--root`, `--split`, `--size`, `--scenes`, `--data-seed` and (with `focus`)
    `--focus`: the dataset a command trains or evaluates on (`dataset_from_options` builds
    it); `data_help` ends the help of `--data`."""
    from datasets.registry import DATASET_NAMES

    parser.add_argument(
        "--data",
        choices=sorted([*DATASET_NAMES, *extra_choices]),
        default=default,
        help="dataset: synthetic scenes (embedded), "
        + ("the real motorcycle scene, " if "motorcycle" in extra_choices else "")
        + "or a real-format folder given by --root" + data_help,
    )
    parser.add_argument(
        "--root", type=Path, default=None, help="dataset folder (all but --data synthetic)"
    )
    parser.add_argument("--split", default="train", help="dataset split (folder datasets)")
    parser.add_argument(
        "--size",
        type=int,
        nargs=2,
        default=None,
        metavar=("H", "W"),
        help="image size in pixels: the synthetic scenes' (48 48 unless given), a resize of "
        "real photos (default: their own size)",
    )
    parser.add_argument(
        "--scenes", type=int, default=256, help="number of synthetic scenes (--data synthetic)"
    )
    parser.add_argument("--data-seed", type=int, default=0, help="seed of the synthetic scenes")
    if focus:
        parser.add_argument(
            "--focus", choices=FOCUS_MODES, default=None,
            help="the focused images: the real photos, or synthesised the paper's way from the "
            "all-in-focus image and the depth (--data dslr: the f/8 photo and its depth, "
            "rendered at 0.2 and 0.8 of the 10 m depth cap). Default: the dataset's own (dslr: "
            "real; rgbd, nyu, middlebury, ...: synthesized; folder: real)")


def dataset_from_options(args: argparse.Namespace, split: str | None = None,
                         seed_offset: int = 0):
    """The dataset selected by `add_data_arguments`' options (`split` overrides `--split`)."""
    from datasets.registry import build_dataset

    size = tuple(args.size) if args.size else (48, 48) if args.data == "synthetic" else None
    return build_dataset(args.data, args.root, split=split or args.split, size=size,
                         scenes=args.scenes, seed=args.data_seed + seed_offset,
                         focus=getattr(args, "focus", None))


def device_kind(name: str) -> str:
    """`"cuda"` or `"cpu"` for a `--device` value (`"auto"`: CUDA when available).

    Example:
        >>> device_kind("cpu")
        'cpu'
    """
    import torch

    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    try:
        return "cuda" if torch.device(name).type == "cuda" else "cpu"
    except RuntimeError:
        raise SystemExit(f"--device must be 'auto', 'cpu' or 'cuda[:N]', got {name!r}") from None
