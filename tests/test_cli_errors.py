"""Every command reports bad input in one line on stderr with exit code 2; --version works."""

from __future__ import annotations

import pytest

from defocus import __version__
from defocus.cli import main


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"defocus {__version__}"


@pytest.mark.parametrize("argv", [
    ["predict", "missing.pt", "--image", "missing.png"],
    ["evaluate", "missing.pt"],
    ["train", "--config", "missing.yaml"],
    ["train", "--set", "stpes=3"],
    ["train", "--set", "aperture=hexagon"],
    ["render", "--focus", "0", "--scale", "0.1"],
    ["calibrate", "--pair", "a.dng", "b.dng", "2.0"],
])
def test_bad_input_is_one_line(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("DEFOCUS_DEBUG", raising=False)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"defocus {argv[0]}: error: ") and "\n" not in err, err
    assert "Traceback" not in err


def test_bad_aperture_spec_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["render", "--aperture", "hexagon"])
    assert exit_info.value.code == 2
    assert "expected one of: gaussian" in capsys.readouterr().err


def test_debug_shows_the_traceback(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises((ValueError, FileNotFoundError, OSError)):
        main(["--debug", "evaluate", "missing.pt"])
