import dataclasses

import pytest

from defocus.cli import COMMANDS, build_parser
from defocus.commands.train import config_fields_help
from models.training import TrainConfig


def test_every_config_field_is_explained_in_train_help():
    text = config_fields_help()
    for field in dataclasses.fields(TrainConfig):
        line = next(row for row in text.splitlines() if row.strip().startswith(f"{field.name} = "))
        assert len(line.split(":", 1)[1].strip()) > 5, line


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_option_has_help(command):
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    for action in sub._actions:
        if action.dest != "help":
            assert action.help and len(action.help) > 5, (command, action.dest)
