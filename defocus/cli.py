"""The `defocus` command line. Each subcommand lives in its own module, imported on use.

A subcommand module (`defocus.commands.NAME`) defines `add_arguments(parser)` and
`run(args) -> int`; it parses arguments, builds the workflow's request (`defocus.app`), calls it
and prints. Only the chosen subcommand's module is imported and its parser built: `defocus
--help` lists every command from `COMMANDS` alone, and `defocus predict --help` imports no
training code.

Errors: a bad value, a missing file, a refused input or a mistyped command line ends the command
with one line on stderr, `defocus COMMAND: error: MESSAGE`, and exit code 2 (a mistyped option
is named with the closest one; `--help` shows the usage). The
traceback is shown with `--debug` or the environment variable `DEFOCUS_DEBUG=1`. Any other
exception is also one line (exit code 1) that says it is unexpected. Ctrl-C (SIGINT) or SIGTERM
ends a command with one line and exit code 130 or 143 (`defocus train` saves a checkpoint
first).
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import os
import re
import signal
import sys
import threading
import warnings
from typing import Any

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
    "sample": ("defocus.commands.sample", "write a small set of photos to try the commands on"),
    "convert-checkpoint": ("defocus.commands.convert_checkpoint",
                           "rewrite a trusted old checkpoint so that it opens without running code"),
}

#: `add_argument` actions that may be given more than once: they add up (flags take no value).
_REPEATABLE_ACTIONS = ("append", "append_const", "extend", "count", "help", "version")
#: A word that is a number (`1.5`, `-8.3`, `2e-3`, `inf`): a value, never an option or a file.
_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?|[-+]?(inf|nan)", re.IGNORECASE)


class CommandParser(argparse.ArgumentParser):
    """An `ArgumentParser` that records the arguments added to it (`arguments`, in order;
    `options`: option string -> its action; `repeatable`: the actions that may be given more
    than once), so that the
    command line answers an unknown option with the closest one and refuses an option given
    twice or empty without reading argparse's private state; and that keeps its subcommands'
    parsers by name (`commands`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.arguments: list[argparse.Action] = []
        self.options: dict[str, argparse.Action] = {}
        self.repeatable: set[argparse.Action] = set()
        self.commands: dict[str, CommandParser] = {}
        super().__init__(*args, **kwargs)  # adds --help through add_argument

    def add_argument(self, *args: Any, **kwargs: Any) -> argparse.Action:
        return self._record(super().add_argument(*args, **kwargs), kwargs)

    def add_argument_group(self, *args: Any, **kwargs: Any):  # noqa: ANN201 (argparse's)
        return self._recording(super().add_argument_group(*args, **kwargs))

    def add_mutually_exclusive_group(self, **kwargs: Any):  # noqa: ANN201 (argparse's)
        return self._recording(super().add_mutually_exclusive_group(**kwargs))

    def _recording(self, group):  # noqa: ANN001, ANN202
        """`group` with its `add_argument` recording into this parser too."""
        add = group.add_argument
        group.add_argument = lambda *args, **kwargs: self._record(add(*args, **kwargs), kwargs)
        return group

    def _record(self, action: argparse.Action, kwargs: dict[str, Any]) -> argparse.Action:
        self.arguments.append(action)
        self.options.update(dict.fromkeys(action.option_strings, action))
        if action.nargs == 0 or kwargs.get("action") in _REPEATABLE_ACTIONS:
            self.repeatable.add(action)
        return action

    def error(self, message: str):  # noqa: ANN201 (argparse's signature; it never returns)
        """End with one line, `PROG: error: MESSAGE`, and exit code 2 (no usage block: `--help`
        shows it)."""
        self.exit(2, f"{self.prog}: error: {one_line(message)}\n")


def add_global_options(parser: argparse.ArgumentParser, after_command: bool = False) -> None:
    """`--debug` and `--quiet`, accepted before the subcommand and after it (there, with no
    default of their own, so that one given before the subcommand holds)."""
    default = {"default": argparse.SUPPRESS} if after_command else {}
    parser.add_argument("--debug", action="store_true", **default,
                        help="show the full traceback of an error (also DEFOCUS_DEBUG=1)")
    parser.add_argument("--quiet", action="store_true", **default,
                        help="print only results, warnings and errors: no progress bars or "
                             "progress lines")


def build_parser(only: str | None = None) -> CommandParser:
    """The parser of `defocus`: every subcommand is listed with its one-line help, and the
    options of subcommand `only` (of all of them where None, e.g. for the docs) are added by
    its module's `add_arguments`; `parser.commands` holds the subcommands' parsers by name.

    Example:
        >>> parser = build_parser("sample")
        >>> sorted(parser.commands) == sorted(COMMANDS), "--scale" in parser.commands["sample"].options
        (True, True)
    """
    parser = CommandParser(
        prog="defocus",
        description="Differentiable optics and depth from defocus. Lengths are in metres.",
        allow_abbrev=False,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    add_global_options(parser)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        command = sub.add_parser(name, help=help_text, description=help_text,
                                 formatter_class=DefaultsOnceFormatter, allow_abbrev=False)
        parser.commands[name] = command
        if only is None or name == only:
            importlib.import_module(module).add_arguments(command)
            add_global_options(command, after_command=True)
    return parser


def chosen_command(argv: list[str]) -> str | None:
    """The subcommand `argv` names: its first word that is not an option (the options before
    a subcommand take no value), or None.

    Example:
        >>> chosen_command(["--quiet", "predict", "--image", "aif.png"])
        'predict'
    """
    return next((word for word in argv if not word.startswith("-")), None)


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    """The parsed command line. Refused in one line: an unknown option (before anything is
    parsed, so that its values never become positionals; named with the closest option,
    `closest_options`), a number taken for a positional or left over (a value too many for the
    option before it), an option that takes values given twice or given an empty value."""
    argv = list(sys.argv[1:] if argv is None else argv)
    name = chosen_command(argv)
    parser = build_parser(name or "")
    if name in parser.commands:
        at = argv.index(name)
        for options, words, owner in ((parser.options, argv[:at], parser),
                                      (parser.commands[name].options, argv[at + 1:],
                                       parser.commands[name])):
            problem = _unknown_option(options, words)
            if problem:
                owner.error(problem)
    args, unknown = parser.parse_known_args(argv)
    command = parser.commands[args.command]
    words = argv[argv.index(args.command) + 1:]
    if unknown:
        number = next((word for word in unknown if _NUMBER.fullmatch(word)), None)
        command.error(_stray_number(command, words, number, None) if number is not None
                      else f"unrecognized arguments: {' '.join(unknown)}")
    problem = _number_as_positional(command, args, words) or _repeated_or_empty(command, words)
    if problem:
        command.error(problem)
    return args


def closest_options(word: str, options: list[str]) -> list[str]:
    """The options `word` (an unknown option) most likely means, best first: those whose words
    begin with the typed words (`--focus` -> `--focus-distance`, not `--focused`), then those
    whose words start with them (`--foc` -> `--focused`, `--focus-distance`), then those that
    have words starting with them in order (`--range` -> `--depth-range`), then the longest
    option the word runs on past (`--dataset` -> `--data`), else the closest spelling
    (`--focsed` -> `--focused`); empty where none is close.

    Example:
        >>> closest_options("--focus", ["--focused", "--focus-distance", "--image-focus-distance"])
        ['--focus-distance']
        >>> closest_options("--depth", ["--depth-range", "--out"])
        ['--depth-range']
    """
    typed = word.lstrip("-").partition("=")[0].split("-")
    named = {option: option.lstrip("-").split("-") for option in options
             if option.startswith("--")}

    def in_order(words: list[str]) -> bool:
        rest = iter(words)
        return all(any(have.startswith(want) for have in rest) for want in typed)

    for fits in (lambda words: words[:len(typed)] == typed,
                 lambda words: len(words) >= len(typed)
                 and all(have.startswith(want) for have, want in zip(words, typed, strict=False)),
                 in_order):
        found = [option for option, words in named.items() if fits(words)]
        if found and all(typed):
            return found[:3]
    extended = [option for option in named if word.partition("=")[0].startswith(option)]
    if extended:  # the typed word runs on past an option (`--dataset` -> `--data`)
        return [max(extended, key=len)]
    return difflib.get_close_matches(word.partition("=")[0], list(named), n=1, cutoff=0.75)


def _unknown_option(options: dict[str, argparse.Action], words: list[str]) -> str | None:
    """Why `words` are refused: the first word that is an option none of `options` names (a
    number such as `-8.3` is a value), with the closest options; None where there is none."""
    for word in words:
        if word == "--":
            return None
        if len(word) < 2 or not word.startswith("-") or _NUMBER.fullmatch(word) \
                or word.partition("=")[0] in options:
            continue
        close = closest_options(word, list(options))
        hint = f" (did you mean {' or '.join(close)}?)" if close else ""
        return f"unrecognized option {word.partition('=')[0]}{hint}"
    return None


def _number_as_positional(command: CommandParser, args: argparse.Namespace,
                          words: list[str]) -> str | None:
    """Why a positional (a file, a folder) is refused: it is a number, a value too many for the
    option before it (`--depth-range 1.5 8 9` would make 9 the checkpoint)."""
    for action in command.arguments:
        value = None if action.option_strings else getattr(args, action.dest, None)
        for item in value if isinstance(value, list) else [value]:
            if item is not None and _NUMBER.fullmatch(str(item)):
                return _stray_number(command, words, str(item), action)
    return None


def _stray_number(command: CommandParser, words: list[str], number: str,
                  positional: argparse.Action | None) -> str:
    """The one-line refusal of `number`, a value no option takes: what it would have become,
    and how many values the option before it takes."""
    index = words.index(number) if number in words else len(words)
    before = next((word.partition("=")[0] for word in reversed(words[:index])
                   if word.partition("=")[0] in command.options), None)
    action = command.options.get(before)
    count = None if action is None else 1 if action.nargs is None else action.nargs
    takes = f"{before} takes {count} value{'s' * (count != 1)}" if isinstance(count, int) \
        else f"{before} takes numbers only before the next option" if before else ""
    if positional is None:
        return f"{number} is a value too many{': ' + takes if takes else ''}"
    name = positional.metavar or positional.dest.upper()
    return (f"{number} would be {name}, a number where a path goes{'; ' + takes if takes else ''}"
            f" (a path named so: write ./{number})")


def _repeated_or_empty(command: CommandParser, words: list[str]) -> str | None:
    """Why the words after the subcommand are refused, or None: an option that takes values
    given twice (argparse keeps the last silently: `--focused a b --focused c` would drop a and
    b) or given an empty value (`--out ""` is the current folder)."""
    seen: dict[argparse.Action, str] = {}
    for index, word in enumerate(words):
        if word == "--":
            break
        option, equals, value = word.partition("=")
        action = command.options.get(option)
        if action is None or action in command.repeatable:
            continue
        if action in seen:
            both = "" if seen[action] == option else f" (as {seen[action]} and {option})"
            return f"{option} is given twice{both}: give it once, with all its values"
        seen[action] = option
        following = value if equals else (words[index + 1] if index + 1 < len(words) else None)
        if following is not None and following.strip() == "":
            return f"{option} must not be empty"
    return None


def one_line_warnings(command: str):
    """A `warnings.formatwarning` that writes each warning as one line,
    `defocus COMMAND: warning: MESSAGE`, without the source file and line, and each message
    once (repeats format as nothing)."""
    seen: set[str] = set()

    def format_warning(message, category, filename, lineno, line=None):  # noqa: ANN001
        text = one_line(message)
        if text in seen:
            return ""
        seen.add(text)
        return f"defocus {command}: warning: {text}\n"

    return format_warning


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command is, so that it ends as Ctrl-C does: its files
    written whole or not at all, and one line."""

    signal = signal.SIGTERM


def _raise_terminated(signum, frame) -> None:  # noqa: ANN001 (a signal handler's signature)
    raise Terminated("terminated")


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    debug = args.debug or os.environ.get("DEFOCUS_DEBUG", "") not in ("", "0")
    original = warnings.formatwarning
    if not debug:
        warnings.formatwarning = one_line_warnings(args.command)
    handler = None
    if threading.current_thread() is threading.main_thread():
        handler = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        return int(importlib.import_module(COMMANDS[args.command][0]).run(args) or 0)
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
    finally:
        warnings.formatwarning = original
        if handler is not None:
            signal.signal(signal.SIGTERM, handler)


if __name__ == "__main__":
    sys.exit(main())
