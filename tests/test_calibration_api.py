"""Tests of calibrate's PSF specs and of CalibrationResult as CameraSettings (small, fast fits)."""

from __future__ import annotations

import json

import pytest
import torch

from optics import (
    CalibrationPair,
    Camera,
    CameraSettings,
    Disk,
    Gaussian,
    Polygon,
    Sensor,
    ThinLens,
    calibrate,
)

DISTANCES = (1.2, 1.5, 4.0)


def _pairs(aperture, size=32, distances=DISTANCES):
    camera = Camera(ThinLens(0.025, 4.0, 2.0), Sensor(1e-5), aperture)
    sharp = torch.rand(1, 3, size, size, generator=torch.Generator().manual_seed(5),
                       dtype=torch.float64)
    pairs = []
    for d in distances:
        with torch.no_grad():
            blurred = camera.render(sharp, torch.full((1, 1, size, size), d, dtype=torch.float64))
        pairs.append(CalibrationPair(sharp, blurred, d, name=f"{d} m"))
    return pairs


@pytest.fixture(scope="module")
def gaussian_fit():
    return calibrate(_pairs(Gaussian(0.4)), focal_length=0.025, f_number=4.0, pixel_pitch=1e-5,
                     aperture="gaussian", adam_steps=15, lbfgs_steps=10)


def test_result_carries_camera_settings(gaussian_fit, tmp_path):
    fit = gaussian_fit
    assert isinstance(fit.settings, CameraSettings) and tuple(fit.settings.shape) == (1,)
    assert fit.psf == "gaussian" and fit.fitted == ("focus_distance", "psf_scale")
    assert fit.settings.aperture == f"gaussian:{fit.psf_scale:.6g}"
    assert fit.psf_scale == pytest.approx(0.4, rel=0.05)
    # values are read from the settings (one source of truth), as a fresh dict of floats.
    values = fit.values
    assert list(values) == ["focus_distance", "f_number", "focal_length", "pixel_pitch",
                            "psf_scale"]
    for name in ("focal_length", "f_number", "focus_distance", "pixel_pitch"):
        assert values[name] == float(getattr(fit.settings, name)[0])
    values["f_number"] = 99.0
    assert fit.values["f_number"] == 4.0
    # camera() is settings.shot(0), with the Gaussian scale at full precision.
    camera = fit.camera()
    shot = fit.settings.shot(0)
    assert float(camera.lens.focus_distance) == float(shot.lens.focus_distance)
    assert float(camera.aperture.scale) == pytest.approx(fit.psf_scale, rel=1e-6)
    depth = torch.tensor([1.0, 3.0], dtype=torch.float64)
    torch.testing.assert_close(camera.coc_px(depth), shot.coc_px(depth))
    # The JSON loads back as the same settings, and keeps the calibration's extra keys.
    fit.save(tmp_path / "fit.json")
    assert CameraSettings.from_json(tmp_path / "fit.json") == fit.settings
    data = json.loads((tmp_path / "fit.json").read_text())
    assert data == json.loads(json.dumps(fit.to_dict()))
    assert {"uncertainty", "fitted", "rmse", "margin_px", "pairs"} <= set(data)
    assert data["aperture"] == {"family": "gaussian", "scale": fit.psf_scale}
    assert isinstance(Camera.from_json(tmp_path / "fit.json").aperture, Gaussian)
    assert "psf_scale" in fit.table() and "psf: gaussian" in fit.table()


def test_gaussian_spec_with_scale_fixes_it(gaussian_fit):
    pairs = _pairs(Gaussian(0.4))
    kwargs = dict(focal_length=0.025, f_number=4.0, pixel_pitch=1e-5, adam_steps=3,
                  lbfgs_steps=2)
    by_spec = calibrate(pairs, aperture="Gaussian:0.4", **kwargs)
    by_arg = calibrate(pairs, aperture="gaussian", psf_scale=0.4, **kwargs)
    assert by_spec.fitted == by_arg.fitted == ("focus_distance",)
    assert by_spec.values == by_arg.values and by_spec.psf_scale == 0.4
    assert by_spec.settings == by_arg.settings and by_spec.settings.aperture == "gaussian:0.4"
    with pytest.raises(ValueError, match="give the Gaussian scale once"):
        calibrate(pairs, aperture="gaussian:0.4", psf_scale=0.5, **kwargs)


def test_polygon_is_fitted_like_the_disk():
    pairs = _pairs(Polygon(6))
    fit = calibrate(pairs, focal_length=0.025, pixel_pitch=1e-5, aperture="polygon:6",
                    adam_steps=15, lbfgs_steps=10)
    assert fit.psf == "polygon:6" and fit.settings.aperture == "polygon:6"
    assert fit.psf_scale == 1.0 and isinstance(fit.aperture(), Polygon)
    assert fit.values["focus_distance"] == pytest.approx(2.0, rel=0.02)
    assert fit.values["f_number"] == pytest.approx(4.0, rel=0.02)
    assert fit.to_dict()["aperture"] == {"family": "polygon", "n_blades": 6, "rotation": 0.0}
    assert "psf_scale" not in fit.table()
    with pytest.raises(ValueError, match="psf_scale applies to the Gaussian PSF only.*polygon:6"):
        calibrate(pairs, focal_length=0.025, pixel_pitch=1e-5, aperture="polygon:6", psf_scale=0.5)


def test_disk_result_and_unsupported_specs():
    pairs = _pairs(Disk(), size=24)
    fit = calibrate(pairs, focal_length=0.025, pixel_pitch=1e-5, adam_steps=3, lbfgs_steps=2)
    assert fit.psf == "disk" and fit.settings.aperture == "disk" and fit.psf_scale == 1.0
    assert isinstance(fit.camera().aperture, Disk)
    for bad in ("airy", "disk:2", "polygon", 3):
        with pytest.raises(ValueError, match=r"psf must be one of \['disk', 'gaussian'"):
            calibrate(pairs, focal_length=0.025, pixel_pitch=1e-5, aperture=bad)


def test_a_fit_without_blur_is_refused():
    # A target in focus at one depth: the blur (zero) says nothing about the f-number.
    pairs = _pairs(Disk(), size=24, distances=(2.0,))
    with pytest.raises(ValueError, match="blur"):
        calibrate(pairs, focal_length=0.025, pixel_pitch=1e-5, focus_distance=2.0,
                  adam_steps=0, lbfgs_steps=0)
