"""The defocus command line: help texts, train -> evaluate -> predict on tiny inputs."""

import json

import numpy as np
import pytest

from defocus.cli import build_parser, main


@pytest.mark.parametrize("command", ["train", "evaluate", "predict", "demo"])
def test_help_explains_options(command, capsys):
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    assert "metres" in text or "pixels" in text
    assert "default" in text


def test_demo_defaults_write_to_runs_demo():
    args = build_parser().parse_args(["demo"])
    assert str(args.out) == "runs/demo" and args.steps > 0


@pytest.mark.slow
def test_train_evaluate_predict(tmp_path, capsys):
    from skimage.io import imsave

    out = tmp_path / "run"
    assert main(["train", "--out", str(out), "--scenes", "4", "--size", "16", "16",
                 "--set", "steps=2", "batch_size=2", "width=4", "progress=false",
                 "depth_min=1.5", "depth_max=6.0"]) == 0
    checkpoint = out / "checkpoints" / "last.pt"
    assert checkpoint.exists() and (out / "train_log.csv").exists()
    assert "abs rel" in capsys.readouterr().out

    metrics_path = tmp_path / "m.json"
    assert main(["evaluate", str(checkpoint), "--data", "motorcycle", "--scale", "0.08",
                 "--json", str(metrics_path)]) == 0
    metrics = json.loads(metrics_path.read_text())
    assert 0 < metrics["abs_rel"] < 2 and 0 <= metrics["delta1"] <= 1

    rng = np.random.default_rng(0)
    paths = []
    for name in ("aif", "near", "far"):
        paths.append(tmp_path / f"{name}.png")
        imsave(paths[-1], (rng.random((20, 24, 3)) * 255).astype(np.uint8))
    assert main(["predict", str(checkpoint), "--image", str(paths[0]), "--focused",
                 str(paths[1]), str(paths[2]), "--focus-distance", "2", "6", "--f-number", "2",
                 "--focal-length", "0.05", "--pixel-pitch", "180e-6",
                 "--out", str(tmp_path / "pred")]) == 0
    depth = np.load(tmp_path / "pred" / "depth.npy")
    assert depth.shape == (20, 24) and 1.5 < depth.min() and depth.max() < 6.0
    capsys.readouterr()
    assert main(["predict", str(checkpoint), "--image", str(paths[0])]) == 2
    assert "needs 2 --focused" in capsys.readouterr().err


@pytest.mark.slow
def test_demo_writes_metrics_json_and_figures(tmp_path, capsys):
    import torch

    from datasets.middlebury import motorcycle_sample
    from defocus.app.demo import METHODS
    from models.metrics import METRIC_NAMES, depth_metrics

    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--steps", "2", "--scenes", "4", "--size", "16",
                 "--width", "4", "--scale", "0.08", "--direct-steps", "2"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert tuple(metrics) == METHODS
    for method, values in metrics.items():
        assert set(values) >= set(METRIC_NAMES), method
        assert all(np.isfinite(v) for v in values.values()), method
        assert 0 < values["abs_rel"] < 2 and 0 <= values["delta1"] <= 1
    # The constant row is the abs-rel-optimal constant: no other constant does better.
    sample = motorcycle_sample(0.08)
    for depth in torch.linspace(1.5, 6.0, 19):
        other = depth_metrics(pred=torch.full_like(sample["depth"], depth)[None],
                              target=sample["depth"][None], mask=sample["mask"][None])["abs_rel"]
        assert metrics["constant"]["abs_rel"] <= other + 1e-6
    for name in ("motorcycle_comparison.png", "focus_sweep.png",
                 "self_supervised/checkpoints/last.pt", "supervised/train_log.csv"):
        assert (out / name).stat().st_size > 0, name
    printed = capsys.readouterr().out
    assert "self_supervised" in printed and "best constant abs rel" in printed
    assert "goal" not in printed.lower()  # a user's table states results, not targets


def test_product_text_states_results_not_goals():
    """What users read (the packages' output and docstrings, the examples, README and docs)
    speaks of results; the team's targets live in benchmarks/."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    files = [root / "README.md", *(path for folder in ("defocus", "models", "optics",
                                                       "datasets", "examples", "docs")
                                   for pattern in ("*.py", "*.md")
                                   for path in (root / folder).rglob(pattern))]
    found = [f"{path.relative_to(root)}:{number}" for path in files
             for number, line in enumerate(path.read_text().splitlines(), 1)
             if re.search(r"\bgoals?\b", line, re.IGNORECASE)]
    assert not found, found


def test_predict_marks_the_mirrored_depths_on_the_figure_and_the_summary(tmp_path, capsys):
    """One focused shot beside the all-in-focus photo, focused inside the range: the depths on
    both sides of its focus plane that blur it alike are named in the summary and hatched in
    figure.png (two focus planes have none: `test_mirrored_depths_none_for_two_focus_planes_or_a_
    focus_outside_the_range`)."""
    from defocus.app.sample import write_sample_set
    from models.depth_from_photos import ambiguous_depths
    from models.plotting import figure_mirrored_depths
    from optics import CameraSettings

    sample = write_sample_set(tmp_path / "s", scale=0.2)
    pitch = json.loads((sample.folder / "camera.json").read_text())["pixel_pitch"][0]
    with pytest.warns(UserWarning, match="mirror"):
        assert main(["predict", "--image", str(sample.folder / "aif.png"), "--focused",
                     str(sample.folder / "near.png"), "--focus-distance", "2.3",
                     "--f-number", "1.8", "--focal-length", "0.05", "--pixel-pitch", str(pitch),
                     "--depth-range", "1.5", "8", "--out", str(tmp_path / "one"),
                     "--quiet"]) == 0
    span = ambiguous_depths(CameraSettings(0.05, 1.8, [2.3], pitch), 1.5, 8.0)
    assert span is not None
    assert f"depths {span[0]:.2f}-{span[1]:.2f} m may lie mirrored" in capsys.readouterr().out
    assert figure_mirrored_depths(tmp_path / "one" / "figure.png") == pytest.approx(span)


def test_predict_warns_when_the_photos_camera_is_not_the_networks(tmp_path, capsys):
    """A network trained for the synthetic scenes' camera (f/1.4 focused at 2 and 6 m) on the
    sample photos (f/1.8 at 2.3 and 4.6 m): one warning naming both cameras and what to do;
    none when the photos' camera is the training one."""
    import warnings

    from defocus.app.sample import write_sample_set

    out = tmp_path / "run"
    assert main(["train", "--out", str(out), "--scenes", "2", "--size", "16", "16", "--set",
                 "steps=1", "batch_size=1", "width=4", "--quiet"]) == 0
    checkpoint = str(out / "checkpoints" / "last.pt")
    sample = write_sample_set(tmp_path / "s", scale=0.1)
    photos = ["--image", str(sample.folder / "aif.png"), "--focused",
              str(sample.folder / "near.png"), str(sample.folder / "far.png")]
    with pytest.warns(UserWarning) as caught:
        assert main(["predict", checkpoint, *photos, "--camera", str(sample.folder /
                     "camera.json"), "--out", str(tmp_path / "other"), "--quiet"]) == 0
    message = [str(w.message) for w in caught if "trained for" in str(w.message)]
    assert len(message) == 1 and "\n" not in message[0]
    assert "f/1.8 focused at 2.3, 4.6 m" in message[0]
    assert "f/1.4 focused at 2, 6 m" in message[0]
    assert "without a model file" in message[0] and "defocus train" in message[0]
    capsys.readouterr()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["predict", checkpoint, *photos, "--focus-distance", "2.01", "6",
                     "--f-number", "1.4", "--focal-length", "0.05", "--pixel-pitch", "180e-6",
                     "--out", str(tmp_path / "same"), "--quiet"]) == 0
    assert not [w for w in caught if "trained for" in str(w.message)]
