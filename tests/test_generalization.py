"""Cross-dataset evaluation: `defocus evaluate` renders the data with the camera the checkpoint
was trained for, and `examples/generalization.py` prints the sources x targets matrix."""

from __future__ import annotations

import json

import pytest
import torch
from test_datasets_fixtures import write_dslr_release
from test_examples import load_example

from datasets import DSLR, SynthesizedFocus
from defocus.cli import main


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """A network trained one step on the synthetic scenes (50 mm f/1.4 at 2 m and 6 m)."""
    out = tmp_path_factory.mktemp("run") / "run"
    assert main(["train", "--out", str(out), "--scenes", "2", "--size", "16", "16", "--quiet",
                 "--set", "steps=1", "batch_size=2", "width=4", "progress=false",
                 "device=cpu", "depth_min=1.5", "depth_max=6.0"]) == 0
    return out / "checkpoints" / "last.pt"


def test_evaluate_renders_the_data_with_the_checkpoints_camera(checkpoint, tmp_path, capsys):
    """`--data dslr --focus synthesized`: the f/8 photos and depth rendered with the training
    camera, not the DSLR's; the metrics are those of the network on those renders."""
    from models.evaluation import evaluate_network
    from models.loading import load_model
    from optics import CameraSettings

    write_dslr_release(tmp_path / "data")
    capsys.readouterr()
    result = tmp_path / "m.json"
    assert main(["evaluate", str(checkpoint), "--data", "dslr", "--root", str(tmp_path / "data"),
                 "--focus", "synthesized", "--split", "train", "--json", str(result)]) == 0
    out = capsys.readouterr().out
    assert ("rendered with the camera the checkpoint was trained for: f/1.4 focused at 2, 6 m "
            "(focal length 50 mm, pixel pitch 180 um)") in out
    network, config = load_model(checkpoint)
    camera = CameraSettings(0.05, 1.4, [2.0, 6.0], 180e-6)
    expected = evaluate_network(network, config, SynthesizedFocus(
        DSLR(tmp_path / "data", focus="synthesized"), camera))
    assert json.loads(result.read_text())["abs_rel"] == pytest.approx(expected["abs_rel"],
                                                                      rel=1e-5)
    # the real photos (one focused photo, f/2.8) are not rendered: this network reads two
    assert main(["evaluate", str(checkpoint), "--data", "dslr", "--root", str(tmp_path / "data"),
                 "--split", "train"]) == 2
    assert "n_focus=2" in capsys.readouterr().err


def test_synthesized_focus_leaves_a_network_of_the_image_alone(checkpoint, tmp_path):
    """`checkpoint_focus` renders with the recorded camera; without a record the samples stay
    as they are, with a warning."""
    from defocus.app.evaluate import checkpoint_focus
    from models.checkpoints import load_checkpoint, save_checkpoint

    samples = [{"image": torch.rand(3, 8, 8), "depth": torch.full((1, 8, 8), 3.0)}]
    rendered, line, warning = checkpoint_focus(samples, checkpoint, "gaussian")
    assert warning is None and "f/1.4 focused at 2, 6 m" in line
    assert rendered[0]["focused"].shape == (2, 3, 8, 8)
    state = load_checkpoint(checkpoint)
    del state["camera"]
    older = tmp_path / "older.pt"
    save_checkpoint(state, older)
    same, line, warning = checkpoint_focus(samples, older, "gaussian")
    assert same is samples and line is None and "records no camera" in warning


def test_matrix_shows_the_mean_and_spread_over_seeds(monkeypatch):
    module = load_example("generalization", monkeypatch)
    rows = [{"source": "synthetic", "target": target, "method": "m", "seed": seed,
             "metrics": {"abs_rel": value}}
            for target, values in (("synthetic", (0.2, 0.4)), ("dslr", (1.0, 1.0)))
            for seed, value in enumerate(values)]
    text = module.matrix(rows, "abs_rel", ["synthetic", "dslr", "middlebury"])
    assert "| synthetic / m " in text and "0.300 ± 0.141" in text and "1.000 ± 0.000" in text
    assert text.splitlines()[0].startswith("| abs rel ↓: source / method")
    assert text.rstrip().endswith("- |")  # no row for that target


@pytest.mark.slow
def test_generalization_example_quick_run(tmp_path, monkeypatch, capsys):
    """--quick on a release fixture: every source trains the four networks with the seed given,
    every row is scored on every target and written with --json."""
    write_dslr_release(tmp_path / "data", times=tuple(
        f"2018-04-26T16:{m:02d}:00" for m in range(5)), depth_lag_s=(0.5,) * 5)
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(tmp_path / "cache"))
    module = load_example("generalization", monkeypatch)
    table = tmp_path / "rows.json"
    argv = ["--quick", "--root", str(tmp_path / "data"), "--out", str(tmp_path / "run"),
            "--seeds", "3", "--json", str(table), "--set", "steps=1", "width=4",
            "batch_size=2"]
    assert module.main(argv) == 0
    out = capsys.readouterr().out
    for metric in ("abs rel ↓", "d<1.25 ↑", "order ↑"):
        assert f"| {metric}: source / method" in out
    found = json.loads(table.read_text())
    assert found["sources"] == ["synthetic", "dslr"]
    assert found["targets"] == ["synthetic", "dslr", "middlebury"] and found["seeds"] == [3]
    rows = found["rows"]
    assert len(rows) == 2 * 3 * 5  # sources x targets x (4 networks + constant)
    kinds = {(row["input"], row["supervision"]) for row in rows}
    assert kinds == {("aif", "self"), ("aif", "depth"), ("aif+focused", "self"),
                     ("aif+focused", "depth"), ("none", "none")}
    for row in rows:
        assert set(row) == {"source", "target", "method", "input", "supervision", "seed",
                            "metrics"}
        assert set(row["metrics"]) >= {"abs_rel", "rmse", "delta1", "depth_order"}
        assert row["seed"] == 3
    assert "seed: 3" in (tmp_path / "run" / "dslr" / "seed3" / "self-aif" / "config.yaml"
                         ).read_text()
    assert "f/2.8 focused at 2, 8 m" in found["cameras"]["dslr"]
    with pytest.raises(SystemExit, match="already exists"):
        module.main(argv)  # an earlier table is not replaced without --overwrite
