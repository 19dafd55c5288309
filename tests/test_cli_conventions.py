"""Command-line conventions: `python -m defocus`, global options after the subcommand, no
abbreviations, unknown options answered by the subcommand, options named as typed in errors,
warnings in one line, `--quiet`."""

from __future__ import annotations

import subprocess
import sys

import pytest

from defocus.cli import main


def test_python_m_defocus_runs_the_command_line():
    done = subprocess.run([sys.executable, "-m", "defocus", "--version"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.startswith("defocus ")


def test_global_options_are_accepted_after_the_subcommand(monkeypatch):
    monkeypatch.delenv("DEFOCUS_DEBUG", raising=False)
    monkeypatch.setattr("defocus.commands.render.run", lambda args: 1 / 0)
    assert main(["render"]) == 1  # one line, no traceback
    with pytest.raises(ZeroDivisionError):
        main(["render", "--debug"])
    with pytest.raises(ZeroDivisionError):
        main(["--debug", "render"])


def test_abbreviations_are_refused_with_the_closest_option(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["predict", "--focus-dist", "2", "--depth-range", "1", "5"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    # one line, from the subcommand (not the top level), no usage block
    assert err == "defocus predict: error: unrecognized option --focus-dist (did you mean " \
        "--focus-distance?)\n"


def test_unknown_options_get_no_far_fetched_hint(capsys):
    with pytest.raises(SystemExit):
        main(["render", "--bogus"])
    err = capsys.readouterr().err
    assert err == "defocus render: error: unrecognized option --bogus\n"


@pytest.mark.parametrize(("argv", "message"), [
    (["predict", "--focused", "a.png", "b.png", "--f-number", "-8.3", "--depth-range", "1", "5"],
     "defocus predict: error: --f-number -8.3: must be a finite number > 0"),
    (["predict", "--focused", "a.png", "b.png", "--depth-range", "0", "5"],
     "defocus predict: error: --depth-range 0: must be a finite number > 0"),
    (["calibrate", "--pair", "a.dng", "b.dng", "2", "--focal-length", "-0.05"],
     "defocus calibrate: error: --focal-length -0.05: must be a finite number > 0"),
    (["render", "--f-number", "inf"],
     "defocus render: error: --f-number inf: must be a finite number > 0"),
])
def test_errors_name_the_option_as_typed(argv, message, capsys, monkeypatch):
    monkeypatch.delenv("DEFOCUS_DEBUG", raising=False)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err == message and "tensor(" not in err


WARN_TWICE = """
import warnings
import defocus.commands.render as render
from defocus.cli import main

def run(args):
    warnings.warn("the same thing\\n  twice", UserWarning, stacklevel=1)
    warnings.warn("the same thing\\n  twice", UserWarning, stacklevel=1)
    return 0

render.run = run
raise SystemExit(main(["render"]))
"""


def test_warnings_are_one_line_each_once():
    done = subprocess.run([sys.executable, "-c", WARN_TWICE], capture_output=True, text=True,
                          timeout=120, env={**__import__("os").environ, "DEFOCUS_DEBUG": ""})
    assert done.returncode == 0, done.stderr
    assert done.stderr == "defocus render: warning: the same thing twice\n"


def test_quiet_prints_only_the_result(tmp_path, capsys):
    assert main(["sample", str(tmp_path / "s"), "--scale", "0.1", "--quiet"]) == 0
    out = capsys.readouterr()
    assert out.err == "" and out.out.startswith("wrote ")
