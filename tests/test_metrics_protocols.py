"""The benchmarks' protocols (`models.protocols.PROTOCOLS`) against independent numpy versions of
the benchmarks' own evaluation code (DDFF-12's `BaseDDFFEval`, DFV's FoD500 evaluation,
FOSSA's `eval_depth`), and the evaluation loop of `models.evaluation`."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from skimage import filters

from models.evaluation import evaluate, label_free_method
from models.metrics import depth_metrics, format_table
from models.protocols import PROTOCOL_METRIC_NAMES, PROTOCOLS, bumpiness, protocol_metrics

FB = 521.4052 * 1982.02508 / 7317.02064 * 1e-3


def ddff_reference(pred: np.ndarray, target: np.ndarray, clip: float = 0.05) -> dict[str, float]:
    """Hazirbas et al.'s metrics as their code computes them: numpy masked arrays over the
    pixels with target > 0, accuracies and bumpiness x100 (target 0 marks invalid)."""
    valid = target > 0
    n = valid.sum()
    p = np.where(valid, pred, 0.0)
    err = p - target
    mse = float(np.square(err).sum() / n)
    log_p, log_t = np.ma.log(p), np.ma.log(target)
    ratio = np.ma.maximum(np.ma.divide(p, target), np.ma.divide(target, p))
    out = {"mse": mse, "rmse": mse**0.5,
           "rmse_log": float(np.sqrt(np.square(log_p - log_t).sum() / n)),
           "abs_rel": float(np.ma.divide(np.abs(err), target).sum() / n),
           "sq_rel": float(np.ma.divide(np.square(err), target).sum() / n)}
    for name, thr in (("delta1", 1.25), ("delta2", 1.25**2), ("delta3", 1.25**3)):
        out[name] = float((ratio < thr).sum() / n * 100)
    diff = np.asarray(pred - target, dtype=np.float64)
    dx, dy = filters.scharr_v(diff), filters.scharr_h(diff)
    hessian = np.sqrt(filters.scharr_v(dx) ** 2 + filters.scharr_h(dx) ** 2
                      + filters.scharr_h(dy) ** 2 + filters.scharr_v(dy) ** 2)
    out["bumpiness"] = float(np.clip(hessian, 0, clip)[valid].sum() / n * 100)
    return out


def _disparity_scene(seed: int, h: int = 20, w: int = 24):
    rng = np.random.default_rng(seed)
    disp = rng.uniform(0.03, 0.26, (h, w))
    disp[2:5, 3:9] = 0.0  # no measurement
    disp[7, 7] = 0.4  # outside the valid range: the official code clips it to 0
    pred_disp = np.clip(disp + rng.normal(0, 0.02, (h, w)), 0.021, 0.3)
    return disp, pred_disp


def test_ddff12_protocol_matches_the_official_code():
    disp, pred_disp = _disparity_scene(0)
    official_target = np.where((disp >= 0.0202) & (disp <= 0.2825), disp, 0.0)
    expected = ddff_reference(pred_disp, official_target)
    depth = torch.from_numpy(np.where(disp > 0, FB / np.where(disp > 0, disp, 1), 7.0))
    mask = torch.from_numpy(disp > 0)
    got = protocol_metrics(pred=torch.from_numpy(FB / pred_disp), target=depth, mask=mask,
                           protocol="ddff12")
    for name in PROTOCOLS["ddff12"].metrics:
        assert got[name] == pytest.approx(expected[name], rel=1e-9, abs=1e-12), name
    assert got["pixels"] == float((official_target > 0).sum())


def test_batch_is_the_mean_of_the_images():
    scenes = [_disparity_scene(s) for s in (1, 2)]
    targets = [np.where((d >= 0.0202) & (d <= 0.2825), d, 0.0) for d, _ in scenes]
    refs = [ddff_reference(p, t) for (_, p), t in zip(scenes, targets, strict=True)]
    depth = torch.stack([torch.from_numpy(FB / np.where(t > 0, t, 1))[None] for t in targets])
    pred = torch.stack([torch.from_numpy(FB / p)[None] for _, p in scenes])
    mask = torch.stack([torch.from_numpy(t > 0)[None] for t in targets])
    got = protocol_metrics(pred=pred, target=depth, mask=mask, protocol="ddff12")
    for name in ("rmse", "bumpiness", "delta1"):
        assert got[name] == pytest.approx((refs[0][name] + refs[1][name]) / 2, rel=1e-9)


def test_bumpiness_against_scikit_image():
    rng = np.random.default_rng(4)
    pred, target = rng.random((9, 11)) * 0.1, rng.random((9, 11)) * 0.1
    target[0, :3] = 0
    expected = ddff_reference(pred, target, clip=0.05)["bumpiness"]
    got = bumpiness(pred=torch.from_numpy(pred), target=torch.from_numpy(target),
                    mask=torch.from_numpy(target > 0))
    assert float(got[0]) == pytest.approx(expected, rel=1e-10)
    with pytest.raises(TypeError, match="keyword"):
        bumpiness(torch.from_numpy(pred), torch.from_numpy(target), torch.ones(9, 11))


def test_fod500_protocol_clips_at_1_5_metres():
    rng = np.random.default_rng(5)
    gt = rng.uniform(0.1, 2.5, (16, 16))
    gt[0, :4] = 0.0
    pred = np.clip(gt * rng.uniform(0.8, 1.25, gt.shape), 0.05, 3.0)
    expected = ddff_reference(np.clip(pred, 0, 1.5), np.clip(gt, 0, 1.5))
    got = protocol_metrics(pred=torch.from_numpy(pred), target=torch.from_numpy(gt),
                           mask=torch.from_numpy(gt > 0), protocol="fod500")
    for name in PROTOCOLS["fod500"].metrics:
        assert got[name] == pytest.approx(expected[name], rel=1e-9, abs=1e-12), name


def test_zedd_protocol_matches_fossa_eval_depth():
    rng = np.random.default_rng(6)
    gt = rng.uniform(0.5, 12.0, (10, 14))
    gt[0, 0], gt[1, 1], gt[2, 2] = np.nan, 0.005, 2000.0  # invalid: NaN, below 0.01, above 1000
    pred = gt * rng.uniform(0.9, 1.2, gt.shape)
    pred[~np.isfinite(pred)] = 1.0
    keep = np.isfinite(gt) & (gt >= 0.01) & (gt <= 1000)
    p, g = pred[keep], gt[keep]
    thresh = np.maximum(g / p, p / g)
    dl = np.log(p) - np.log(g)
    expected = {
        "delta1.05": np.mean(thresh < 1.05), "delta1.15": np.mean(thresh < 1.15),
        "delta1": np.mean(thresh < 1.25), "delta2": np.mean(thresh < 1.5625),
        "delta3": np.mean(thresh < 1.953125), "abs_rel": np.mean(np.abs(p - g) / g),
        "sq_rel": np.mean((p - g) ** 2 / g), "mse": np.mean((p - g) ** 2),
        "rmse": np.sqrt(np.mean((p - g) ** 2)), "rmse_log": np.sqrt(np.mean(dl**2)),
        "log10": np.mean(np.abs(np.log10(p) - np.log10(g))),
        "silog": np.sqrt(np.mean(dl**2) - 0.5 * np.mean(dl) ** 2),
    }
    got = protocol_metrics(pred=torch.from_numpy(pred), target=torch.from_numpy(gt),
                           protocol="zedd")
    for name, value in expected.items():
        assert got[name] == pytest.approx(float(value), rel=1e-9), name
    assert set(PROTOCOL_METRIC_NAMES) <= set(got)


def test_protocol_agrees_with_depth_metrics_where_they_overlap():
    rng = np.random.default_rng(7)
    gt = torch.from_numpy(rng.uniform(1.0, 5.0, (1, 8, 8)))
    pred = gt * torch.from_numpy(rng.uniform(0.7, 1.4, (1, 8, 8)))
    ours = protocol_metrics(pred=pred, target=gt, protocol="zedd")
    eigen = depth_metrics(pred=pred, target=gt)
    for name in ("abs_rel", "sq_rel", "rmse", "rmse_log", "log10", "delta1", "delta2"):
        assert ours[name] == pytest.approx(eigen[name], rel=1e-9)


def test_protocol_errors():
    gt = torch.ones(1, 4, 4)
    with pytest.raises(ValueError, match="protocol must be one of"):
        protocol_metrics(pred=gt, target=gt, protocol="kitti")
    with pytest.raises(ValueError, match="no valid ground-truth pixel"):
        protocol_metrics(pred=gt, target=gt * 0, protocol="zedd")
    with pytest.raises(ValueError, match="finite and > 0"):
        protocol_metrics(pred=gt * 0, target=gt, protocol="zedd")
    with pytest.raises(TypeError, match="keyword"):
        protocol_metrics(gt, gt, protocol="zedd")


def test_format_table_number_format_keeps_small_values():
    table = format_table({"m": {"mse": 9.7e-4}}, metrics=("mse",), number_format="{:.4g}")
    assert "0.00097" in table and "MSE ↓" in table
    assert "0.200" in format_table({"c": {"abs_rel": 0.2}}, metrics=("abs_rel",))  # unchanged


def _sample(depth_value: float = 2.0, has_gt: bool = True):
    from optics import CameraSettings

    return {"image": torch.rand(3, 16, 16), "focused": torch.rand(3, 3, 16, 16),
            "camera": CameraSettings(0.05, 2.0, [1.0, 2.0, 4.0], 2e-5).to(torch.float32),
            "depth": torch.full((1, 16, 16), depth_value),
            "mask": torch.full((1, 16, 16), has_gt), "has_all_in_focus": False, "id": "s"}


def test_evaluate_benchmark_takes_any_method_and_skips_samples_without_depth():
    seen = []

    def method(sample):
        seen.append(sample["id"])
        return torch.full((1, 16, 16), 2.5)

    result = evaluate(method, [_sample(), _sample(has_gt=False)], "zedd",
                      report=lambda i, name, values: seen.append(i))
    assert result["images"] == 1 and result["skipped"] == 1 and seen == ["s", 0]
    assert result["abs_rel"] == pytest.approx(0.25)
    with pytest.raises(ValueError, match="no sample has ground-truth depth"):
        evaluate(method, [_sample(has_gt=False)], "zedd")
    with pytest.raises(ValueError, match="shape"):
        evaluate(lambda s: torch.ones(16, 16), [_sample()], "zedd")


def test_label_free_method_reads_the_stack_without_the_stand_in_image():
    method = label_free_method((0.5, 8.0), max_pixels=10_000)
    depth = method(_sample())
    assert depth.shape == (1, 16, 16) and bool((depth > 0).all())
    assert method.name == "auto"
    with pytest.raises(ValueError, match="needs an all-in-focus photo"):
        label_free_method((0.5, 8.0), "sweep")(_sample())


def test_network_method_covers_the_image_whole_or_in_tiles():
    import tempfile

    from models.evaluation import network_method
    from models.training import TrainConfig, Trainer

    samples = [{"image": torch.rand(3, 40, 56), "depth": torch.full((1, 40, 56), 2.0),
                "mask": torch.ones(1, 40, 56, dtype=torch.bool)}]
    cfg = TrainConfig(steps=1, batch_size=1, input_mode="aif", supervision="depth", width=4,
                      progress=False, out_dir=tempfile.mkdtemp(), device="cpu")
    trainer = Trainer(cfg, samples)
    whole = network_method(trainer.model)(samples[0])
    assert torch.equal(whole, trainer.predict(samples[0]["image"][None])[0])
    tiled = network_method(trainer.model, max_pixels=100, tile=16, overlap=8)(samples[0])
    assert tiled.shape == (1, 40, 56) and bool(torch.isfinite(tiled).all())
    assert bool((tiled >= cfg.depth_min).all() and (tiled <= cfg.depth_max).all())
    with pytest.raises(ValueError, match="tile must be > 0"):
        network_method(trainer.model, max_pixels=100, tile=0)
