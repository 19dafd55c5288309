"""A mistyped command line is refused in one line before anything runs: an unknown option is
named with the closest option (`closest_options`), its values never become positionals, and a
number left over (a value too many for the option before it) is never taken for a file or a
folder. Every command, checked the same way."""

from __future__ import annotations

import pytest

from defocus.cli import COMMANDS, build_parser, closest_options, main


def _refused(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.count("\n") == 1, err  # one line, no usage block
    assert err.startswith(f"defocus {argv[0]}: error: "), err
    return err.strip()


#: Per command: a mistyped option with numbers after it, and the option it names.
MISTYPED = {
    "demo": (["demo", "--step", "100"], "--steps"),
    "render": (["render", "--focus", "2.2", "5"], "--focus-distance"),  # the old spelling
    "calibrate": (["calibrate", "--pair", "a.dng", "b.dng", "2", "--lbfgs", "5"],
                  "--lbfgs-steps"),
    "train": (["train", "--scene", "16"], "--scenes"),
    "evaluate": (["evaluate", "--depth", "80"], "--depth-cap"),
    "predict": (["predict", "--image", "a.png", "--focused", "b.png", "c.png", "--depth", "1.5",
                 "8"], "--depth-range"),
    "sample": (["sample", "--seeds", "3"], "--seed"),
    "convert-checkpoint": (["convert-checkpoint", "old.pt", "new.pt", "--trusted"], "--trust"),
}

#: Per command: a number too many after an option; where the command has a positional, the
#: number would have become it.
STRAY = {
    "demo": (["demo", "--steps", "100", "200"], "200 is a value too many: --steps takes 1 value"),
    "render": (["render", "--f-number", "1.4", "2"], "2 is a value too many: --f-number"),
    "calibrate": (["calibrate", "--pair", "a.dng", "b.dng", "2", "3"],
                  "3 is a value too many: --pair takes 3 values"),
    "train": (["train", "--size", "32", "32", "48"], "48 is a value too many: --size takes 2"),
    "evaluate": (["evaluate", "--depth-cap", "80", "6"],
                 "6 would be CHECKPOINT, a number where a path goes; --depth-cap takes 1 value"),
    "predict": (["predict", "--focused", "b.png", "c.png", "--depth-range", "1.5", "8", "9"],
                "9 would be CHECKPOINT, a number where a path goes; --depth-range takes 2 "
                "values (a path named so: write ./9)"),
    "sample": (["sample", "--scale", "0.2", "0.3"], "0.3 would be FOLDER"),
    "convert-checkpoint": (["convert-checkpoint", "old.pt", "2", "--trust"],
                           "2 would be TARGET, a number where a path goes"),
}


def test_every_command_is_checked():
    assert set(MISTYPED) == set(COMMANDS) == set(STRAY)


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_mistyped_option_is_one_line_naming_the_closest(command, capsys, tmp_path,
                                                          monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv, closest = MISTYPED[command]
    err = _refused(argv, capsys)
    assert err.endswith(f"(did you mean {closest}?)"), err
    assert not list(tmp_path.iterdir())  # nothing ran


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_number_never_becomes_a_positional_by_accident(command, capsys, tmp_path,
                                                         monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv, message = STRAY[command]
    assert message in _refused(argv, capsys)
    assert not list(tmp_path.iterdir())  # nothing ran, no folder named 0.3


def test_the_issue_line_names_depth_range_not_the_checkpoint(capsys):
    err = _refused(["predict", "--image", "a.png", "--focused", "b.png", "c.png", "--depth",
                    "1.5", "8"], capsys)
    assert err == "defocus predict: error: unrecognized option --depth (did you mean " \
        "--depth-range?)"


def test_focus_means_focus_distance_not_focused(capsys):
    err = _refused(["predict", "--focused", "a.png", "b.png", "--focus", "2.3", "4.6"], capsys)
    assert err.endswith("(did you mean --focus-distance?)"), err


def test_a_prefix_of_several_options_names_them_all(capsys):
    err = _refused(["predict", "--foc", "2"], capsys)
    assert "--focused" in err and "--focus-distance" in err and "--focal-length" in err, err


@pytest.mark.parametrize(("typed", "expected"), [
    ("--focus", ["--focus-distance"]),        # the words typed begin the option
    ("--depth", ["--depth-range"]),
    ("--range", ["--depth-range"]),           # a word of the option
    ("--focsed", ["--focused"]),              # a misspelling
    ("--bogus", []),
])
def test_closest_options(typed, expected):
    options = list(build_parser("predict").commands["predict"].options)
    assert closest_options(typed, options) == expected


def test_negative_numbers_are_values_not_options(capsys):
    assert main(["predict", "--focused", "a.png", "b.png", "--f-number", "-8.3",
                 "--depth-range", "1", "5"]) == 2
    assert capsys.readouterr().err.strip() == \
        "defocus predict: error: --f-number -8.3: must be a finite number > 0"


@pytest.mark.parametrize("argv", [[], ["bogus"], ["--verbose", "predict"],
                                  ["convert-checkpoint", "old.pt"]])
def test_parser_errors_are_one_line(argv, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.count("\n") == 1 and "usage:" not in err, err


def test_help_still_shows_the_usage(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["predict", "--help"])
    assert stop.value.code == 0 and capsys.readouterr().out.startswith("usage: defocus predict")


def test_options_of_a_group_are_known(capsys):
    err = _refused(["train", "--resum"], capsys)  # --resume is in a mutually exclusive group
    assert err.endswith("(did you mean --resume?)"), err
