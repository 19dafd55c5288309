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


TRAIN = ["train", "--scenes", "2", "--size", "16", "16", "--set", "width=4", "progress=false"]

#: bad values for every command (issue #11): each ends in one line, exit code 2, no traceback
BAD_INPUT = {
    "train lr=-1": [*TRAIN, "lr=-1"],
    "train lr=0": [*TRAIN, "lr=0"],
    "train lr=nan": [*TRAIN, "lr=.nan"],
    "train lr=inf": [*TRAIN, "lr=1e999"],
    "train steps=0": [*TRAIN, "steps=0"],
    "train steps=abc": [*TRAIN, "steps=abc"],
    "train key typo": [*TRAIN, "stpes=3"],
    "train no key=value": [*TRAIN, "steps"],
    "train missing config": ["train", "--config", "missing.yaml"],
    "train width=0": [*TRAIN, "width=0"],
    "train log_every=0": [*TRAIN, "log_every=0"],
    "train ssim_window=4": [*TRAIN, "ssim_window=4"],
    "train max_kernel_size=8": [*TRAIN, "max_kernel_size=8"],
    "train render_mode": [*TRAIN, "render_mode=fast"],
    "train grad_clip=-1": [*TRAIN, "grad_clip=-1"],
    "train checkpoint_every=-1": [*TRAIN, "checkpoint_every=-1"],
    "train batch_size=0": [*TRAIN, "batch_size=0"],
    "train depth_min<0": [*TRAIN, "depth_min=-1"],
    "train device": [*TRAIN, "device=cuda:99"],
    "train aperture": [*TRAIN, "aperture=hexagon"],
    "train resume": [*TRAIN, "resume=maybe"],
    "train n_focus": [*TRAIN, "n_focus=3"],
    "train scenes=0": ["train", "--scenes", "0"],
    "train resume nothing": ["train", "--resume", "--out", "nothing_here"],
    "evaluate missing": ["evaluate", "missing.pt"],
    "evaluate scale=0": ["evaluate", "{ck}", "--scale", "0"],
    "evaluate scenes=0": ["evaluate", "{ck}", "--data", "synthetic", "--scenes", "0"],
    "evaluate not a checkpoint": ["evaluate", "photo.png"],
    "predict missing": ["predict", "missing.pt", "--image", "missing.png"],
    "predict missing image": ["predict", "{ck}", "--image", "missing.png"],
    "predict focused count": ["predict", "{ck}", "--image", "photo.png"],
    "predict device missing": ["predict", "--image", "photo.png", "--device", "cuda:99"],
    "predict device name": ["predict", "--image", "photo.png", "--device", "gpu"],
    "predict aggregation": ["predict", "--image", "photo.png", "--aggregation", "boxes"],
    "predict aggregation with a model": ["predict", "{ck}", "--image", "photo.png",
                                         "--aggregation", "windows"],
    "render focus 0": ["render", "--focus-distance", "0", "--scale", "0.1"],
    "render scale 0": ["render", "--scale", "0"],
    "render f-number 0": ["render", "--f-number", "0", "--scale", "0.1"],
    "render focal length": ["render", "--focal-length", "-1", "--scale", "0.1"],
    "demo steps 0": ["demo", "--steps", "0"],
    "demo lr": ["demo", "--lr", "-1"],
    "demo width 0": ["demo", "--width", "0"],
    "demo scenes 0": ["demo", "--scenes", "0"],
    "demo scale 0": ["demo", "--scale", "0"],
    "calibrate missing": ["calibrate", "--pair", "a.dng", "b.dng", "2.0"],
    "calibrate distance": ["calibrate", "--pair", "a.dng", "b.dng", "-1"],
    "convert missing": ["convert-checkpoint", "missing.pt", "new.pt", "--trust"],
    "convert not a checkpoint": ["convert-checkpoint", "photo.png", "new.pt", "--trust"],
    "convert no trust": ["convert-checkpoint", "{ck}", "new.pt"],
}


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """A tiny aif+focused checkpoint (1 step, width 4)."""
    from datasets.synthetic import SyntheticScenes
    from models.training import TrainConfig, Trainer

    out = tmp_path_factory.mktemp("ck")
    cfg = TrainConfig(steps=1, batch_size=1, width=4, out_dir=out / "run", progress=False,
                      supervision="depth")
    Trainer(cfg, SyntheticScenes(1, (16, 16), seed=0)).fit()
    return out / "run" / "checkpoints" / "last.pt"


@pytest.mark.parametrize("case", list(BAD_INPUT))
def test_bad_input_is_one_line(case, capsys, tmp_path, monkeypatch, checkpoint):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("DEFOCUS_DEBUG", raising=False)
    (tmp_path / "photo.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(32))
    argv = [arg.replace("{ck}", str(checkpoint)) for arg in BAD_INPUT[case]]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"defocus {argv[0]}: error: ") and "\n" not in err, err
    assert "Traceback" not in err
    assert not list(tmp_path.rglob("train_log.csv"))  # no training started


def test_unexpected_errors_are_one_line_too(capsys, monkeypatch):
    import defocus.commands.render as render

    monkeypatch.delenv("DEFOCUS_DEBUG", raising=False)
    monkeypatch.setattr(render, "run", lambda args: 1 / 0)
    assert main(["render"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == ("defocus render: error: unexpected ZeroDivisionError: division by zero "
                   "(rerun with --debug for the traceback)")
    monkeypatch.setenv("DEFOCUS_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        main(["render"])


def test_bad_aperture_spec_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["render", "--aperture", "hexagon"])
    assert exit_info.value.code == 2
    assert "expected one of: gaussian" in capsys.readouterr().err


def test_debug_shows_the_traceback(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises((ValueError, FileNotFoundError, OSError)):
        main(["--debug", "evaluate", "missing.pt"])


@pytest.mark.parametrize(("argv", "message"), [
    (["predict", "--focused", "a.png", "b.png", "--focused", "c.png", "d.png", "--depth-range",
      "1", "5"], "--focused is given twice: give it once, with all its values"),
    (["predict", "--focused", "a.png", "b.png", "--depth-range", "1", "5", "--f-number", "2",
      "--f-number", "4"], "--f-number is given twice"),
    (["predict", "--focused", "a.png", "b.png", "--depth-range", "1", "5", "--out", ""],
     "--out must not be empty"),
    (["predict", "--focused", "a.png", "b.png", "--depth-range", "1", "5", "--out="],
     "--out must not be empty"),
    (["render", "--out", " "], "--out must not be empty"),
])
def test_an_option_given_twice_or_empty_is_refused_not_dropped(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    last = capsys.readouterr().err.strip().splitlines()[-1]  # after argparse's usage
    assert exit_info.value.code == 2 and message in last, last


def test_flags_may_be_repeated(tmp_path, capsys):
    code = main(["--quiet", "predict", "--quiet", "--focused", str(tmp_path / "a.png"),
                 str(tmp_path / "b.png"), "--depth-range", "1", "5", "--out", str(tmp_path / "o")])
    assert code == 2 and "missing file" in capsys.readouterr().err  # not the repeated --quiet


@pytest.mark.parametrize("argv", [["render", "--focus-distance", "1e300"],
                                  ["predict", "--focused", "a.png", "b.png", "--focus-distance",
                                   "2.3", "1e39", "--depth-range", "1", "5"]])
def test_values_too_large_for_any_camera_are_named(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "must be a finite number > 0 and at most 1e+09" in err and "tensor(" not in err, err


def test_sigterm_ends_a_command_in_one_line(monkeypatch, tmp_path, capsys):
    import os
    import signal
    import time

    import defocus.commands.sample as sample

    def terminated(args):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises before this ends
        raise AssertionError("SIGTERM did not stop the command")

    monkeypatch.setattr(sample, "run", terminated)
    before = signal.getsignal(signal.SIGTERM)
    assert main(["sample", str(tmp_path / "s")]) == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip() == "defocus sample: interrupted: terminated"
    assert signal.getsignal(signal.SIGTERM) is before
