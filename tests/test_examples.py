"""Each example script trains and evaluates end to end on fixture data in its dataset's format."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
from test_datasets_fixtures import (
    write_dslr,
    write_kitti,
    write_lightfield,
    write_make3d,
    write_middlebury,
    write_nyu,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def load_example(name: str, monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))  # the scripts import their shared _common
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_lightfield_splits(root: Path) -> None:
    write_lightfield(root, n=2, h=24, w=32)  # native size: no resampling of the views
    (root / "train.txt").write_text("IMG_0000_eslf.png\n")
    (root / "test.txt").write_text("IMG_0001_eslf.png\n")


FIXTURES = {
    "nyu": write_nyu,
    "kitti": write_kitti,
    "make3d": write_make3d,
    "dslr": lambda root: (write_dslr(root, split="train"), write_dslr(root, split="test")),
    "lightfield": write_lightfield_splits,
    "middlebury": write_middlebury,
}


@pytest.mark.parametrize("name", sorted(FIXTURES))
def test_example_help(name, monkeypatch, capsys):
    module = load_example(name, monkeypatch)
    with pytest.raises(SystemExit) as exit_info:
        module.main(["--help"])
    assert exit_info.value.code == 0
    help_text = capsys.readouterr().out
    assert "--root" in help_text and "--steps" in help_text
    assert "--root" in module.__doc__ or "root" in module.__doc__  # header says what to put there


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(FIXTURES))
def test_example_trains_and_evaluates(name, tmp_path, monkeypatch, capsys):
    root = tmp_path / "data"
    FIXTURES[name](root)
    module = load_example(name, monkeypatch)
    argv = ["--root", str(root), "--steps", "2", "--batch-size", "2", "--size", "24", "32",
            "--width", "8",
            "--out", str(tmp_path / "run"), "--no-progress", "--max-test", "1"]
    assert module.main(argv) == 0
    out = capsys.readouterr().out
    assert "| method" in out and "ours (small, aif+focused, 2 steps)" in out
    if name == "lightfield":
        assert "loss" in out
    else:
        assert "abs rel" in out and "best constant depth" in out
    assert (tmp_path / "run" / "train_log.csv").is_file()
