"""`defocus sample` and `defocus render`: the output policy (no earlier file replaced without
`--overwrite`, every path checked before any work, all files or none) and the refusal of
inputs that cannot work (a scale too small, a negative seed, an output path that is a file,
cannot be created or is empty), each in one line naming the option and the value."""

from __future__ import annotations

import errno
import json
import shlex
from pathlib import Path

import numpy as np
import pytest

from defocus.app import sample as sample_app
from defocus.app.render import write_focus_sweep
from defocus.app.sample import (
    SAMPLE_FILES,
    SCENE_SIZE,
    predict_problem,
    render_problem,
    scaled_size,
    smallest_scale,
    write_sample_set,
)
from defocus.cli import build_parser, main

#: Small photos that `defocus predict` still reads (fast).
SMALL = "0.05"


def _refused(capsys, command: str) -> str:
    """The one error line of a refused command."""
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith(f"defocus {command}: error: "), err
    assert "unexpected" not in err and "Errno" not in err, err
    return err


def _main_refuses(argv: list[str]) -> None:
    """`main(argv)` refuses with exit code 2: its own one-line error, or argparse's (the CLI
    may refuse an empty option value before the command runs)."""
    try:
        code = main(argv)
    except SystemExit as stop:
        code = stop.code
    assert code == 2


def _tree(folder: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else None
            for p in sorted(folder.rglob("*"))}


# ---- bug 1: earlier files are kept without --overwrite --------------------------------------
def test_sample_refuses_earlier_files_naming_them_and_replaces_them_with_overwrite(tmp_path,
                                                                                   capsys):
    folder = tmp_path / "d"
    folder.mkdir()
    (folder / "camera.json").write_text("mine")
    (folder / "far.png").write_bytes(b"mine too")
    (folder / "notes.txt").write_text("not ours")
    before = _tree(folder)
    assert main(["sample", str(folder), "--scale", SMALL]) == 2
    err = _refused(capsys, "sample")
    assert "camera.json" in err and "far.png" in err and "--overwrite" in err, err
    assert _tree(folder) == before  # nothing written, nothing replaced

    assert main(["sample", str(folder), "--scale", SMALL, "--overwrite"]) == 0
    assert capsys.readouterr().out.startswith("wrote ")
    assert sorted(p.name for p in folder.iterdir()) == sorted([*SAMPLE_FILES, "notes.txt"])
    assert json.loads((folder / "camera.json").read_text())["photos"] == ["near.png", "far.png"]
    assert (folder / "far.png").read_bytes().startswith(b"\x89PNG")
    assert (folder / "notes.txt").read_text() == "not ours"


def test_a_second_sample_into_the_same_folder_is_refused(tmp_path, capsys):
    folder = tmp_path / "s"
    assert main(["sample", str(folder), "--scale", SMALL, "--quiet"]) == 0
    before = _tree(folder)
    assert main(["sample", str(folder), "--scale", SMALL, "--seed", "1"]) == 2
    err = _refused(capsys, "sample")
    assert all(name in err for name in SAMPLE_FILES), err
    assert _tree(folder) == before


def test_sample_help_offers_overwrite():
    options = build_parser("sample").commands["sample"].options
    assert "--overwrite" in options


# ---- bug 2: every path checked first, all files or none ------------------------------------
def test_a_folder_in_the_way_is_refused_by_name_before_anything_is_written(tmp_path, capsys):
    folder = tmp_path / "d2"
    (folder / "camera.json").mkdir(parents=True)
    assert main(["sample", str(folder), "--scale", SMALL, "--overwrite"]) == 2
    err = _refused(capsys, "sample")
    assert f"{folder / 'camera.json'}" in err and "folder" in err, err
    assert _tree(folder) == {"camera.json": None}


@pytest.mark.parametrize("earlier", [False, True])
def test_a_failure_while_writing_leaves_no_half_set(tmp_path, capsys, monkeypatch, earlier):
    folder = tmp_path / "new" / "s"
    if earlier:
        assert main(["sample", str(folder), "--scale", SMALL, "--quiet"]) == 0
    before = _tree(tmp_path)

    def full_disk(*args, **kwargs):  # depth.npy is the last file of the set
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "save", full_disk)
    argv = ["sample", str(folder), "--scale", SMALL, "--seed", "3"]
    assert main([*argv, "--overwrite"] if earlier else argv) == 2
    err = _refused(capsys, "sample")
    assert "depth.npy" in err and "No space left" in err, err
    # the earlier set as it was, or no folder at all (the folders it made are removed again)
    assert _tree(tmp_path) == before
    assert earlier or not (tmp_path / "new").exists()


def test_a_failure_before_writing_removes_the_folders_it_made(tmp_path, monkeypatch):
    import datasets.capture

    def broken(*args, **kwargs):
        raise RuntimeError("capture failed")

    monkeypatch.setattr(datasets.capture, "capture", broken)
    with pytest.raises(RuntimeError, match="capture failed"):
        write_sample_set(tmp_path / "a" / "b", scale=0.05)
    assert list(tmp_path.iterdir()) == []


# ---- bug 3: a scale too small is refused with the smallest one allowed ----------------------
def test_scaled_size_is_the_size_the_scene_is_downscaled_to():
    from datasets.middlebury import load_motorcycle, motorcycle_scene

    assert tuple(load_motorcycle()["image"].shape[-2:]) == SCENE_SIZE
    for scale in (0.0392, 0.05, 0.123, 0.35):
        assert tuple(motorcycle_scene(scale)[0].shape[-2:]) == scaled_size(scale), scale


@pytest.mark.parametrize(("scale", "size"), [("0.001", "0x0"), ("0.01", "7x5"),
                                              ("0.0391", "28x19")])
def test_sample_refuses_a_scale_too_small_for_predict(tmp_path, capsys, scale, size):
    assert main(["sample", str(tmp_path / "s"), "--scale", scale]) == 2
    err = _refused(capsys, "sample")
    assert f"--scale {scale} would give {size}-pixel photos" in err, err
    assert "the smallest --scale is 0.0392" in err and "predict" in err, err
    assert not (tmp_path / "s").exists()


def _try_command(out: str) -> list[str]:
    line = next(line for line in out.splitlines() if line.startswith("try: defocus "))
    return shlex.split(line)[2:]


def test_the_smallest_scale_is_the_one_the_suggested_predict_command_needs(tmp_path, capsys,
                                                                          monkeypatch):
    smallest = smallest_scale(predict_problem)
    assert smallest == 0.0392
    assert main(["sample", str(tmp_path / "ok"), "--scale", f"{smallest:g}"]) == 0
    command = _try_command(capsys.readouterr().out)
    assert main([*command, "--quiet"]) == 0, capsys.readouterr().err
    # one step smaller, made without the check, and the suggested command fails
    monkeypatch.setattr(sample_app, "predict_problem", lambda scale: None)
    assert main(["sample", str(tmp_path / "small"), "--scale", f"{smallest - 1e-4:g}"]) == 0
    command = _try_command(capsys.readouterr().out)
    assert main(command) == 2
    assert "predict: error: " in capsys.readouterr().err


def test_the_help_states_the_smallest_scales():
    parser = build_parser()
    sample_help = parser.commands["sample"].options["--scale"].help
    render_help = parser.commands["render"].options["--scale"].help
    assert f"at least {smallest_scale(predict_problem):g} " in sample_help, sample_help
    assert f"at least {smallest_scale(render_problem):g}," in render_help, render_help


@pytest.mark.parametrize(("command", "value", "expected"), [
    ("sample", "0", "--scale 0: must be a number in (0, 1]"),
    ("sample", "1.5", "--scale 1.5: must be a number in (0, 1]"),
    ("sample", "nan", "--scale nan: must be a number in (0, 1]"),
    ("render", "0", "--scale 0: must be a number in (0, 1]"),
    ("render", "-1", "--scale -1: must be a number in (0, 1]"),
    ("render", "0.001", "--scale 0.001 would give 0x0-pixel renders"),
    ("render", "0.0019", "--scale 0.0019 would give 1x0-pixel renders"),
])
def test_a_scale_out_of_range_is_refused_by_name(tmp_path, capsys, command, value, expected):
    out = ["--out", str(tmp_path / "o")] if command == "render" else [str(tmp_path / "o")]
    assert main([command, *out, "--scale", value]) == 2
    err = _refused(capsys, command)
    assert expected in err, err
    assert "0.002" in err or "0.0392" in err or "must be" in err, err
    assert not (tmp_path / "o").exists()


def test_render_at_the_smallest_scale_works(tmp_path, capsys):
    smallest = smallest_scale(render_problem)
    assert smallest == 0.002 and scaled_size(smallest) == (1, 1)
    assert main(["render", "--out", str(tmp_path), "--scale", f"{smallest:g}",
                 "--focus-distance",
                 "2.2", "5.0"]) == 0
    assert (tmp_path / "focus_sweep.png").is_file()


# ---- bug 4: messages that name the option and say what is wrong ----------------------------
def test_a_negative_seed_is_refused_by_name(tmp_path, capsys):
    assert main(["sample", str(tmp_path / "s"), "--seed", "-1", "--scale", SMALL]) == 2
    assert "--seed -1: must be an integer >= 0" in _refused(capsys, "sample")
    assert not (tmp_path / "s").exists()


def test_a_file_given_as_the_folder_is_refused(tmp_path, capsys):
    path = tmp_path / "f"
    path.write_text("mine")
    assert main(["sample", str(path), "--scale", SMALL]) == 2
    assert f"FOLDER {path} is a file, not a folder" in _refused(capsys, "sample")
    assert main(["sample", str(path / "sub"), "--scale", SMALL]) == 2
    err = _refused(capsys, "sample")
    assert f"FOLDER {path / 'sub'} cannot be created: {path} is a file, not a folder" in err, err
    assert path.read_text() == "mine"


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
@pytest.mark.parametrize("command", ["sample", "render"])
def test_a_folder_that_cannot_be_created_is_refused_with_the_reason(capsys, command):
    out = ["--out", "/proc/x"] if command == "render" else ["/proc/x"]
    assert main([command, *out, "--scale", SMALL]) == 2
    err = _refused(capsys, command)
    option = "--out" if command == "render" else "FOLDER"
    assert f"{option} /proc/x cannot be created in /proc: No such file or directory" in err, err


def test_the_reason_a_folder_cannot_be_created_is_given(tmp_path, capsys, monkeypatch):
    def read_only(self, *args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(Path, "mkdir", read_only)
    assert main(["sample", str(tmp_path / "a" / "b"), "--scale", SMALL]) == 2
    err = _refused(capsys, "sample")
    assert f"FOLDER {tmp_path / 'a' / 'b'} cannot be created in {tmp_path}: Read-only" in err


# ---- bug 5: an empty output path is refused --------------------------------------------------
def test_an_empty_folder_is_refused_and_nothing_is_written_here(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _main_refuses(["sample", "", "--scale", SMALL])
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("defocus sample: error: ") and "empty" in last, last
    _main_refuses(["render", "--out", "", "--scale", SMALL])
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("defocus render: error: ") and "--out" in last and "empty" in last
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("blank", ["", " "])
def test_the_library_refuses_an_empty_output_path_by_name(tmp_path, monkeypatch, blank):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="^FOLDER '.*': an empty path would write into the "):
        write_sample_set(blank, scale=0.05)
    with pytest.raises(ValueError, match="^--out '.*': an empty path would write into the "):
        write_focus_sweep(blank, scale=0.05)
    assert list(tmp_path.iterdir()) == []
