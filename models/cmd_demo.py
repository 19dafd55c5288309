"""``defocus demo``: the README's main job.

Until training lands it renders the focus sweep of the real motorcycle scene.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from . import cmd_render


def add_arguments(parser: argparse.ArgumentParser) -> None:
    cmd_render.add_arguments(parser)
    parser.set_defaults(out=Path("runs/demo"))


def run(args: argparse.Namespace) -> int:
    return cmd_render.run(args)
