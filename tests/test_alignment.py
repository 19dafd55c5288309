"""Sub-pixel alignment of focal-stack shots (optics.alignment), against closed forms."""

import math

import pytest
import torch
from skimage import data

from optics import (
    Disk,
    align_shots,
    estimate_motion,
    estimate_shift,
    render_defocus,
    translate,
    warp,
)


def _waves(shape, shift=(0.0, 0.0), dtype=torch.float64):
    """A sum of low-frequency plane waves at `p - shift`: band-limited, so `translate` is exact."""
    h, w = shape
    y = torch.arange(h, dtype=dtype)[:, None] - shift[0]
    x = torch.arange(w, dtype=dtype)[None, :] - shift[1]
    out = 0.5 + 0.2 * torch.sin(2 * math.pi * (0.21 * y + 0.13 * x)) \
        + 0.1 * torch.cos(2 * math.pi * (-0.08 * y + 0.27 * x + 0.3))
    return out.expand(1, 3, h, w)


def _texture(size=96, dtype=torch.float32):
    grey = torch.from_numpy(data.camera()[100:100 + size, 200:200 + size]).to(dtype) / 255
    return grey.expand(1, 3, size, size).contiguous()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_translate_matches_the_shifted_function(dtype):
    shift = (0.3, -1.7)
    moved = translate(_waves((48, 64), dtype=dtype), torch.tensor([shift], dtype=dtype))
    expected = _waves((48, 64), shift, dtype)
    inner = (..., slice(12, -12), slice(12, -12))
    # Mirrored borders are not the function's continuation: their kink leaks a few thousandths
    # into the interior. Bilinear resampling is off by 0.076 here (it blurs these waves).
    assert torch.allclose(moved[inner], expected[inner], atol=0.01)
    assert moved.dtype == dtype


def test_translate_by_whole_pixels_is_exact_for_any_image():
    image = torch.rand(2, 3, 20, 24, dtype=torch.float64)
    moved = translate(image, torch.tensor([[2.0, -3.0], [0.0, 1.0]], dtype=torch.float64))
    assert torch.allclose(moved[0, :, 2:, :-3], image[0, :, :-2, 3:], atol=1e-10)
    assert torch.allclose(moved[1, :, :, 1:], image[1, :, :, :-1], atol=1e-10)


def test_translate_does_not_blur():
    """A half-pixel move there and back returns a band-limited image (bilinear resampling would
    be off by about 0.1: it halves the contrast of these waves)."""
    image = _waves((64, 64))
    there = translate(image, torch.tensor([[0.5, 0.5]], dtype=torch.float64))
    back = translate(there, torch.tensor([[-0.5, -0.5]], dtype=torch.float64))
    assert torch.allclose(back[..., 16:-16, 16:-16], image[..., 16:-16, 16:-16], atol=0.02)


def test_translate_gradcheck():
    image = torch.rand(1, 2, 9, 10, dtype=torch.float64, requires_grad=True)
    shift = torch.tensor([[0.3, -0.6]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(translate, (image, shift))


@pytest.mark.parametrize("shift", [(0.37, -1.4), (-0.8, 0.25), (4.6, -5.3)])
def test_estimate_shift_sees_through_defocus_and_noise(shift):
    """The moving photo is also defocused (a 5 px disk) and noisy: the shift is still found."""
    reference = _texture()
    coc = torch.full((1, 1, 96, 96), 5.0)
    blurred = render_defocus(reference, coc, Disk())
    g = torch.Generator().manual_seed(0)
    moving = translate(blurred, torch.tensor([shift])) + 0.01 * torch.randn(
        blurred.shape, generator=g)
    found = estimate_shift(reference, moving)
    assert torch.allclose(found, torch.tensor([shift]), atol=0.05), found


def test_estimate_shift_of_a_textureless_pair_is_zero():
    flat = torch.full((1, 3, 40, 40), 0.5)
    assert torch.equal(estimate_shift(flat, flat), torch.zeros(1, 2))


def test_align_shots_undoes_each_shift():
    image = _texture(64, torch.float64)
    shifts = torch.tensor([[0.6, -0.2], [-1.1, 0.9]], dtype=torch.float64)
    focused = torch.stack([translate(image, s[None]) for s in shifts], 1)
    aligned, found = align_shots(image, focused)
    assert torch.allclose(found[0, :, :2], shifts, atol=0.01)
    # no zoom, no rotation: both ignored
    assert torch.equal(found[0, :, 2:], torch.tensor([[1.0, 0.0]] * 2, dtype=torch.float64))
    assert torch.allclose(aligned[0, :, :, 12:-12, 12:-12],
                          image[:, :, 12:-12, 12:-12].expand(2, -1, -1, -1), atol=0.03)


def test_bad_shifts_are_refused():
    image = torch.rand(1, 3, 8, 8)
    with pytest.raises(ValueError, match="shift must be"):
        translate(image, torch.tensor([1.0, 2.0]))
    with pytest.raises(ValueError, match="finite"):
        translate(image, torch.tensor([[float("nan"), 0.0]]))
    with pytest.raises(ValueError, match="one batch size"):
        estimate_shift(image, torch.rand(2, 3, 8, 8))


@pytest.mark.parametrize("zoom", [0.985, 1.012])
def test_estimate_motion_finds_focus_breathing_through_defocus(zoom):
    """A focused photo magnified by the lens (and shifted, defocused by 4 px, noisy)."""
    reference = _texture(128)
    blurred = render_defocus(reference, torch.full((1, 1, 128, 128), 4.0), Disk())
    g = torch.Generator().manual_seed(1)
    moving = warp(blurred, torch.tensor([[0.6, -0.9]]), torch.tensor([zoom]))
    moving = moving + 0.01 * torch.randn(moving.shape, generator=g)
    found = estimate_motion(reference, moving)[0]
    assert torch.allclose(found[:2], torch.tensor([0.6, -0.9]), atol=0.1), found
    assert float(found[2]) == pytest.approx(zoom, abs=1e-3)


def test_warp_matches_the_magnified_function():
    """warp(image, t, z)(p) = image(c + (p - c - t) / z), on band-limited waves."""
    h = w = 64
    shift, zoom = (0.5, -1.0), 1.02
    y = torch.arange(h, dtype=torch.float64)[:, None]
    x = torch.arange(w, dtype=torch.float64)[None, :]
    c = (h - 1) / 2

    def waves(yy, xx):
        return (0.5 + 0.2 * torch.sin(2 * math.pi * (0.06 * yy + 0.04 * xx))).expand(1, 1, h, w)

    moved = warp(waves(y, x), torch.tensor([shift], dtype=torch.float64),
                 torch.tensor([zoom], dtype=torch.float64))
    expected = waves(c + (y - c - shift[0]) / zoom, c + (x - c - shift[1]) / zoom)
    # bicubic interpolation errs by about 0.006; a zoom or shift of the wrong sign, by 0.1 or more
    assert torch.allclose(moved[..., 8:-8, 8:-8], expected[..., 8:-8, 8:-8], atol=0.01)


@pytest.mark.parametrize("angle", [-0.006, 0.004])
def test_estimate_motion_finds_a_turned_camera_through_defocus(angle):
    """A hand-held focused photo turned by a few tenths of a degree (and magnified, shifted,
    defocused by 4 px, noisy)."""
    reference = _texture(128)
    blurred = render_defocus(reference, torch.full((1, 1, 128, 128), 4.0), Disk())
    g = torch.Generator().manual_seed(2)
    moving = warp(blurred, torch.tensor([[-0.4, 0.7]]), torch.tensor([1.005]),
                  torch.tensor([angle]))
    moving = moving + 0.01 * torch.randn(moving.shape, generator=g)
    found = estimate_motion(reference, moving)[0]
    assert torch.allclose(found[:2], torch.tensor([-0.4, 0.7]), atol=0.1), found
    assert float(found[2]) == pytest.approx(1.005, abs=1e-3)
    assert float(found[3]) == pytest.approx(angle, abs=5e-4)


def test_warp_matches_the_turned_function_on_a_wide_image():
    """warp(image, t, z, a)(p) = image(c + R(-a) (p - c - t) / z) on a non-square image, with R
    turning x (right) toward y (down)."""
    h, w = 48, 80
    shift, zoom, angle = (0.7, -1.2), 0.97, 0.15
    y = torch.arange(h, dtype=torch.float64)[:, None]
    x = torch.arange(w, dtype=torch.float64)[None, :]
    cy, cx = (h - 1) / 2, (w - 1) / 2

    def waves(yy, xx):
        return (0.5 + 0.2 * torch.sin(2 * math.pi * (0.05 * yy + 0.03 * xx))).expand(1, 1, h, w)

    moved = warp(waves(y, x), torch.tensor([shift], dtype=torch.float64),
                 torch.tensor([zoom], dtype=torch.float64),
                 torch.tensor([angle], dtype=torch.float64))
    u, v = x - cx - shift[1], y - cy - shift[0]
    cos, sin = math.cos(angle), math.sin(angle)
    expected = waves(cy + (-sin * u + cos * v) / zoom, cx + (cos * u + sin * v) / zoom)
    inner = (..., slice(10, -10), slice(10, -10))
    assert torch.allclose(moved[inner], expected[inner], atol=0.01)


def test_warp_gradcheck():
    """Differentiable in the image, the shift, the zoom and the angle (bicubic resampling)."""
    g = torch.Generator().manual_seed(4)
    image = torch.rand(1, 2, 10, 12, generator=g, dtype=torch.float64, requires_grad=True)
    shift = torch.tensor([[0.3, -0.4]], dtype=torch.float64, requires_grad=True)
    zoom = torch.tensor([1.05], dtype=torch.float64, requires_grad=True)
    angle = torch.tensor([0.1], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(warp, (image, shift, zoom, angle))
