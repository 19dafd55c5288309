"""Depth metrics against values computed by hand."""

import math

import pytest
import torch
from scipy.stats import spearmanr

from models.metrics import (
    METRIC_NAMES,
    best_constant_depth,
    confident_half_error,
    crop_mask,
    depth_metrics,
    depth_order,
    format_table,
)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_metrics_match_hand_computation(dtype):
    pred = torch.tensor([[1.0, 3.0], [4.0, 10.0]], dtype=dtype)
    gt = torch.tensor([[2.0, 3.0], [5.0, 8.0]], dtype=dtype)
    m = depth_metrics(pred=pred, target=gt)
    # errors: -1, 0, -1, 2 ; ratios max(d/g,g/d): 2, 1, 1.25, 1.25
    assert m["abs_rel"] == pytest.approx((0.5 + 0 + 0.2 + 0.25) / 4)
    assert m["sq_rel"] == pytest.approx((1 / 2 + 0 + 1 / 5 + 4 / 8) / 4)
    assert m["rmse"] == pytest.approx(math.sqrt((1 + 0 + 1 + 4) / 4))
    logs = [math.log(1 / 2), 0.0, math.log(4 / 5), math.log(10 / 8)]
    assert m["rmse_log"] == pytest.approx(math.sqrt(sum(v * v for v in logs) / 4), rel=1e-6)
    assert m["log10"] == pytest.approx(sum(abs(v) for v in logs) / math.log(10) / 4, rel=1e-6)
    assert m["delta1"] == pytest.approx(1 / 4)  # 1.25 is not < 1.25
    assert m["delta2"] == pytest.approx(3 / 4)
    assert m["delta3"] == pytest.approx(3 / 4)  # 1.25^3 = 1.953 < 2
    assert set(m) == set(METRIC_NAMES)


def test_delta3_excludes_ratio_two():
    m = depth_metrics(pred=torch.tensor([[1.0, 2.0]]), target=torch.tensor([[2.0, 2.0]]))
    assert m["delta3"] == pytest.approx(0.5)


def test_mask_cap_and_clamp():
    pred = torch.tensor([[2.0, 100.0, 1.0]])
    gt = torch.tensor([[2.0, 9.0, 50.0]])
    mask = torch.tensor([[True, True, True]])
    m = depth_metrics(pred=pred, target=gt, mask=mask, max_depth=10.0)  # 50 m is beyond the cap
    # second pixel: prediction clamped to 10 -> |10 - 9| / 9
    assert m["abs_rel"] == pytest.approx((0 + 1 / 9) / 2)
    m = depth_metrics(pred=pred, target=gt, mask=torch.tensor([[True, False, False]]))
    assert m["abs_rel"] == 0.0


def test_batch_is_mean_of_images():
    pred = torch.tensor([2.0, 2.0, 4.0, 4.0]).reshape(2, 1, 1, 2)
    gt = torch.tensor([2.0, 2.0, 2.0, 2.0]).reshape(2, 1, 1, 2)
    assert depth_metrics(pred=pred, target=gt)["abs_rel"] == pytest.approx(0.5)


def test_median_scaling_reported():
    gt = torch.tensor([[1.0, 2.0, 3.0]])
    m = depth_metrics(pred=gt * 2, target=gt, median_scaling=True)
    assert m["median_scale"] == pytest.approx(0.5)
    assert m["abs_rel"] == pytest.approx(0.0)
    assert "(median scaled)" in format_table({"net": m})


def test_crops():
    mask = crop_mask(100, 200, "garg")
    rows = mask.any(1).nonzero()
    cols = mask.any(0).nonzero()
    assert (int(rows.min()), int(rows.max())) == (40, 98)
    assert (int(cols.min()), int(cols.max())) == (7, 191)
    assert crop_mask(100, 200, "eigen").sum() < crop_mask(100, 200, None).sum()
    with pytest.raises(ValueError, match="crop"):
        crop_mask(10, 10, "kitti")
    with pytest.raises(ValueError, match="fractions"):
        crop_mask(10, 10, (0.5, 0.2, 0.0, 1.0))


def test_errors():
    with pytest.raises(ValueError, match="same shape"):
        depth_metrics(pred=torch.ones(2, 2), target=torch.ones(3, 3))
    with pytest.raises(ValueError, match="no valid"):
        depth_metrics(pred=torch.ones(2, 2), target=torch.ones(2, 2),
                      mask=torch.zeros(2, 2, dtype=torch.bool))
    with pytest.raises(ValueError, match="finite"):
        depth_metrics(pred=torch.full((2, 2), float("nan")), target=torch.ones(2, 2))
    with pytest.raises(TypeError):
        depth_metrics(pred=[1.0], target=torch.ones(1))


def test_best_constant_depth_minimises_abs_rel():
    gt = torch.rand(200, generator=torch.Generator().manual_seed(0)) * 3 + 2
    best = best_constant_depth(target=gt)
    grid = torch.linspace(2, 5, 601)
    abs_rel = ((grid[:, None] - gt[None]).abs() / gt[None]).mean(1)
    assert depth_metrics(pred=torch.full_like(gt, best)[None], target=gt[None])["abs_rel"] == pytest.approx(
        float(abs_rel.min()), abs=1e-3)


def test_format_table_rows_and_arrows():
    table = format_table({"a": {k: 0.1 for k in METRIC_NAMES}, "bb": {"abs_rel": 0.25}})
    lines = table.splitlines()
    assert len(lines) == 4
    assert "abs rel ↓" in lines[0] and "d<1.25 ↑" in lines[0]
    assert "0.250" in lines[3] and "-" in lines[3]


def test_confident_half_error_is_the_mean_over_the_confident_half():
    error = torch.tensor([[1.0, 2.0], [3.0, 4.0]])
    assert confident_half_error(error, -error) == pytest.approx(1.5 / 2.5)  # trusts the small
    assert confident_half_error(error, error) == pytest.approx(3.5 / 2.5)  # trusts the large
    with pytest.raises(ValueError, match="one shape"):
        confident_half_error(error, error.flatten())


def test_depth_order_is_spearmans_rank_correlation():
    g = torch.Generator().manual_seed(0)
    target = 1 + 4 * torch.rand(2, 1, 9, 11, generator=g, dtype=torch.float64)
    pred = (target + torch.rand(target.shape, generator=g, dtype=torch.float64)).round()  # ties
    mask = torch.rand(target.shape, generator=g) > 0.3
    expected = sum(spearmanr(pred[i][mask[i]].numpy(), target[i][mask[i]].numpy())[0]
                   for i in range(2)) / 2
    assert depth_order(pred=pred, target=target, mask=mask) == pytest.approx(expected, abs=1e-12)


def test_depth_order_of_a_constant_is_zero_and_bad_maps_are_refused():
    target = torch.tensor([[1.0, 2.0, 3.0]])
    assert depth_order(pred=torch.full_like(target, 2.0), target=target) == 0.0
    with pytest.raises(ValueError, match="same shape"):
        depth_order(pred=torch.ones(1, 2), target=target)
    with pytest.raises(ValueError, match="fewer than two valid"):
        depth_order(pred=target, target=target, mask=torch.tensor([[True, False, False]]))
    with pytest.raises(TypeError, match="by keyword"):
        depth_order(target, target)
