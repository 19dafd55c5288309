"""The `defocus` command line. Each subcommand lives in its own module, imported on use.

A subcommand module (`defocus.commands.NAME`) defines `add_arguments(parser)` and
`run(args) -> int`; it parses arguments and calls the library, nothing else.

Errors: a bad value, a missing file or a refused input ends the command with one line on stderr,
`defocus COMMAND: error: MESSAGE`, and exit code 2, as argparse does for bad options. The
traceback is shown with `--debug` or the environment variable `DEFOCUS_DEBUG=1`. Any other
exception is also one line (exit code 1) that says it is unexpected. Ctrl-C (SIGINT) or SIGTERM
ends a command with one line and exit code 130 or 143 (`defocus train` saves a checkpoint
first).
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys

from defocus import __version__
from defocus.errors import USER_ERRORS, one_line
from defocus.options import DefaultsOnceFormatter

#: subcommand -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("defocus.commands.demo", "the main job on the embedded default data (README)"),
    "render": ("defocus.commands.render", "render a focus sweep of a real scene and save a figure"),
    "calibrate": ("defocus.commands.calibrate", "fit a camera from raw photo pairs (sharp, defocused)"),
    "train": ("defocus.commands.train", "train a depth network (config YAML + key=value overrides)"),
    "evaluate": ("defocus.commands.evaluate", "depth metrics of a checkpoint on a dataset"),
    "predict": ("defocus.commands.predict", "depth of your own photos (no network needed)"),
    "convert-checkpoint": ("defocus.commands.convert_checkpoint",
                           "rewrite a trusted old checkpoint so that it opens without running code"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="defocus",
        description="Differentiable optics and depth from defocus. Lengths are in metres.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show the full traceback of an error (also DEFOCUS_DEBUG=1)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        command = sub.add_parser(
            name,
            help=help_text,
            description=help_text,
            formatter_class=DefaultsOnceFormatter,
        )
        importlib.import_module(module).add_arguments(command)
        command.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    debug = args.debug or os.environ.get("DEFOCUS_DEBUG", "") not in ("", "0")
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except KeyboardInterrupt as error:  # also models.training.TrainingInterrupted
        if debug:
            raise
        signum = getattr(error, "signal", signal.SIGINT)
        print(f"defocus {args.command}: interrupted: {one_line(error) or 'stopped'}",
              file=sys.stderr)
        return 128 + int(signum)
    except USER_ERRORS as error:
        if debug:
            raise
        message = one_line(error) or repr(error)
        print(f"defocus {args.command}: error: {message}", file=sys.stderr)
        return 2
    except Exception as error:
        if debug:
            raise
        print(f"defocus {args.command}: error: unexpected {type(error).__name__}: "
              f"{one_line(error)} (rerun with --debug for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
