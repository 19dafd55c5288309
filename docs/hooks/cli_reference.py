"""MkDocs hook: the CLI reference page (`cli.md`), generated from the argparse parser at build time.

Nothing of it is kept by hand: `defocus.cli.build_parser()` is walked and, for `defocus` and
every subcommand, the page gets its description, usage, every option with its help, default and
choices, and the epilog (e.g. the TrainConfig fields of `defocus train`).

Enabled in mkdocs.yml with `hooks: [docs/hooks/cli_reference.py]`; `cli_reference_markdown()`
is also what `tests/test_docs.py` checks.
"""

from __future__ import annotations

import argparse
import html
import os
import sys
from pathlib import Path

#: Path of the generated page inside the docs folder (the nav points at it).
PAGE = "cli.md"
#: Usage lines are wrapped at this width, whatever the terminal of the build.
WIDTH = "100"

_ROOT = Path(__file__).resolve().parents[2]


def _parser() -> argparse.ArgumentParser:
    if str(_ROOT) not in sys.path:
        sys.path.insert(0, str(_ROOT))
    from defocus.cli import build_parser

    return build_parser()


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Name -> parser of every subcommand of `parser` (registration order)."""
    return dict(getattr(parser, "commands", {}))


def _cell(text: str) -> str:
    """Plain help text made safe for one Markdown table cell."""
    text = html.escape(" ".join(str(text).split()), quote=False)
    return text.replace("|", "\\|").replace("$", "&#36;").replace("*", "\\*")


def _code(text: str) -> str:
    text = " ".join(str(text).split()).replace("|", "\\|")
    return f"`` {text} ``" if "`" in text else f"`{text}`"


def _default(action: argparse.Action) -> str:
    if action.default is argparse.SUPPRESS or action.dest == "help":
        return ""
    if action.default is None:
        return "none" if action.option_strings else "required"
    value = action.default
    if isinstance(value, Path):
        value = str(value)
    if isinstance(value, (list, tuple)):
        return _code(" ".join(str(v) for v in value)) if value else "empty"
    return _code(value)


def _help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    if not action.help or action.help is argparse.SUPPRESS:
        return ""
    try:  # expands %(default)s, %(prog)s, ... (a plain formatter: defaults have their column)
        text = argparse.HelpFormatter(parser.prog)._expand_help(action)
    except (KeyError, TypeError, ValueError):
        text = action.help
    return _cell(text)


def _name(action: argparse.Action) -> str:
    if action.option_strings:
        metavar = ""
        if action.nargs != 0:
            formatter = argparse.HelpFormatter("defocus")
            metavar = " " + formatter._format_args(action, action.dest.upper())
        return ", ".join(_code(o + metavar) for o in action.option_strings)
    return _code(action.metavar or action.dest)


def _section(title: str, parser: argparse.ArgumentParser, level: int) -> list[str]:
    lines = [f"{'#' * level} `{title}`", ""]
    if parser.description:
        lines += [_cell(parser.description), ""]
    lines += ["```text", parser.format_usage().strip(), "```", ""]
    actions = list(parser.arguments)
    if actions:
        lines += ["| option | description | default | choices |", "|---|---|---|---|"]
        for action in actions:
            choices = ", ".join(_code(c) for c in action.choices) if action.choices else ""
            lines.append(
                f"| {_name(action)} | {_help(parser, action)} | {_default(action)} | {choices} |"
            )
        lines.append("")
    if parser.epilog:
        lines += ["```text", parser.epilog.strip("\n"), "```", ""]
    return lines


def cli_reference_markdown(parser: argparse.ArgumentParser | None = None) -> str:
    """The Markdown of the CLI reference page for `parser` (by default `defocus`'s)."""
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = WIDTH
    try:
        parser = parser or _parser()
        commands = subcommands(parser)
        lines = [
            "# Command line",
            "",
            "<!-- Generated at build time by docs/hooks/cli_reference.py from "
            "defocus.cli.build_parser(); do not edit. -->",
            "",
            "Installing the package puts the `defocus` command on the `PATH` "
            f"(also `python -m defocus.cli`). It has {len(commands)} subcommands; "
            "`defocus COMMAND --help` prints the same information as this page. "
            "Lengths are in metres.",
            "",
            "| command | what it does |",
            "|---|---|",
        ]
        for name, sub in commands.items():
            lines.append(f"| [`{name}`](#defocus-{name}) | {_cell(sub.description or '')} |")
        lines.append("")
        lines += _section(parser.prog, parser, 2)
        for sub in commands.values():
            lines += _section(sub.prog, sub, 2)
        return "\n".join(lines)
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


def on_files(files, config):
    """Add the generated page to the site's files (before the nav is built)."""
    from mkdocs.structure.files import File

    existing = files.get_file_from_path(PAGE)
    if existing is not None:
        files.remove(existing)
    files.append(File.generated(config, PAGE, content=cli_reference_markdown()))
    return files
