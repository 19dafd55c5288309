"""optics.plotting draws on its own Figure: no pyplot figures, no backend change."""

from __future__ import annotations

import matplotlib
import pytest
import torch
from matplotlib.figure import Figure

from optics import CalibrationPair, Camera, Gaussian, Sensor, ThinLens, calibrate, plot_calibration


@pytest.fixture(scope="module")
def fit():
    camera = Camera(ThinLens(0.025, 4.0, 2.0), Sensor(1e-5), Gaussian(0.4))
    sharp = torch.rand(1, 3, 24, 24, generator=torch.Generator().manual_seed(1),
                       dtype=torch.float64)
    pairs = []
    for d in (1.2, 1.5, 4.0):
        with torch.no_grad():
            blurred = camera.render(sharp, torch.full((1, 1, 24, 24), d, dtype=torch.float64))
        pairs.append(CalibrationPair(sharp, blurred, d))
    return calibrate(pairs, focal_length=0.025, f_number=4.0, pixel_pitch=1e-5, aperture="gaussian",
                     adam_steps=3, lbfgs_steps=2)


def test_plot_calibration_leaves_backend_and_pyplot_alone(fit, tmp_path):
    import matplotlib.pyplot as plt

    before = matplotlib.get_backend()
    try:
        matplotlib.use("svg")  # not Agg: plotting must neither switch nor need the backend
        backend = matplotlib.get_backend()
        plt.close("all")
        figure = plot_calibration(fit)
        saved = plot_calibration(fit, tmp_path / "fit.png")
        assert matplotlib.get_backend() == backend
        assert plt.get_fignums() == []
    finally:
        matplotlib.use(before)
    assert isinstance(figure, Figure) and isinstance(saved, Figure)
    assert len(figure.axes) == 5  # the curve, three residual maps, the colour bar
    assert figure.axes[0].get_title().startswith("D_f = ") and ", scale " in figure.axes[0].get_title()
    assert (tmp_path / "fit.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "fit.png").stat().st_size > 1000


def test_no_pyplot_or_backend_switch_in_optics():
    from pathlib import Path

    import optics

    root = Path(optics.__file__).parent
    for path in sorted(root.rglob("*.py")):
        if path.name == "render.py" or path.name.startswith("_render"):
            continue  # owned elsewhere; checked there
        text = path.read_text()
        for pattern in ("matplotlib.pyplot", "import pyplot", "matplotlib.use("):
            assert pattern not in text, f"{path}: {pattern}"


def test_every_figure_leaves_backend_and_pyplot_alone(tmp_path):
    """The focus sweep (optics) and the prediction figures (models) too."""
    import matplotlib.pyplot as plt

    from datasets.middlebury import motorcycle_focus_sweep, motorcycle_sample
    from models.plotting import plot_comparison, plot_prediction
    from optics.plotting import plot_focus_sweep

    before = matplotlib.get_backend()
    try:
        matplotlib.use("svg")
        backend = matplotlib.get_backend()
        plt.close("all")
        sweep = motorcycle_focus_sweep([2.2, 5.0], scale=0.1)
        plot_focus_sweep(sweep["image"], sweep["depth"], sweep["renders"], sweep["coc_px"],
                         sweep["settings"], tmp_path / "sweep.png")
        sample = motorcycle_sample(0.1)
        plot_prediction(tmp_path / "p.png", sample["image"], sample["depth"], sample["focused"],
                        sample["depth"], sample["mask"])
        plot_comparison(tmp_path / "c.png", sample, {"truth": sample["depth"]}, (1.5, 6.0))
        assert matplotlib.get_backend() == backend
        assert plt.get_fignums() == []
        assert all((tmp_path / n).stat().st_size > 1000 for n in ("sweep.png", "p.png", "c.png"))
    finally:
        matplotlib.use(before)


def test_prediction_figure_shows_the_confidence_when_given(tmp_path):
    from PIL import Image

    from datasets.middlebury import motorcycle_sample
    from models.plotting import plot_prediction

    sample = motorcycle_sample(0.1)
    plot_prediction(tmp_path / "a.png", sample["image"], sample["depth"], sample["focused"])
    plot_prediction(tmp_path / "b.png", sample["image"], sample["depth"], sample["focused"],
                    confidence=torch.rand(1, *sample["depth"].shape[-2:]))
    width = {n: Image.open(tmp_path / n).size[0] for n in ("a.png", "b.png")}
    assert width["b.png"] - width["a.png"] == pytest.approx(2.8 * 90, abs=2)  # one more panel


def test_prediction_figure_hatches_the_mirrored_depths(tmp_path, monkeypatch):
    """The depths the photos cannot place on either side of the focus plane reach the depth
    panel (hatched over its colour bar's range) and are stored in the PNG."""
    import models.plotting as plotting
    from datasets.middlebury import motorcycle_sample

    drawn = []
    hatch = plotting._hatch_mirrored
    monkeypatch.setattr(plotting, "_hatch_mirrored", lambda ax, bar, depth, limits, span: (
        drawn.append((tuple(depth.shape), limits, span)), hatch(ax, bar, depth, limits, span)))
    sample = motorcycle_sample(0.1)
    path = plotting.plot_prediction(tmp_path / "a.png", sample["image"], sample["depth"],
                                    sample["focused"], stated_range=(1.5, 8.0),
                                    mirrored_depths=(1.92, 8.0))
    assert plotting.figure_mirrored_depths(path) == (1.92, 8.0)
    ((shape, limits, span),) = drawn  # the predicted depth's panel, not the ground truth's
    assert shape == tuple(sample["depth"].shape[-2:]) and span == (1.92, 8.0)
    assert limits == pytest.approx(plotting.robust_range(sample["depth"]))
    plain = plotting.plot_prediction(tmp_path / "b.png", sample["image"], sample["depth"])
    assert plotting.figure_mirrored_depths(plain) is None and len(drawn) == 1
