"""`optics.calibration.blur_curve`: the camera fitted from photo pairs with depth maps recovers
the camera that rendered them (disk PSF, a reference that is itself slightly blurred at f/8,
JPEG-compressed photos)."""

from __future__ import annotations

import io

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from optics import Camera, Disk, Gaussian, Sensor, ThinLens
from optics.calibration.blur_curve import (
    BlurCurve,
    calibrate_from_depth,
    fit_blur_curve,
    measure_blur_curve,
)
from optics.calibration.pair import CalibrationPair

FOCUS, PITCH, FOCAL = 1.7, 5.6e-5, 0.035


def jpeg(image: torch.Tensor, quality: int = 80) -> torch.Tensor:
    """`image` (1,3,H,W) in [0, 1] through an 8-bit JPEG and back."""
    array = (image[0].permute(1, 2, 0).clamp(0, 1).numpy() * 255).round().astype(np.uint8)
    buffer = io.BytesIO()
    iio.imwrite(buffer, array, extension=".jpg", quality=quality)
    back = iio.imread(buffer.getvalue(), extension=".jpg")
    return torch.from_numpy(back.astype(np.float64) / 255).permute(2, 0, 1)[None]


def scene(seed: int, depth_m: float, size: int = 96) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    texture = torch.rand(1, 3, size // 4, size // 4, generator=generator, dtype=torch.float64)
    sharp = torch.nn.functional.interpolate(texture, size=(size, size), mode="bicubic",
                                            align_corners=False).clamp(0, 1)
    return sharp, torch.full((1, 1, size, size), depth_m, dtype=torch.float64)


def pairs_for(aperture, reference_f_number: float | None, compress: bool):
    defocused = Camera(ThinLens(FOCAL, 2.8, FOCUS), Sensor(PITCH), aperture)
    reference = (None if reference_f_number is None else
                 Camera(ThinLens(FOCAL, reference_f_number, FOCUS), Sensor(PITCH), aperture))
    pairs = []
    for seed, depth_m in enumerate((0.75, 0.9, 1.1, 1.3, 2.4, 3.2, 4.5, 7.0)):
        sharp, depth = scene(seed, depth_m)
        blurred = defocused.render(sharp, depth)
        if reference is not None:
            sharp = reference.render(sharp, depth)
        if compress:
            sharp, blurred = jpeg(sharp), jpeg(blurred)
        pairs.append(CalibrationPair(sharp, blurred, depth, name=f"{depth_m} m"))
    return pairs


@pytest.mark.parametrize(("aperture", "spec"), [(Disk(), "disk"), (Gaussian(0.5), "gaussian:0.5")])
def test_recovers_the_camera_from_a_blurred_jpeg_reference(aperture, spec):
    pairs = pairs_for(aperture, reference_f_number=8.0, compress=True)
    fit = calibrate_from_depth(pairs, FOCAL, 2.8, aperture=spec, reference_f_number=8.0,
                               min_pixels=500)
    assert fit.fit.focus_distance == pytest.approx(FOCUS, rel=0.05)
    assert float(fit.settings.pixel_pitch[0]) == pytest.approx(PITCH, rel=0.05)
    assert fit.settings.aperture == spec
    # JPEG's own softening; a disk under about 0.7 px barely changes an image, so its floor
    # is loosely determined
    assert fit.floor_px < 1.0


def test_sharp_references_give_the_camera_and_no_floor():
    pairs = pairs_for(Disk(), reference_f_number=None, compress=False)
    fit = calibrate_from_depth(pairs, FOCAL, 2.8, aperture="disk", min_pixels=500)
    assert fit.fit.focus_distance == pytest.approx(FOCUS, rel=0.02)
    assert float(fit.settings.pixel_pitch[0]) == pytest.approx(PITCH, rel=0.03)
    assert fit.floor_px < 0.7  # a disk under about 0.7 px barely changes an image


def test_a_reference_taken_as_sharp_reads_as_a_larger_pitch():
    """Ignoring the f/8 reference's own blur underestimates the blur: a larger pitch."""
    pairs = pairs_for(Gaussian(0.5), reference_f_number=8.0, compress=False)
    kept = calibrate_from_depth(pairs, FOCAL, 2.8, reference_f_number=8.0, min_pixels=500)
    ignored = calibrate_from_depth(pairs, FOCAL, 2.8, min_pixels=500)
    ratio = float(ignored.settings.pixel_pitch[0] / kept.settings.pixel_pitch[0])
    assert ratio == pytest.approx(1 / np.sqrt(1 - (2.8 / 8) ** 2), rel=0.01)


def test_floor_is_found_where_the_defocused_photos_are_softer():
    """A Gaussian softening of every defocused photo (JPEG, demosaicing) is the floor."""

    softening = Camera(ThinLens(FOCAL, 2.8, FOCUS), Sensor(PITCH), Gaussian(0.5))
    pairs = []
    for pair in pairs_for(Gaussian(0.5), reference_f_number=None, compress=False):
        # about 1.6 px (CoC diameter of a Gaussian PSF) everywhere
        soft = softening.render(pair.blurred, torch.full_like(pair.depth, 2.6))
        pairs.append(CalibrationPair(pair.sharp, soft, pair.depth))
    floor_px = float(softening.coc_px(torch.tensor([2.6], dtype=torch.float64))[0])
    fit = calibrate_from_depth(pairs, FOCAL, 2.8, min_pixels=500)
    assert fit.floor_px == pytest.approx(floor_px, rel=0.15)
    assert float(fit.settings.pixel_pitch[0]) == pytest.approx(PITCH, rel=0.05)


def test_fit_blur_curve_closed_form_and_errors():
    edges = torch.tensor([0.8, 1.0, 1.4, 2.0, 3.0, 5.0, 9.0], dtype=torch.float64)
    centres = 2 / (1 / edges[:-1] + 1 / edges[1:])
    blur = ((5 * (1 - 1.5 / centres)) ** 2 + 0.8 ** 2).sqrt()
    candidates = torch.arange(0, 10, 0.25, dtype=torch.float64)
    errors = (candidates - blur[:, None]) ** 2
    curve = BlurCurve(edges, candidates, errors, torch.full((6,), 1e4), torch.ones(1, 3), "disk")
    torch.testing.assert_close(curve.best_px(), blur, atol=0.02, rtol=0)  # parabola, sub-grid
    fit = fit_blur_curve(curve)
    assert (fit.coc_at_infinity_px, fit.focus_distance, fit.floor_px) == pytest.approx(
        (5.0, 1.5, 0.8), rel=0.02)
    sparse = BlurCurve(edges, candidates, errors, torch.tensor([1e4, 1e4, 0, 0, 0, 0.0]),
                       torch.ones(1, 3), "disk")
    with pytest.raises(ValueError, match="measure blur in 2 depth bin"):
        fit_blur_curve(sparse)


def test_bad_inputs_name_the_argument():
    sharp, depth = scene(0, 2.0, 32)
    with pytest.raises(ValueError, match="one distance, not a depth map"):
        measure_blur_curve([CalibrationPair(sharp, sharp, 2.0)])
    with pytest.raises(ValueError, match="edges must be increasing"):
        measure_blur_curve([CalibrationPair(sharp, sharp, depth)], edges=torch.tensor([2.0, 1.0]))
    with pytest.raises(ValueError, match="reference_f_number must exceed f_number"):
        calibrate_from_depth([CalibrationPair(sharp, sharp, depth)], FOCAL, 2.8,
                             reference_f_number=2.0)
    with pytest.raises(ValueError, match="pairs must hold"):
        measure_blur_curve([])
