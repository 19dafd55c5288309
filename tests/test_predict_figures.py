"""What predict's and training's figures say: panel titles, the depth preview's scale in metres,
the training figure's title and the depth progress bar."""

import numpy as np
import pytest
import torch

from defocus.cli import main


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    from defocus.app.sample import write_sample_set

    return write_sample_set(tmp_path_factory.mktemp("sample") / "s", scale=0.1).folder


def test_predict_figure_titles_each_panel_by_what_it_shows(sample, tmp_path, monkeypatch,
                                                           capsys):
    """No file name above the fused image: the --image panel has its file's name, the fused
    one says so, each focused panel names its file and focus distance; the depth progress bar
    counts passes in words."""
    import models.plotting

    calls = []
    original = models.plotting.plot_prediction
    monkeypatch.setattr(models.plotting, "plot_prediction",
                        lambda *args, **kwargs: calls.append(kwargs) or original(*args, **kwargs))
    focused = ["--focused", str(sample / "near.png"), str(sample / "far.png"),
               "--camera", str(sample / "camera.json"), "--depth-range", "1.5", "8"]
    assert main(["predict", "--image", str(sample / "aif.png"), *focused,
                 "--out", str(tmp_path / "pair")]) == 0
    err = capsys.readouterr().err
    assert "0pass" not in err and "1pass" not in err
    assert "passes over the depth range done: 1" in err
    assert main(["predict", *focused, "--out", str(tmp_path / "fused"), "--quiet"]) == 0
    with_image, fused = calls
    for kwargs in calls:
        assert not kwargs.get("title")
        assert kwargs["focused_labels"] == ["near.png, focused at 2.3 m",
                                            "far.png, focused at 4.6 m"]
    assert with_image["image_label"] == "aif.png"
    assert fused["image_label"] == "all-in-focus (fused)"
    assert (tmp_path / "fused" / "figure.png").stat().st_size > 0


def test_depth_preview_has_a_scale_in_metres_beside_the_photos_pixels(tmp_path):
    """depth.png holds the map at the photo's own pixels, and a colour bar to its right whose
    ends (metres) the PNG records."""
    import matplotlib
    from PIL import Image

    from models.plotting import DEPTH_SCALE_KEY, PREVIEW_BAR_PX, save_depth_preview

    depth = torch.linspace(1.0, 5.0, 30 * 40).reshape(1, 30, 40)
    path = save_depth_preview(tmp_path / "depth.png", depth, (1.0, 5.0))
    with Image.open(path) as image:
        assert image.text[DEPTH_SCALE_KEY] == "1 5"
        assert image.size[0] == 40 + PREVIEW_BAR_PX and image.size[1] >= 30
        pixels = np.asarray(image.convert("RGB"))[:30, :40]
    expected = matplotlib.colormaps["magma_r"](((depth[0] - 1) / 4).numpy(), bytes=True)[..., :3]
    assert np.abs(pixels.astype(int) - expected.astype(int)).max() <= 1


def test_training_figure_title_names_the_sample_and_the_step(tmp_path, monkeypatch):
    from training_helpers import tiny_config

    import models.training.trainer
    from datasets.synthetic import SyntheticScenes
    from models.plotting import figure_title
    from models.training import Trainer

    assert figure_title("", 50) == "step 50"
    titles = []
    monkeypatch.setattr(models.training.trainer, "plot_prediction",
                        lambda *args, **kwargs: titles.append(kwargs["title"]))
    trainer = Trainer(tiny_config(tmp_path / "run", steps=1), SyntheticScenes(2, (16, 16)))
    trainer.step = 50
    trainer.save_figure()
    assert titles == ["sample 0-0, step 50"]
