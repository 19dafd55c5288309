"""Issue 11, case 14: calibration refuses fits the photos cannot determine, with the reason and
what to shoot instead; no result with an infinite or NaN uncertainty is returned or saved."""

from __future__ import annotations

import importlib
import json
import math

import pytest
import torch
from _synthetic_dng import render_plane, synthetic_camera, texture, write_pairs

from defocus.cli import main
from optics import CalibrationPair, Disk, calibrate
from optics.calibration.fit import CalibrationError
from optics.calibration.problem import Problem, needed_distances
from optics.calibration.start import initial_guess

CAMERA = synthetic_camera(Disk())  # 25 mm, f/4, focused at 2 m, pitch 5 um
FAST = {"adam_steps": 5, "lbfgs_steps": 3}


def pair(distance: float, seed: int = 0, size: int = 32, crop: int = 12) -> CalibrationPair:
    scene = texture(size + 2 * crop, seed=seed)
    sharp = scene[..., crop:-crop, crop:-crop]
    return CalibrationPair(sharp, render_plane(scene, CAMERA, distance, crop), distance,
                           name=f"{distance} m")


def test_case14_one_distance_with_f_number_and_pitch_known_refused():
    # Before: focus_distance 0.3 m (+/- inf) "fitted"; the truth is 2.0 m.
    with pytest.raises(ValueError, match=r"\['focus_distance'\] needs targets at two or more "
                                         r"distinct depths.*\[1.2\].*in front of.*behind"):
        calibrate([pair(1.2)], focal_length=0.025, f_number=4.0, pixel_pitch=5e-6, **FAST)


def test_case14_all_pairs_at_the_focus_distance_refused():
    # Before: 0.50 m. One distance for two unknowns, and no blur either.
    pairs = [pair(2.0, seed) for seed in range(3)]
    with pytest.raises(ValueError, match="two or more distinct depths"):
        calibrate(pairs, focal_length=0.025, pixel_pitch=5e-6, **FAST)
    # Distinct distances, all (nearly) in focus: no measurable blur.
    pairs = [pair(2.0, 0), pair(2.001, 1), pair(1.999, 2)]
    with pytest.raises(ValueError, match="no measurable blur.*nearer and.*farther"):
        calibrate(pairs, focal_length=0.025, pixel_pitch=5e-6, **FAST)


def test_case14_sharp_equal_to_blurred_refused():
    # Before: f/756.
    pairs = [pair(d, i) for i, d in enumerate((1.2, 1.5, 4.0))]
    same = [CalibrationPair(p.sharp, p.sharp.clone(), p.depth) for p in pairs]
    with pytest.raises(ValueError, match=r"no measurable blur.*the same photo twice\?"):
        calibrate(same, focal_length=0.025, pixel_pitch=5e-6, **FAST)
    with pytest.raises(ValueError, match="no measurable blur"):
        calibrate(same[:1], focal_length=0.025, pixel_pitch=5e-6, focus_distance=2.0, **FAST)


@pytest.mark.parametrize("value", [0.0, 1.0])
def test_case14_constant_images_refused(value):
    good = pair(1.2)
    flat = torch.full_like(good.sharp, value)
    with pytest.raises(ValueError, match=f"blurred is constant \\(every pixel {value:g}\\)"):
        CalibrationPair(good.sharp, flat, 1.2, name="cap")
    with pytest.raises(ValueError, match="pair 'cap': sharp is constant"):
        CalibrationPair(flat, good.blurred, 1.2, name="cap")


def test_non_finite_pair_images_named():
    good = pair(1.2)
    bad = good.blurred.clone()
    bad[0, 1, 3, 4] = float("nan")
    with pytest.raises(ValueError, match=r"pair 'x': blurred has 1 NaN .*\(0, 1, 3, 4\)"):
        CalibrationPair(good.sharp, bad, 1.2, name="x")


def test_needed_distances():
    assert needed_distances(("focus_distance",)) == 2
    assert needed_distances(("f_number",)) == 1
    assert needed_distances(("focus_distance", "f_number")) == 2


def test_initial_focus_guess_uses_the_known_blur_scale():
    pairs = [pair(1.2, 0), pair(4.0, 1)]
    problem = Problem.build(pairs, "disk", focal_length=0.025, f_number=4.0, pixel_pitch=5e-6,
                            focus_distance=None, psf_scale=None)
    start = initial_guess(problem, None, 24.0)
    assert start.values["focus_distance"] == pytest.approx(2.0, rel=0.05)
    fit = calibrate(pairs, focal_length=0.025, f_number=4.0, pixel_pitch=5e-6, adam_steps=5,
                    lbfgs_steps=20)
    assert fit.values["focus_distance"] == pytest.approx(2.0, rel=0.03)
    assert all(math.isfinite(v) for v in fit.uncertainty.values())


def test_singular_fit_raises_and_is_never_saved(monkeypatch, tmp_path):
    calibrate_module = importlib.import_module("optics.calibration.fit")
    real = calibrate_module.gauss_newton

    def singular(model, theta):
        fit = real(model, theta)
        fit.covariance = torch.full_like(fit.covariance, float("inf"))
        fit.singular = True
        return fit

    monkeypatch.setattr(calibrate_module, "gauss_newton", singular)
    pairs = [pair(1.2, 0), pair(4.0, 1)]
    with pytest.raises(CalibrationError, match=r"do not determine.*focus_distance inf") as info:
        calibrate(pairs, focal_length=0.025, f_number=4.0, pixel_pitch=5e-6, **FAST)
    assert isinstance(info.value, ValueError)
    result = info.value.result
    assert result.uncertainty["focus_distance"] == float("inf")
    with pytest.raises(ValueError, match="refusing to save.*focus_distance"):
        result.save(tmp_path / "fit.json")
    assert not (tmp_path / "fit.json").exists()


def test_case14_cli_one_distance_exits_non_zero_without_json(tmp_path, capsys):
    files = write_pairs(tmp_path, CAMERA, (1.2,), size=32)
    sharp, blurred, _ = files[0]
    out = tmp_path / "fit.json"
    argv = ["calibrate", "--pair", str(sharp), str(blurred), "1.2", "--out", str(out),
            "--adam-steps", "3", "--lbfgs-steps", "2"]
    assert main(argv) == 2  # was 0, with focus_distance 0.3 (+/- inf) saved
    err = capsys.readouterr().err
    assert err.startswith("defocus calibrate: error:") and "distinct depths" in err
    assert not out.exists() and not out.with_suffix(".png").exists()


def test_case14_cli_sharp_twice_exits_non_zero_without_json(tmp_path, capsys):
    files = write_pairs(tmp_path, CAMERA, (1.2, 4.0), size=32)
    out = tmp_path / "fit.json"
    argv = ["calibrate", "--out", str(out), "--adam-steps", "3", "--lbfgs-steps", "2"]
    for sharp, _, distance in files:
        argv += ["--pair", str(sharp), str(sharp), str(distance)]
    assert main(argv) == 2
    assert "no measurable blur" in capsys.readouterr().err
    assert not out.exists()


def test_cli_good_fit_still_saves(tmp_path):
    files = write_pairs(tmp_path, CAMERA, (1.2, 4.0), size=48)
    out = tmp_path / "fit.json"
    argv = ["calibrate", "--out", str(out), "--adam-steps", "5", "--lbfgs-steps", "5"]
    for sharp, blurred, distance in files:
        argv += ["--pair", str(sharp), str(blurred), str(distance)]
    assert main(argv) == 0
    data = json.loads(out.read_text())
    assert data["focus_distance"] == pytest.approx(2.0, rel=0.05)
    assert all(math.isfinite(v) for v in data["uncertainty"].values())
