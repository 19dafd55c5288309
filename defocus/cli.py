"""The ``defocus`` command line. Each subcommand lives in its own module, imported on use.

A subcommand module defines ``add_arguments(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from defocus import __version__

#: subcommand -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("defocus.commands.demo", "the main job on the embedded default data (README)"),
    "render": ("defocus.commands.render", "render a focus sweep of a real scene and save a figure"),
    "calibrate": ("defocus.commands.calibrate", "fit a camera from raw photo pairs (sharp, defocused)"),
    "train": ("defocus.commands.train", "train a depth network (config YAML + key=value overrides)"),
    "evaluate": ("defocus.commands.evaluate", "depth metrics of a checkpoint on a dataset"),
    "predict": ("defocus.commands.predict", "depth of your own photos with a checkpoint"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="defocus",
        description="Differentiable optics and depth from defocus. Lengths are in metres.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        command = sub.add_parser(
            name,
            help=help_text,
            description=help_text,
            formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        )
        importlib.import_module(module).add_arguments(command)
        command.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(importlib.import_module(args._module).run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
