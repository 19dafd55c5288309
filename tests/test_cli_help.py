import dataclasses
import re

import pytest

from defocus.app.train import config_fields_help
from defocus.cli import COMMANDS, build_parser
from models.training import TrainConfig


def test_every_config_field_is_explained_in_train_help():
    text = config_fields_help()
    for field in dataclasses.fields(TrainConfig):
        line = next(row for row in text.splitlines() if row.strip().startswith(f"{field.name} = "))
        assert len(line.split(":", 1)[1].strip()) > 5, line


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_option_has_help(command):
    sub = build_parser(command).commands[command]
    for action in sub.arguments:
        if action.dest != "help":
            assert action.help and len(action.help) > 5, (command, action.dest)


@pytest.mark.parametrize("command", list(COMMANDS))
def test_help_states_each_default_once_and_no_dates(command, capsys):
    """Every option's default appears at most once, never as a meaningless "(default: None)",
    and the help holds no year (dated text goes stale: it belongs in the CHANGELOG)."""
    with pytest.raises(SystemExit):
        build_parser().parse_args([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines anywhere
    options = re.split(r"\s(?=-{1,2}[a-z])", text)
    doubled = [o for o in options if o.count("(default") > 1]
    assert not doubled, doubled
    assert "(default: None)" not in text and "(default: [])" not in text
    assert "(default: False)" not in text
    assert not re.search(r"\b(19[5-9]\d|20[0-4]\d)\b", text), re.findall(r".{30}\b20\d\d\b.{10}",
                                                                         text)


def test_the_help_checker_sees_a_doubled_default():
    options = re.split(r"\s(?=-{1,2}[a-z])", "--a X x (default: 1) (default: 1) --b Y y")
    assert [o for o in options if o.count("(default") > 1] == ["--a X x (default: 1) (default: 1)"]


def test_help_builds_only_the_chosen_command():
    """`defocus --help` lists every command without importing one; `defocus predict --help`
    imports no training code (nor torch: only its own module and the option helpers)."""
    import subprocess
    import sys

    code = ("import sys\nfrom defocus.cli import main\ntry:\n    main(sys.argv[1:])\n"
            "except SystemExit:\n    pass\nprint('MODULES', *sys.modules)")
    for argv, commands in ((["--help"], []), (["predict", "--help"], ["predict"])):
        out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True,
                             text=True, check=True).stdout
        modules = out.split("MODULES", 1)[1].split()
        assert [m for m in modules if m.startswith("defocus.commands.")] == \
            [f"defocus.commands.{name}" for name in commands]
        assert not [m for m in modules if m.startswith(("models", "torch", "matplotlib"))], argv
        assert all(name in out for name, (_, text) in COMMANDS.items()) or commands
