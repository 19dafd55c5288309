"""Tests of optics.calibrate (optics.calibration): round trips through synthetic Bayer DNGs, fixing, errors."""

from __future__ import annotations

import json
import math

import pytest
import torch
from _synthetic_dng import synthetic_camera, write_pairs

from datasets.photos import read_raw
from optics import (
    CalibrationPair,
    Camera,
    CameraSettings,
    Disk,
    Gaussian,
    Sensor,
    ThinLens,
    calibrate,
    fit_thin_lens_curve,
    measure_blur,
    plot_calibration,
)
from optics.calibration.measure import ConstantBlur as _ConstantBlur

DISTANCES = (1.2, 1.5, 4.0)


def _read_pairs(files):
    pairs = []
    for sharp, blurred, distance in files:
        s, _ = read_raw(sharp)
        b, meta = read_raw(blurred)
        pairs.append(CalibrationPair(s, b, distance, name=f"{distance} m"))
    return pairs, meta


@pytest.fixture(scope="module")
def disk_pairs(tmp_path_factory):
    files = write_pairs(tmp_path_factory.mktemp("disk"), synthetic_camera(Disk()), DISTANCES,
                        size=64)
    return _read_pairs(files)


@pytest.fixture(scope="module")
def gaussian_pairs(tmp_path_factory):
    files = write_pairs(tmp_path_factory.mktemp("gauss"), synthetic_camera(Gaussian(0.4)),
                        DISTANCES, size=64, seed=10)
    return _read_pairs(files)


@pytest.mark.slow
def test_round_trip_disk_recovers_focus_and_f_number(disk_pairs, tmp_path):
    pairs, meta = disk_pairs
    fit = calibrate(pairs, focal_length=meta.focal_length, pixel_pitch=meta.pixel_pitch, aperture="disk")
    assert fit.fitted == ("focus_distance", "f_number")
    assert fit.values["focus_distance"] == pytest.approx(2.0, rel=0.02)
    assert fit.values["f_number"] == pytest.approx(4.0, rel=0.02)
    assert all(0 < fit.uncertainty[k] < 0.02 * fit.values[k] for k in fit.fitted)
    assert all(g == pytest.approx(1.0, abs=0.01) for g in fit.gains)
    # The JSON loads back as the same camera.
    fit.save(tmp_path / "fit.json")
    data = json.loads((tmp_path / "fit.json").read_text())
    assert set(data["uncertainty"]) == {"focus_distance", "f_number"}
    assert data["aperture"] == {"family": "disk"}
    assert CameraSettings.from_json(tmp_path / "fit.json") == fit.settings
    assert data["rmse"] == fit.rmse and len(data["pairs"]) == 3
    camera = Camera.from_json(tmp_path / "fit.json")
    assert isinstance(camera.aperture, Disk)
    for key, value in camera.settings().tensors().items():
        assert float(value) == pytest.approx(fit.values[key], rel=1e-12)
    fig = plot_calibration(fit, tmp_path / "fit.png")
    assert (tmp_path / "fit.png").stat().st_size > 1000 and len(fig.axes) >= 4


@pytest.mark.slow
def test_round_trip_gaussian_scale_with_known_f_number(gaussian_pairs):
    pairs, meta = gaussian_pairs
    assert meta.f_number == 4.0
    fit = calibrate(pairs, focal_length=meta.focal_length, f_number=meta.f_number,
                    pixel_pitch=meta.pixel_pitch, aperture="gaussian")
    assert fit.fitted == ("focus_distance", "psf_scale")
    assert fit.values["psf_scale"] == pytest.approx(0.4, rel=0.05)
    assert fit.values["focus_distance"] == pytest.approx(2.0, rel=0.02)
    assert fit.values["f_number"] == 4.0
    assert fit.settings.aperture == f"gaussian:{fit.values['psf_scale']:.6g}"


def _clean_pairs(camera, size=40, distances=DISTANCES, dtype=torch.float64):
    generator = torch.Generator().manual_seed(3)
    sharp = torch.rand(1, 3, size, size, generator=generator, dtype=dtype)
    pairs = []
    for d in distances:
        with torch.no_grad():
            blurred = camera.render(sharp, torch.full((1, 1, size, size), d, dtype=dtype))
        pairs.append(CalibrationPair(sharp, blurred, d))
    return pairs


def test_fixed_parameter_stays_fixed():
    pairs = _clean_pairs(Camera(ThinLens(0.025, 4.0, 2.0), Sensor(1e-5), Disk()))
    fit = calibrate(pairs, focal_length=0.025, focus_distance=2.1, pixel_pitch=1e-5,
                    adam_steps=10, lbfgs_steps=5)
    assert fit.values["focus_distance"] == 2.1 and fit.values["pixel_pitch"] == 1e-5
    assert fit.values["focal_length"] == 0.025 and fit.fitted == ("f_number",)
    assert set(fit.uncertainty) == {"f_number"}
    assert float(fit.camera().lens.focus_distance) == 2.1


def test_pixel_pitch_can_be_fitted_instead():
    pairs = _clean_pairs(Camera(ThinLens(0.025, 4.0, 2.0), Sensor(1e-5), Disk()))
    fit = calibrate(pairs, focal_length=0.025, f_number=4.0, adam_steps=20, lbfgs_steps=20)
    assert fit.values["pixel_pitch"] == pytest.approx(1e-5, rel=0.01)
    assert fit.values["focus_distance"] == pytest.approx(2.0, rel=0.01)


def test_renderer_path_agrees_with_invariant_blur():
    camera = Camera(ThinLens(0.025, 4.0, 2.0), Sensor(1e-5), Gaussian(0.5))
    pairs = _clean_pairs(camera, size=32)
    fast = calibrate(pairs, focal_length=0.025, f_number=4.0, pixel_pitch=1e-5, aperture="gaussian",
                     psf_scale=0.5, adam_steps=0, lbfgs_steps=6)
    slow = calibrate(pairs, focal_length=0.025, f_number=4.0, pixel_pitch=1e-5, aperture="gaussian",
                     psf_scale=0.5, adam_steps=0, lbfgs_steps=6, use_renderer=True)
    assert slow.values["focus_distance"] == pytest.approx(2.0, rel=0.01)
    assert fast.values["focus_distance"] == pytest.approx(slow.values["focus_distance"], rel=0.01)


def test_refuses_degenerate_sets_and_bad_inputs():
    pairs = _clean_pairs(Camera(ThinLens(0.025, 4.0, 2.0), Sensor(1e-5), Disk()), size=24)
    with pytest.raises(ValueError, match="cannot fit .*f_number.*psf_scale"):
        calibrate(pairs, focal_length=0.025, pixel_pitch=1e-5, aperture="gaussian")
    with pytest.raises(ValueError, match="cannot fit .*f_number.*pixel_pitch"):
        calibrate(pairs, focal_length=0.025)
    with pytest.raises(ValueError, match="psf_scale applies to the Gaussian"):
        calibrate(pairs, focal_length=0.025, pixel_pitch=1e-5, psf_scale=0.5)
    with pytest.raises(ValueError, match="every parameter is fixed"):
        calibrate(pairs, focal_length=0.025, pixel_pitch=1e-5, f_number=4, focus_distance=2)
    with pytest.raises(ValueError, match="two or more"):
        calibrate(pairs[:1], focal_length=0.025, pixel_pitch=1e-5)
    with pytest.raises(ValueError, match="f_number must be finite and > 0"):
        calibrate(pairs, focal_length=0.025, pixel_pitch=1e-5, f_number=-2.0)
    with pytest.raises(ValueError, match="psf must be one of"):
        calibrate(pairs, focal_length=0.025, pixel_pitch=1e-5, aperture="airy")
    with pytest.raises(ValueError, match="at least one"):
        calibrate([], focal_length=0.025)
    image = torch.rand(1, 3, 24, 24)
    with pytest.raises(ValueError, match="same shape.*24, 24.*20, 24"):
        CalibrationPair(image, torch.rand(1, 3, 20, 24), 2.0)
    with pytest.raises(ValueError, match="depth .*> 0 metres, got 0"):
        CalibrationPair(image, image, 0)
    with pytest.raises(ValueError, match="depth"):
        CalibrationPair(image, image, float("nan"))
    with pytest.raises(ValueError, match=r"depth map must have shape \(1, 1, 24, 24\), got \(1, 1, 10"):
        CalibrationPair(image, image, torch.ones(1, 1, 10, 10))


def test_fit_thin_lens_curve_and_measure_blur():
    depths = [0.8, 1.1, 3.0, 6.0]
    coc = [12.0 * abs(1 - 1.7 / d) for d in depths]
    a, df = fit_thin_lens_curve(depths, coc)
    assert a == pytest.approx(12.0, rel=1e-3) and df == pytest.approx(1.7, rel=1e-3)
    a, df = fit_thin_lens_curve(depths, coc, focus_distance=1.7)
    assert (a, df) == (pytest.approx(12.0), 1.7)
    camera = Camera(ThinLens(0.05, 2.0, 2.0), Sensor(2e-5), Disk())
    pair = _clean_pairs(camera, size=48, distances=(3.0,))[0]
    expected = 0.05**2 * 1.0 / (2.0 * 3.0 * 1.95 * 2e-5)  # thin-lens CoC, pixels
    assert measure_blur(pair, Disk()) == pytest.approx(expected, rel=0.01)


def test_measure_blur_and_calibrate_on_the_photos_device(device):
    """Photos on `device` (CUDA where present) with a hexagon left on the CPU: the same blur and
    fit as on the CPU."""
    from optics import Polygon

    camera = Camera(ThinLens(0.05, 2.0, 2.0), Sensor(2e-5), Disk())
    pairs = _clean_pairs(camera, size=40, distances=(1.2, 3.0, 6.0))
    moved = [CalibrationPair(p.sharp.to(device), p.blurred.to(device), p.depth) for p in pairs]
    for psf in (Disk(), Polygon(6)):
        assert measure_blur(moved[1], psf) == pytest.approx(measure_blur(pairs[1], psf), rel=1e-6)
    kwargs = {"focal_length": 0.05, "pixel_pitch": 2e-5, "adam_steps": 10, "lbfgs_steps": 5}
    here, cpu = calibrate(moved, **kwargs), calibrate(pairs, **kwargs)
    for name in ("f_number", "focus_distance"):
        assert float(getattr(here.settings, name)) == pytest.approx(
            float(getattr(cpu.settings, name)), rel=1e-4)
    assert here.rmse == pytest.approx(cpu.rmse, rel=1e-3, abs=1e-9)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("psf", [Disk(), Gaussian(0.5)])
def test_invariant_blur_matches_renderer_inside(dtype, psf):
    image = torch.rand(1, 3, 30, 30, dtype=dtype)
    coc = 5.3
    blur = _ConstantBlur(image, 9)(psf, coc).to(dtype)
    camera_render = camera_free_render(image, coc, psf)
    m = psf.half_width(coc)
    inner = (..., slice(m, -m), slice(m, -m))
    tol = 1e-5 if dtype == torch.float32 else 1e-9
    # The Gaussian window of the renderer ends at 3 sigma; ours is wider.
    tol = max(tol, 5e-4) if isinstance(psf, Gaussian) else tol
    torch.testing.assert_close(blur[inner], camera_render[inner], atol=tol, rtol=0)


def camera_free_render(image, coc, psf):
    from optics import render_defocus

    return render_defocus(image, torch.full_like(image[:, :1], coc), psf=psf)


def test_invariant_blur_gradcheck():
    image = torch.rand(1, 1, 8, 8, dtype=torch.float64)
    blur = _ConstantBlur(image, 3)
    coc = torch.tensor([2.3], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda c: blur(Disk(), c), (coc,))
    scale = torch.tensor(0.4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda s: blur(Gaussian(s), coc.detach()), (scale,))
    assert math.isfinite(float(blur(Gaussian(0.5), coc).sum()))


def test_thin_lens_curve_takes_infinite_depth_and_refuses_bad_measurements():
    # A |1 - D_f / D| with A = 8 px, D_f = 2 m; a point at infinity has blur A
    a, df = fit_thin_lens_curve([1.0, 1.5, 4.0, math.inf], [8.0, 8 / 3, 4.0, 8.0])
    assert abs(a - 8.0) < 1e-3 and abs(df - 2.0) < 1e-3
    bad = [(([1.0, 1.5], [4.0, math.nan]), "coc_px must be finite"),
           (([1.0, 1.5], [4.0, -1.0]), "coc_px must be finite and >= 0"),
           (([0.0, 1.5], [4.0, 2.0]), "depths must be > 0"),
           (([1.0, math.nan], [4.0, 2.0]), "depths must be > 0"),
           (([1.0], [4.0]), "at least 2"),
           (([1.0, 2.0], [4.0]), "got 2 and 1"),
           (([math.inf, math.inf], [4.0, 4.0]), "a finite depth")]
    for (depths, coc), message in bad:
        with pytest.raises(ValueError, match=message):
            fit_thin_lens_curve(depths, coc)
    with pytest.raises(ValueError, match="focus_distance must be None or a finite number > 0"):
        fit_thin_lens_curve([1.0, 2.0], [4.0, 1.0], focus_distance=0.0)


def test_measure_blur_refuses_a_margin_that_leaves_no_image():
    pair = CalibrationPair(torch.rand(1, 3, 48, 48, dtype=torch.float64),
                           torch.rand(1, 3, 48, 48, dtype=torch.float64), 3.0)
    for margin in (-3, 24, 100, 2.5, True):
        with pytest.raises(ValueError, match="margin_px must be None or a whole number of pixels "
                                             "from 0 to 23"):
            measure_blur(pair, Disk(), margin_px=margin)
    with pytest.raises(ValueError, match="max_coc_px must be a finite number > 0"):
        measure_blur(pair, Disk(), max_coc_px=0)
    with pytest.raises(TypeError, match=r"parse_aperture\('disk'\)"):
        measure_blur(pair, "disk")
