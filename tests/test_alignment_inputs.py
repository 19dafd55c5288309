"""optics.alignment on awkward inputs: 1-pixel-high or -wide images, half precision, empty
batches, and the inputs it must refuse (non-finite, integer, too small), each by name."""

import math
import warnings

import pytest
import torch
from skimage import data

from optics import align_shots, estimate_motion, estimate_shift, translate, undo_motion, warp


def _texture(size=64, dtype=torch.float32):
    grey = torch.from_numpy(data.camera()[100:100 + size, 200:200 + size]).to(dtype) / 255
    return grey.expand(1, 3, size, size).contiguous()


def _wave(n, shift=0.0, dtype=torch.float64):
    """Band-limited samples of a 1-D function at `x - shift` (translate is exact on them)."""
    x = torch.arange(n, dtype=dtype) - shift
    return 0.5 + 0.2 * torch.sin(2 * math.pi * 0.11 * x) + 0.1 * torch.cos(2 * math.pi * 0.04 * x)


# --- 1. images one pixel high or wide ---------------------------------------------------------

def test_translate_moves_a_one_pixel_high_image_along_its_length(device):
    row = _wave(64).to(device).reshape(1, 1, 1, 64)
    moved = translate(row, torch.tensor([[0.0, 0.4]], dtype=torch.float64, device=device))
    assert moved.shape == row.shape
    expected = _wave(64, 0.4).to(device)
    assert torch.allclose(moved[0, 0, 0, 12:-12], expected[12:-12], atol=0.01)
    whole = translate(row, torch.tensor([[0.0, 3.0]], dtype=torch.float64, device=device))
    assert torch.allclose(whole[..., 3:], row[..., :-3], atol=1e-10)
    # mirrored at its border, a single row is the same along y: a dy leaves it as it is
    up = translate(row, torch.tensor([[2.5, 0.0]], dtype=torch.float64, device=device))
    assert torch.allclose(up, row, atol=1e-12)


def test_warp_and_undo_motion_move_a_one_pixel_wide_image_along_its_length():
    column = _wave(40).reshape(1, 1, 40, 1)
    moved = warp(column, torch.tensor([[2.0, 0.0]], dtype=torch.float64))
    assert moved.shape == column.shape
    assert torch.allclose(moved[..., 2:, :], column[..., :-2, :], atol=1e-10)
    back = undo_motion(moved, torch.tensor([2.0, 0.0], dtype=torch.float64))
    assert back.shape == column.shape
    assert torch.allclose(back[..., 4:-4, :], column[..., 4:-4, :], atol=1e-6)


# --- 2. non-finite or impossible values are refused by name -----------------------------------

@pytest.mark.parametrize(("zoom", "angle", "shift", "name"), [
    (0.0, 0.0, 0.0, "zoom"), (float("nan"), 0.0, 0.0, "zoom"), (-1.0, 0.0, 0.0, "zoom"),
    (float("inf"), 0.0, 0.0, "zoom"), (1.0, float("nan"), 0.0, "angle"),
    (1.0, float("inf"), 0.0, "angle"), (1.1, 0.0, float("nan"), "shift"),
])
def test_warp_refuses_non_finite_or_non_positive_values(zoom, angle, shift, name):
    image = torch.rand(1, 1, 8, 8)
    with pytest.raises(ValueError, match=f"^{name} (must be|has)"):
        warp(image, torch.tensor([[shift, 0.0]]), torch.tensor([zoom]), torch.tensor([angle]))


def test_translate_refuses_a_nan_pixel_and_an_infinite_shift():
    image = torch.rand(1, 1, 8, 8)
    image[0, 0, 2, 3] = float("nan")
    with pytest.raises(ValueError, match=r"image has 1 NaN .* index \(0, 0, 2, 3\)"):
        translate(image, torch.zeros(1, 2))
    with pytest.raises(ValueError, match="shift has 0 NaN and 1 infinite"):
        translate(torch.rand(1, 1, 8, 8), torch.tensor([[0.0, float("inf")]]))


def test_undo_motion_refuses_a_zero_zoom_and_a_wrong_motion():
    image = torch.rand(1, 1, 8, 8)
    with pytest.raises(ValueError, match="motion.*zoom.*> 0"):
        undo_motion(image, torch.tensor([0.0, 0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match=r"motion must be .* got shape \(3,\)"):
        undo_motion(image, torch.tensor([0.0, 0.0, 1.0]))


# --- 3. half precision and integer images -----------------------------------------------------

@pytest.mark.parametrize(("dtype", "atol"), [(torch.float16, 2e-3), (torch.bfloat16, 1e-2)])
def test_translate_and_warp_keep_a_half_precision_dtype(dtype, atol):
    image = torch.rand(1, 2, 16, 16).to(dtype)
    moved = translate(image, torch.tensor([[2.0, -1.0]]))
    assert moved.dtype == dtype
    # a whole-pixel move is exact up to the dtype's rounding
    assert torch.allclose(moved[..., 2:, :-1].float(), image[..., :-2, 1:].float(), atol=atol)
    turned = warp(image, torch.zeros(1, 2), angle=torch.tensor([math.pi / 2]))
    assert turned.dtype == dtype
    assert torch.allclose(turned.float(), image.rot90(-1, (-2, -1)).float(), atol=atol)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_estimate_shift_and_align_shots_work_in_half_precision(dtype):
    reference = _texture()
    moving = translate(reference, torch.tensor([[1.3, -0.6]]))
    found = estimate_shift(reference.to(dtype), moving.to(dtype))
    assert found.dtype == dtype
    assert torch.allclose(found.float(), torch.tensor([[1.3, -0.6]]), atol=0.02), found
    aligned, motions = align_shots(reference.to(dtype), moving.to(dtype)[:, None])
    assert aligned.dtype == motions.dtype == dtype
    assert torch.allclose(motions[0, 0].float(), torch.tensor([1.3, -0.6, 1.0, 0.0]), atol=0.02)
    assert torch.allclose(aligned[0, 0, :, 12:-12, 12:-12].float(),
                          reference[0, :, 12:-12, 12:-12], atol=0.05)


def test_estimate_motion_refuses_half_precision_by_name():
    image = _texture().half()
    with pytest.raises(TypeError, match="moving has dtype torch.float16.*moving.float()"):
        estimate_motion(image.float(), image)


@pytest.mark.parametrize("dtype", [torch.int64, torch.uint8])
def test_integer_images_are_refused_by_name(dtype):
    image = torch.randint(0, 200, (1, 1, 16, 16)).to(dtype)
    allowed = f"must be a floating-point tensor .*got dtype {dtype}"
    with pytest.raises(TypeError, match=f"^image {allowed}"):
        translate(image, torch.zeros(1, 2))
    with pytest.raises(TypeError, match=f"^image {allowed}"):
        warp(image, torch.zeros(1, 2), torch.tensor([1.1]))
    with pytest.raises(TypeError, match=f"^reference {allowed}"):
        estimate_shift(image, image.float())
    with pytest.raises(TypeError, match=f"^focused {allowed}"):
        align_shots(image.float(), image[:, None])


# --- 4. estimation inputs: non-finite, too small, empty ---------------------------------------

def test_estimate_shift_refuses_non_finite_images_by_name():
    reference, moving = torch.rand(1, 1, 32, 32), torch.rand(1, 1, 32, 32)
    reference[0, 0, 3, 4] = float("nan")
    with pytest.raises(ValueError, match=r"^reference has 1 NaN .* index \(0, 0, 3, 4\)"):
        estimate_shift(reference, moving)
    moving[0, 0, 0, 0] = float("inf")
    with pytest.raises(ValueError, match="^moving has 0 NaN and 1 infinite"):
        estimate_shift(torch.rand(1, 1, 32, 32), moving)
    with pytest.raises(ValueError, match="^focused has 0 NaN and 1 infinite"):
        align_shots(torch.rand(1, 1, 32, 32), moving[:, None])


@pytest.mark.parametrize("shape", [(4, 4), (5, 40), (1, 64)])
def test_too_small_images_are_refused_with_the_smallest_size(shape):
    image = torch.rand(1, 1, *shape)
    with pytest.raises(ValueError, match="too small .* at least 6x6 pixels"):
        estimate_shift(image, image)
    with pytest.raises(ValueError, match="too small .* at least 6x6 pixels"):
        estimate_motion(image, image)
    with pytest.raises(ValueError, match=r"^image .* too small .* at least 6x6"):
        align_shots(image, image[:, None])
    with pytest.raises(ValueError, match="at least 13x13 pixels .*sigma_px=4"):
        estimate_shift(torch.rand(1, 1, 12, 40), torch.rand(1, 1, 12, 40), sigma_px=4.0)


def test_the_smallest_image_gives_a_finite_shift():
    found = estimate_shift(torch.rand(1, 1, 6, 6), torch.rand(1, 1, 6, 6))
    assert found.shape == (1, 2) and bool(torch.isfinite(found).all())


def test_a_wide_smoothing_skips_the_pyramid_levels_it_does_not_fit():
    """sigma_px=10 mirrors 30 pixels, more than the coarsest level (24 px) holds."""
    reference = _texture(96)
    moving = translate(reference, torch.tensor([[1.3, -0.6]]))
    found = estimate_shift(reference, moving, sigma_px=10.0)
    assert torch.allclose(found, torch.tensor([[1.3, -0.6]]), atol=0.02), found


def test_bad_settings_are_refused_by_name():
    image = torch.rand(1, 1, 32, 32)
    with pytest.raises(TypeError, match="iterations must be an int"):
        estimate_shift(image, image, iterations=2.5)
    with pytest.raises(ValueError, match="finite sigma_px > 0.*inf"):
        estimate_shift(image, image, sigma_px=float("inf"))


def test_empty_batches_give_empty_results():
    empty = torch.rand(0, 1, 16, 16, dtype=torch.float64)
    assert translate(empty, torch.zeros(0, 2)).shape == empty.shape
    assert warp(empty, torch.zeros(0, 2), torch.full((0,), 1.1)).shape == empty.shape
    assert estimate_shift(empty, empty).shape == (0, 2)
    motion = estimate_motion(empty, empty)
    assert motion.shape == (0, 4) and motion.dtype == torch.float64
    aligned, motions = align_shots(empty, empty[:, None].expand(0, 3, 1, 16, 16))
    assert aligned.shape == (0, 3, 1, 16, 16) and motions.shape == (0, 3, 4)


def test_align_shots_refuses_no_focused_photo():
    image = torch.rand(1, 1, 16, 16)
    with pytest.raises(ValueError, match=r"focused must hold at least one photo .*\(1, 0, 1"):
        align_shots(image, image[:, None][:, :0])


def test_align_shots_never_undoes_an_implausible_motion():
    """Photos of different views give Lucas-Kanade nothing to converge on (a zoom of -7 was
    seen on two noise images): the motion undone stays within the MAX_ALIGN_* bounds, and a
    photo that cannot be aligned is used as it is, with a warning."""
    from optics.alignment import MAX_ALIGN_ANGLE, MAX_ALIGN_SHIFT, MAX_ALIGN_ZOOM

    generator = torch.Generator().manual_seed(0)
    image, other = torch.rand(2, 1, 3, 40, 48, generator=generator)
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        aligned, motions = align_shots(image, other[:, None])
    zoom, angle, shift = motions[0, 0, 2], motions[0, 0, 3], motions[0, 0, :2]
    assert abs(float(zoom) - 1) <= MAX_ALIGN_ZOOM and abs(float(angle)) <= MAX_ALIGN_ANGLE
    assert float(shift.abs().max()) <= MAX_ALIGN_SHIFT * 40 and torch.isfinite(aligned).all()
