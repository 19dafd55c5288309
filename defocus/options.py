"""Option groups shared by the subcommands and the example scripts, and the help formatter.

Each `add_*` function adds one group of options to an `argparse` parser; the subcommands
(`defocus.commands`) and the scripts under `examples/` build their parsers from these, so an
option is spelled, checked and documented in one place.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from datasets.registry import DATASET_NAMES

#: Label-free methods (`models.depth_from_photos.METHODS`, listed here so that the help is
#: built without importing the models) and "auto".
METHOD_NAMES = ("auto", "sweep", "relative-blur", "focus")


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


def show_progress(args: argparse.Namespace) -> bool:
    """Progress bars: on a terminal unless `--quiet`; anywhere with `--progress`."""
    from optics.progress import writes_to_terminal

    return bool(getattr(args, "progress", False)) or (
        writes_to_terminal() and not getattr(args, "quiet", False))


def add_overwrite_argument(parser: argparse.ArgumentParser) -> None:
    """`--overwrite`: replace the results of an earlier run (the output policy,
    `defocus.app.outputs`: without it an existing output file is refused; inputs are never
    written, with or without it)."""
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the files of an earlier run (without it an existing output "
                             "file is refused; an input is never written)")


def add_data_arguments(
    parser: argparse.ArgumentParser, extra_choices: tuple[str, ...] = (), default: str = "synthetic"
) -> None:
    """`--data`, `--root`, `--split`, `--size`, `--scenes`, `--data-seed`: the dataset a
    command trains or evaluates on (`dataset_from_options` builds it)."""
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
        default=None,
        metavar=("H", "W"),
        help="image size in pixels: the synthetic scenes' (48 48 unless given), a resize of "
        "real photos (default: their own size)",
    )
    parser.add_argument(
        "--scenes", type=int, default=256, help="number of synthetic scenes (--data synthetic)"
    )
    parser.add_argument("--data-seed", type=int, default=0, help="seed of the synthetic scenes")


def dataset_from_options(args: argparse.Namespace, split: str | None = None,
                         seed_offset: int = 0):
    """The dataset selected by `add_data_arguments`' options (`split` overrides `--split`)."""
    from datasets.registry import build_dataset

    size = tuple(args.size) if args.size else (48, 48) if args.data == "synthetic" else None
    return build_dataset(args.data, args.root, split=split or args.split, size=size,
                         scenes=args.scenes, seed=args.data_seed + seed_offset)


def _new_parser(description: str) -> argparse.ArgumentParser:
    return argparse.ArgumentParser(
        description=description, formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        allow_abbrev=False)


def add_machine_arguments(parser: argparse.ArgumentParser) -> None:
    """`--device` and `--threads`: where the work runs."""
    parser.add_argument("--device", default="auto",
                        help="'auto' (CUDA when available), 'cpu', 'cuda', 'cuda:1', ...")
    parser.add_argument("--threads", type=int, default=0,
                        help="CPU threads of PyTorch (0: its default, one per core; on a "
                             "machine shared with other jobs 1 wastes less time waiting)")


def add_training_arguments(parser: argparse.ArgumentParser, out: str) -> None:
    """The training knobs of the example scripts (`defocus.app.experiment.run_example`)."""
    parser.add_argument("--steps", type=int, default=None,
                        help="training steps (default: CPU as many as fit in --minutes, GPU 20000)")
    parser.add_argument("--minutes", type=float, default=None,
                        help="time budget of training + evaluation (default: CPU 10, GPU none)")
    parser.add_argument("--max-epochs", type=float, default=200.0,
                        help="with --minutes: at most this many passes over the training pixels")
    parser.add_argument("--batch-size", type=int, default=8, help="samples per step")
    parser.add_argument("--crop", type=int, nargs="+", metavar="PX", default=None,
                        help="train on random H [W] crops of the full-resolution samples "
                             "(default: CPU 128, GPU 256; 0: whole images)")
    parser.add_argument("--depth-range", type=float, nargs=2, metavar=("MIN", "MAX"), default=None,
                        help="depths the network can output, metres (default: the dataset's)")
    parser.add_argument("--depth-spacing", choices=["depth", "inverse"], default="depth",
                        help="space the network's output evenly in depth or in inverse depth")
    parser.add_argument("--side", choices=["both", "beyond", "before"], default="both",
                        help="a prior on the side of the focus plane (one focus setting): where "
                             "the self-supervised network puts a blur both sides explain; a blur "
                             "above the far side's bound is put near either way")
    parser.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate")
    parser.add_argument("--smoothness-weight", type=float, default=0.001,
                        help="weight of the self-supervised loss's edge-aware depth smoothness "
                             "(the paper: 0.001)")
    parser.add_argument("--network", choices=["small", "paper"], default="small",
                        help="depth network (the paper's is large; use a GPU)")
    parser.add_argument("--width", type=int, default=32, help="channel width of the small network")
    parser.add_argument("--input-mode", choices=["aif+focused", "aif"], default="aif+focused",
                        help="network input: the all-in-focus image, optionally with the focused ones")
    parser.add_argument("--out", type=Path, default=Path(out), help="run folder (logs, checkpoints)")
    parser.add_argument("--seed", type=int, default=0, help="random seed")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    parser.add_argument("--workers", type=int, default=-1,
                        help="processes preparing batches ahead of the step (-1: up to 4 on a "
                             "GPU, none on a small CPU machine)")
    parser.add_argument("--precision", choices=["float32", "bfloat16"], default="float32",
                        help="the network's arithmetic (bfloat16: autocast; the renderer and "
                             "the loss stay float32)")
    parser.add_argument("--compile", action="store_true", help="torch.compile the network")


def add_sample_arguments(parser: argparse.ArgumentParser) -> None:
    """How the example scripts read and cache a dataset's samples."""
    parser.add_argument("--size", type=int, nargs=2, metavar=("H", "W"), default=None,
                        help="resize whole images to H x W pixels first (the pixel pitch follows, "
                             "so the blur in pixels shrinks too; prefer --crop)")
    parser.add_argument("--max-train", type=int, default=None, help="use at most this many training samples")
    parser.add_argument("--max-test", type=int, default=None, help="evaluate on at most this many samples")
    parser.add_argument("--cache-dir", type=Path, default=None,
                        help="keep synthesised focal stacks here (default: the per-user cache)")
    parser.add_argument("--no-cache", action="store_true",
                        help="keep no synthesised focal stacks on disk")
    parser.add_argument("--memory-cache-mb", type=float, default=2048,
                        help="keep up to this many MiB of full-resolution samples in memory")


def example_parser(description: str, out: str) -> argparse.ArgumentParser:
    """The parser of an example script that trains and evaluates on a dataset under `--root`."""
    parser = _new_parser(description)
    parser.add_argument("--root", type=Path, required=True, help="dataset folder (see the header)")
    add_machine_arguments(parser)
    add_training_arguments(parser, out)
    add_sample_arguments(parser)
    return parser


def benchmark_parser(description: str, split: str | None) -> argparse.ArgumentParser:
    """The parser of an example script that scores a label-free method on a focal-stack
    benchmark under `--root` (`defocus.app.experiment.run_benchmark_example`)."""
    parser = _new_parser(description)
    parser.add_argument("--root", type=Path, required=True, help="dataset folder (see the header)")
    if split is not None:
        parser.add_argument("--split", default=split, help="the split to score")
    add_machine_arguments(parser)
    parser.add_argument("--method", choices=list(METHOD_NAMES), default="auto",
                        help="label-free method (auto: the sweep with an all-in-focus photo, "
                             "the relative blur without)")
    parser.add_argument("--max-samples", type=int, default=None,
                        help="score at most this many samples (default: CPU 8, GPU all)")
    parser.add_argument("--max-pixels", type=int, default=None,
                        help="most pixels of the method's working resolution (default: CPU "
                             "250000, GPU 1500000); metrics use the native resolution")
    add_json_argument(parser, "also write the metrics here")
    return parser


def add_json_argument(parser: argparse.ArgumentParser, text: str) -> None:
    """`--json PATH` and `--overwrite` of an example script: the JSON goes through the output
    policy (`defocus.app.experiment.plan_json_option`): an existing file is replaced only
    with `--overwrite`, an input is never written, and it is written whole or not at all."""
    parser.add_argument("--json", type=Path, default=None, metavar="PATH",
                        help=f"{text} (an existing file is replaced only with --overwrite)")
    add_overwrite_argument(parser)


#: Defaults per device kind of the training examples: crop side (pixels), steps, time budget
#: (minutes).
DEVICE_DEFAULTS = {"cpu": {"crop": 128, "steps": None, "minutes": 10.0},
                   "cuda": {"crop": 256, "steps": 20000, "minutes": None}}
#: Defaults per device kind of the benchmark examples: samples scored, working pixels.
BENCHMARK_DEFAULTS = {"cpu": {"max_samples": 8, "max_pixels": 250_000},
                      "cuda": {"max_samples": None, "max_pixels": 1_500_000}}


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
