"""The loss diagnostic (`models.diagnostics`), the registration of real pairs
(`datasets.pairs`) and the side prior of the depth head."""

from __future__ import annotations

import kornia
import pytest
import torch

from datasets.pairs import register_focused, relative_pair
from models.depth_from_photos.side import fold_to_side
from models.depth_head import DepthHead
from models.diagnostics import (
    blur_scale_losses,
    loss_at_depths,
    match_blur_scale,
    mirror_depth,
    true_depth_wins,
)
from models.losses import DefocusLoss
from models.training.config import TrainConfig
from optics import CameraSettings, render_focal_stack, translate, warp

FOCUS = 1.7
RANGE = (0.8, 10.0)
PITCH = 9e-5  # metres: the fitted effective pitch of the DSLR set (CoC at infinity ~3 px)


def rendered_pairs(count: int = 2, size: int = 48) -> list[dict]:
    """Pairs rendered by a known camera: a textured image, two bands of depth on the two
    sides of the focus plane, the focused photo at f/2.8."""
    generator = torch.Generator().manual_seed(0)
    camera = CameraSettings(0.035, 2.8, [FOCUS], PITCH)
    pairs = []
    for i in range(count):
        texture = torch.rand(1, 3, size // 2, size // 2, generator=generator)
        image = torch.nn.functional.interpolate(texture, size=(size, size), mode="bicubic",
                                                align_corners=False).clamp(0, 1)
        depth = torch.full((1, 1, size, size), (1.1, 3.0, 5.0)[i % 3])
        depth[..., size // 2:] = (4.0, 1.2, 2.2)[i % 3]
        focused = render_focal_stack(image, depth, CameraSettings(0.035, 2.8, [[FOCUS]], PITCH))
        pairs.append({"image": image[0], "focused": focused[0], "camera": camera,
                      "depth": depth[0], "id": str(i)})
    return pairs


def test_true_depth_scores_best_on_rendered_pairs():
    rows = loss_at_depths(rendered_pairs(), DefocusLoss(max_kernel_size=31), RANGE, constants=(2.0,))
    for row in rows:
        assert set(row) == {"id", "true", "mirror", "near end", "far end", "focus",
                            "constant 2 m"}
        assert true_depth_wins(row, tolerance=0.0)
        assert row["true"] < 0.5 * min(v for k, v in row.items() if k not in ("id", "true",
                                                                                 "mirror"))


def test_an_unregistered_pair_prefers_blur_and_registration_mends_it():
    """A shift of the focused photo reads as blur: the diagnostic shows it, registering the
    pair (`register_focused`) restores the true depth's lead."""
    loss = DefocusLoss(max_kernel_size=31)
    shifted = []
    for pair in rendered_pairs():
        moved = translate(pair["focused"], torch.tensor([[1.0, -1.5]]))
        shifted.append({**pair, "focused": moved})
    before = loss_at_depths(shifted, loss, RANGE)
    after = loss_at_depths([register_focused(p) for p in shifted], loss, RANGE)
    assert not all(true_depth_wins(row, tolerance=0.0) for row in before)
    assert all(true_depth_wins(row, tolerance=0.02) for row in after)
    assert all(a["true"] < 0.5 * b["true"] for a, b in zip(after, before, strict=True))


def test_register_focused_splits_a_turn_between_the_photos():
    image = kornia.filters.gaussian_blur2d(torch.rand(1, 3, 96, 96), (7, 7), (1.5, 1.5))
    turned = warp(image, torch.tensor([[0.5, -0.3]]), angle=torch.tensor([0.01]))
    out = register_focused({"image": image[0], "focused": turned})
    assert out["motion"][0, 3].item() == pytest.approx(0.01, abs=1e-3)
    inner = (..., slice(12, -12), slice(12, -12))
    assert (out["focused"][0] - out["image"])[inner].abs().mean() < 0.01
    # the image moved half-way: neither photo was left as it was
    assert (out["image"] - image[0])[inner].abs().mean() > 1e-3


def test_relative_pair_applies_floor_and_gain():
    camera = CameraSettings(0.035, 2.8, [FOCUS], 4e-5)
    image = torch.rand(3, 16, 16)
    plain, relative = relative_pair(image, camera, 8.0)
    assert torch.equal(plain, image) and float(relative.f_number[0]) > 2.8
    gained, _ = relative_pair(image, camera, 8.0, 0.0, [2.0, 1.0, 1.0])
    assert torch.allclose(gained[0], 2 * image[0]) and torch.equal(gained[1:], image[1:])
    with pytest.raises(ValueError, match="must exceed"):
        relative_pair(image, camera, 2.0)


@pytest.mark.parametrize("stated", [1.0, 1.25, 0.8])
def test_match_blur_scale_finds_the_blur_the_photos_have(stated):
    """Pairs rendered by a known camera, given with a camera whose blur is `stated` times the
    real one: the matched scale undoes it (on the default grid)."""
    pairs = rendered_pairs(3)
    for pair in pairs:
        pair["camera"] = pair["camera"].replace(pixel_pitch=PITCH / stated)
    assert match_blur_scale(pairs, DefocusLoss()) == pytest.approx(1 / stated, abs=0.051)
    losses = blur_scale_losses(pairs[:1], DefocusLoss(), (1.0, 2.0))
    assert losses[1.0] == 1.0 and losses[2.0] > 1.0


def test_blur_scales_must_be_positive():
    with pytest.raises(ValueError, match="scales must be"):
        blur_scale_losses(rendered_pairs(1), DefocusLoss(), (1.0, 0.0))
    with pytest.raises(ValueError, match="at least one sample"):
        blur_scale_losses([], DefocusLoss(), (1.0,))


def test_mirror_depth_keeps_the_blur():
    depth = torch.tensor([1.2, 1.7, 2.5])
    mirror = mirror_depth(depth, FOCUS, RANGE)
    assert torch.allclose((1 / mirror - 1 / FOCUS).abs(), (1 / depth - 1 / FOCUS).abs())


@pytest.mark.parametrize("side", ["beyond", "before"])
def test_depth_head_side_prior(side):
    head = DepthHead(0.5, 10.0, side=side, focus_distance=FOCUS)
    depth = head(torch.linspace(-12, 12, 2001))
    assert float(depth.min()) >= 0.5 - 1e-4 and float(depth.max()) <= 10.0 + 1e-3
    blur = (1 / depth - 1 / FOCUS).abs()
    assert bool((blur[1:] >= blur[:-1] - 1e-6).all())  # one blur, one depth: monotone in blur
    if side == "before":
        assert float(depth.max()) <= FOCUS + 1e-4
    else:
        bound = 1 / FOCUS - 1 / 10.0
        beyond = depth >= FOCUS - 1e-4
        # beyond the plane wherever the far side explains the blur, near only above the bound
        assert bool((blur[~beyond] > bound - 1e-4).all()) and bool(beyond[:1000].all())
        assert float(head(torch.tensor(0.0))) > FOCUS  # an untrained network starts beyond


@pytest.mark.parametrize("side", ["beyond", "before"])
def test_fold_to_side_is_what_the_depth_head_can_output(side, dtype):
    """Every folded depth has its true blur and is the one depth of that blur the head outputs
    (the head's curve, sampled densely, interpolated in blur)."""
    depth = torch.linspace(0.5, 10.0, 400, dtype=dtype)
    folded = fold_to_side(depth, FOCUS, (0.5, 10.0), side)
    blur, folded_blur = (1 / depth - 1 / FOCUS).abs(), (1 / folded - 1 / FOCUS).abs()
    inside = (folded > 0.5 + 1e-6) & (folded < 10.0 - 1e-6)
    torch.testing.assert_close(folded_blur[inside], blur[inside])
    head = DepthHead(0.5, 10.0, side=side, focus_distance=FOCUS).to(dtype)
    curve = head(torch.linspace(-14, 14, 20001, dtype=dtype))
    curve_blur = (1 / curve - 1 / FOCUS).abs()
    nearest = (curve_blur[None, :] - folded_blur[inside, None]).abs().argmin(1)
    torch.testing.assert_close(curve[nearest], folded[inside], rtol=2e-3, atol=0)
    if side == "before":
        assert bool((folded <= FOCUS + 1e-6).all())
    else:  # near only where the far side cannot explain the blur
        bound = 1 / FOCUS - 1 / 10.0
        assert bool((blur[folded < FOCUS] > bound - 1e-6).all())
    assert torch.equal(fold_to_side(depth, FOCUS, (0.5, 10.0), "both"), depth)


def test_side_prior_needs_a_focus_distance():
    with pytest.raises(ValueError, match="needs a focus_distance"):
        DepthHead(0.5, 10.0, side="beyond")
    with pytest.raises(ValueError, match="side must be one of"):
        DepthHead(0.5, 10.0, side="left", focus_distance=FOCUS)
    with pytest.raises(ValueError, match="needs a focus_distance"):
        TrainConfig(side="beyond", depth_min=0.5, depth_max=10.0)
    assert TrainConfig(side="beyond", focus_distance=FOCUS, depth_min=0.5).side == "beyond"
