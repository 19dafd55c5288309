"""Hostile inputs to the metrics (`models.metrics`) and losses (`models.losses`): invalid pixels
under a mask leave the numbers (and gradients) of the valid ones alone, and arguments out of
range are refused by name instead of giving NaN or a silently wrong number."""

from __future__ import annotations

import math

import kornia
import numpy as np
import pytest
import torch
from scipy.stats import spearmanr
from test_metrics_protocols import FB, ddff_reference

from models.losses import (
    DefocusLoss,
    edge_aware_smoothness,
    photometric_loss,
    ssim_map,
    supervised_depth_loss,
)
from models.metrics import confident_half_error, depth_metrics, depth_order
from models.protocols import PROTOCOLS, bumpiness, protocol_metrics

NAN, INF = float("nan"), float("inf")


# ---- supervised_depth_loss -------------------------------------------------------------------

@pytest.mark.parametrize("bad_target", [0.0, NAN, INF])
@pytest.mark.parametrize("bad_depth", [1.5, NAN, INF])
def test_supervised_loss_ignores_masked_labels_and_their_gradient(bad_target, bad_depth):
    g = torch.Generator().manual_seed(0)
    target = 1 + torch.rand(1, 1, 8, 8, generator=g, dtype=torch.float64)
    depth = target * (0.8 + 0.4 * torch.rand(target.shape, generator=g, dtype=torch.float64))
    target[..., 0, 0], depth[..., 0, 0] = bad_target, bad_depth
    mask = torch.ones(target.shape, dtype=torch.bool)
    mask[..., 0, 0] = False
    depth.requires_grad_()
    loss = supervised_depth_loss(depth, target, mask)
    loss.backward()
    d, t = depth.detach()[mask], target[mask]  # the 63 valid pixels, by hand
    assert float(loss.detach()) == pytest.approx(float(((d - t).abs() / t).mean()), rel=1e-12)
    expected_grad = torch.zeros_like(target)
    expected_grad[mask] = torch.sign(d - t) / t / 63
    torch.testing.assert_close(depth.grad, expected_grad)


def test_supervised_loss_unchanged_on_valid_labels():
    g = torch.Generator().manual_seed(1)
    target = 1 + torch.rand(2, 1, 6, 7, generator=g)
    depth = 1 + torch.rand(2, 1, 6, 7, generator=g)
    mask = torch.rand(2, 1, 6, 7, generator=g) > 0.3
    error = (depth - target).abs() / target  # the loss before the fix: error * mask
    before = (error * mask.float()).sum() / mask.float().sum().clamp_min(1.0)
    assert torch.equal(supervised_depth_loss(depth, target, mask), before)
    assert torch.equal(supervised_depth_loss(depth, target, mask.float()), before)
    assert torch.equal(supervised_depth_loss(depth, target), error.mean())


def test_supervised_loss_refuses_shapes_that_would_broadcast():
    with pytest.raises(ValueError, match=r"depth and target must have the same shape, got "
                                         r"\(2, 1, 1, 1\) and \(2, 1, 1\)"):
        supervised_depth_loss(torch.tensor([2.0, 3.0]).reshape(2, 1, 1, 1),
                              torch.tensor([2.0, 3.0]).reshape(2, 1, 1))
    with pytest.raises(ValueError, match=r"mask must have the target's shape \(1, 1, 2, 2\)"):
        supervised_depth_loss(torch.ones(1, 1, 2, 2), torch.ones(1, 1, 2, 2),
                              torch.ones(1, 1, 2, dtype=torch.bool))


# ---- bumpiness and protocol_metrics: non-finite predictions outside the mask ------------------

def _protocol_scene(protocol: str, seed: int = 0, size: int = 16):
    """Ground truth inside the protocol's range, a prediction near it, and a mask without the
    4 x 4 top-left corner (pixel (0, 0) is 4 pixels from every valid one)."""
    rng = np.random.default_rng(seed)
    if protocol == "ddff12":
        target = FB / rng.uniform(0.03, 0.26, (1, 1, size, size))
    elif protocol == "fod500":
        target = rng.uniform(0.1, 1.4, (1, 1, size, size))
    else:
        target = rng.uniform(0.5, 10.0, (1, 1, size, size))
    pred = target * rng.uniform(0.9, 1.1, target.shape)
    mask = np.ones(target.shape, dtype=bool)
    mask[..., :4, :4] = False
    return torch.from_numpy(pred), torch.from_numpy(target), torch.from_numpy(mask)


@pytest.mark.parametrize("protocol", sorted(PROTOCOLS))
@pytest.mark.parametrize("bad", [NAN, INF, -INF])
def test_non_finite_prediction_far_outside_the_mask_changes_nothing(protocol, bad):
    pred, target, mask = _protocol_scene(protocol)
    finite = pred.clone()
    finite[..., 0, 0] = 5.0  # any finite value: the filters do not reach a valid pixel
    broken = pred.clone()
    broken[..., 0, 0] = bad
    expected = protocol_metrics(pred=finite, target=target, mask=mask, protocol=protocol)
    got = protocol_metrics(pred=broken, target=target, mask=mask, protocol=protocol)
    assert all(math.isfinite(v) for v in got.values()), got
    assert got == pytest.approx(expected, rel=1e-12, abs=1e-15)


def test_non_finite_prediction_next_to_valid_pixels_counts_as_zero():
    rng = np.random.default_rng(3)
    pred, target = rng.random((9, 11)) * 0.1, rng.random((9, 11)) * 0.1 + 0.01
    target[4, 5] = 0  # invalid, surrounded by valid pixels
    as_zero = pred.copy()
    as_zero[4, 5] = 0.0
    expected = ddff_reference(as_zero, target)["bumpiness"]  # scikit-image's Scharr filters
    for bad in (NAN, INF):
        broken = torch.from_numpy(pred.copy())
        broken[4, 5] = bad
        got = bumpiness(pred=broken, target=torch.from_numpy(target),
                        mask=torch.from_numpy(target > 0))
        assert float(got[0]) == pytest.approx(expected, rel=1e-10)


def test_non_finite_prediction_inside_the_mask_is_refused():
    pred, target, mask = _protocol_scene("zedd")
    pred[..., 8, 8] = NAN
    with pytest.raises(ValueError, match=r"pred must be finite and > 0 metres at every valid "
                                         r"pixel, got 1 value\(s\) that are not, the first nan "
                                         r"at index \(0, 0, 8, 8\)"):
        protocol_metrics(pred=pred, target=target, mask=mask, protocol="zedd")
    with pytest.raises(ValueError, match="pred must be finite at every valid pixel"):
        bumpiness(pred=pred, target=target, mask=mask)
    target[..., 8, 8], pred[..., 8, 8] = INF, 1.0
    with pytest.raises(ValueError, match="target must be finite at every pixel of mask"):
        bumpiness(pred=pred, target=target, mask=mask)


@pytest.mark.parametrize("protocol", [None, 3, "kitti"])
def test_protocol_must_be_a_known_name(protocol):
    gt = torch.ones(1, 4, 4)
    with pytest.raises(ValueError, match=r"protocol must be one of \['ddff12', 'fod500', "
                                         r"'zedd'\] or a Protocol, got " + repr(protocol)):
        protocol_metrics(pred=gt, target=gt, protocol=protocol)


# ---- depth_order, depth_metrics, confident_half_error ----------------------------------------

def test_depth_order_refuses_non_finite_predictions_where_they_count():
    target = torch.tensor([[1.0, 2.0, 3.0, 4.0, 5.0]])
    with pytest.raises(ValueError, match="pred must be finite at every valid pixel, got 5"):
        depth_order(pred=torch.full_like(target, NAN), target=target)
    pred = torch.tensor([[1.0, 3.0, 2.0, 4.0, NAN]])
    mask = torch.tensor([[True, True, True, True, False]])
    expected = spearmanr([1.0, 3.0, 2.0, 4.0], [1.0, 2.0, 3.0, 4.0])[0]  # 0.8
    assert depth_order(pred=pred, target=target, mask=mask) == pytest.approx(expected)


def test_depth_metrics_depth_range():
    pred, target = torch.tensor([[1.0, 3.0]]), torch.tensor([[-2.0, 2.0]])
    with pytest.raises(ValueError, match=r"min_depth must be a finite depth >= 0 metres .*"
                                         r"got -5"):
        depth_metrics(pred=pred, target=target, min_depth=-5)
    with pytest.raises(ValueError, match="min_depth must be a finite depth >= 0 metres"):
        depth_metrics(pred=pred, target=target, min_depth=NAN)
    with pytest.raises(ValueError, match=r"max_depth must be None or a depth > min_depth "
                                         r"\(1.0\) metres \(infinity allowed\), got 0.5"):
        depth_metrics(pred=pred, target=target, min_depth=1.0, max_depth=0.5)
    m = depth_metrics(pred=pred, target=target, min_depth=0)  # the negative label is ignored
    assert m["abs_rel"] == pytest.approx(0.5) and m["rmse_log"] == pytest.approx(math.log(1.5))


@pytest.mark.parametrize("metric", [depth_metrics, depth_order, protocol_metrics])
def test_empty_batch_is_refused(metric):
    empty = torch.ones(0, 1, 4, 4)
    kwargs = {"protocol": "zedd"} if metric is protocol_metrics else {}
    with pytest.raises(ValueError, match=r"pred must hold at least one image \(B >= 1\), got an "
                                         r"empty batch of shape \(0, 1, 4, 4\)"):
        metric(pred=empty, target=empty, **kwargs)


def test_confident_half_error_refuses_undefined_ratios():
    confidence = torch.tensor([0.9, 0.8, 0.2, 0.1])
    with pytest.raises(ValueError, match=r"error must not be 0 at every pixel .* 0 / 0"):
        confident_half_error(torch.zeros(4), confidence)
    with pytest.raises(ValueError, match=r"error must be finite and >= 0 at every pixel, got 1 "
                                         r"value\(s\) that are not, the first -1.0 at index \(2,\)"):
        confident_half_error(torch.tensor([1.0, 0.0, -1.0, 0.0]), confidence)
    with pytest.raises(ValueError, match="error must be finite"):
        confident_half_error(torch.tensor([1.0, NAN, 1.0, 0.0]), confidence)
    with pytest.raises(ValueError, match=r"confidence must be a number \(not NaN\)"):
        confident_half_error(torch.ones(4), torch.tensor([0.9, NAN, 0.2, 0.1]))
    # one pixel of error: ranked last by the confidence, first against it
    error = torch.tensor([0.0, 0.0, 0.0, 2.0])
    assert confident_half_error(error, confidence) == 0.0
    assert confident_half_error(error, -confidence) == pytest.approx(1.0 / 0.5)


# ---- losses: smoothness, photometric, SSIM, DefocusLoss ----------------------------------------

def test_smoothness_unchanged_on_valid_depth():
    g = torch.Generator().manual_seed(4)
    for dtype in (torch.float32, torch.float64):
        depth = (0.5 + 5 * torch.rand(2, 1, 9, 10, generator=g)).to(dtype)
        image = torch.rand(2, 3, 9, 10, generator=g).to(dtype)
        d = depth / depth.mean((2, 3), keepdim=True)  # the definition, no epsilon
        weight_x = torch.exp(-(image[..., 1:] - image[..., :-1]).abs().mean(1, keepdim=True))
        weight_y = torch.exp(-(image[..., 1:, :] - image[..., :-1, :]).abs().mean(1, keepdim=True))
        expected = ((d[..., 1:] - d[..., :-1]).abs() * weight_x).mean() \
            + ((d[..., 1:, :] - d[..., :-1, :]).abs() * weight_y).mean()
        assert torch.equal(edge_aware_smoothness(depth, image), expected)


def test_smoothness_of_a_one_pixel_wide_depth_is_its_vertical_term():
    depth = torch.tensor([1.0, 2.0, 4.0, 1.0]).reshape(1, 1, 4, 1)  # mean 2
    image = torch.zeros(1, 3, 4, 1)
    # |d/2| differences 0.5, 1, 1.5 (flat image: weight 1); no horizontal neighbour
    assert float(edge_aware_smoothness(depth, image)) == pytest.approx(1.0)
    assert float(edge_aware_smoothness(depth.transpose(-1, -2), image.transpose(-1, -2))) \
        == pytest.approx(1.0)


@pytest.mark.parametrize("dtype", [torch.float16, torch.float32, torch.float64])
def test_smoothness_of_zero_mean_depth_is_finite(dtype):
    image = torch.rand(1, 3, 6, 6).to(dtype)
    zeros = torch.zeros(1, 1, 6, 6, dtype=dtype, requires_grad=True)
    loss = edge_aware_smoothness(zeros, image)
    loss.backward()
    assert float(loss.detach()) == 0.0 and bool(torch.isfinite(zeros.grad).all())
    signs = torch.ones(1, 1, 6, 6, dtype=dtype)
    signs[..., ::2, :] = -1  # mean 0
    assert math.isfinite(float(edge_aware_smoothness(signs, image)))


def test_smoothness_refuses_mismatched_or_empty_maps():
    with pytest.raises(ValueError, match=r"image must have the depth's B, H and W, got "
                                         r"\(1, 3, 8, 7\) for depth \(1, 1, 8, 8\)"):
        edge_aware_smoothness(torch.ones(1, 1, 8, 8), torch.ones(1, 3, 8, 7))
    with pytest.raises(ValueError, match=r"depth must be non-empty"):
        edge_aware_smoothness(torch.ones(0, 1, 8, 8), torch.ones(0, 3, 8, 8))


def test_photometric_loss_refuses_empty_and_too_small_images():
    with pytest.raises(ValueError, match=r"rendered must be non-empty \(\.\.\., C, H, W\) "
                                         r"images, got shape \(0, 3, 8, 8\)"):
        photometric_loss(torch.rand(0, 3, 8, 8), torch.rand(0, 3, 8, 8))
    with pytest.raises(ValueError, match=r"rendered and target must be at least 4 x 4 pixels "
                                         r"for window_size=7 .* got H x W = 3 x 8"):
        photometric_loss(torch.rand(1, 3, 3, 8), torch.rand(1, 3, 3, 8))
    with pytest.raises(ValueError, match=r"x and y must be at least 2 x 2 pixels for "
                                         r"window_size=3 .* got H x W = 8 x 1"):
        ssim_map(torch.rand(1, 3, 8, 1), torch.rand(1, 3, 8, 1), 3)


@pytest.mark.parametrize(("size", "window_size"), [(4, 7), (2, 3)])
def test_smallest_allowed_images_match_kornia(size, window_size):
    g = torch.Generator().manual_seed(5)
    a, b = torch.rand(2, 3, size, 5, generator=g), torch.rand(2, 3, size, 5, generator=g)
    torch.testing.assert_close(ssim_map(a, b, window_size),
                               kornia.metrics.ssim(a, b, window_size), atol=1e-5, rtol=1e-5)
    expected = 0.85 * ((1 - kornia.metrics.ssim(a, b, window_size)) / 2).clamp(0, 1).mean() \
        + 0.15 * (a - b).abs().mean()
    torch.testing.assert_close(photometric_loss(a, b, window_size=window_size), expected)


@pytest.mark.parametrize(("kwargs", "error", "match"), [
    ({"foo": 1}, ValueError, r"unknown keyword argument\(s\) \['foo'\]; the renderer takes "
                             r"\['mode', 'max_kernel_size'"),
    ({"ssim_weight": 5}, ValueError, r"ssim_weight must be in \[0, 1\], got 5"),
    ({"sharpness_weight": -0.1}, ValueError, r"sharpness_weight must be finite and >= 0, got -0.1"),
    ({"smoothness_weight": NAN}, ValueError, r"smoothness_weight must be finite and >= 0, got nan"),
    ({"window_size": 4}, ValueError, r"window_size must be an odd number of pixels >= 1, got 4"),
    ({"ssim_weight": "0.85"}, TypeError, r"ssim_weight must be a number, got str '0.85'"),
])
def test_defocus_loss_checks_its_arguments_when_made(kwargs, error, match):
    with pytest.raises(error, match=match):
        DefocusLoss(**kwargs)


def test_defocus_loss_keeps_valid_arguments():
    loss = DefocusLoss(0.5, 0.2, 0.0, 5, mode="gather", max_kernel_size=31)
    assert (loss.ssim_weight, loss.sharpness_weight, loss.smoothness_weight,
            loss.window_size) == (0.5, 0.2, 0.0, 5)
    assert loss.render_kwargs == {"mode": "gather", "max_kernel_size": 31}
