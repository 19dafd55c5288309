"""Depth evaluation metrics (Eigen et al. 2014 conventions) and the paper-style table.

Per image, over valid pixels (mask, ground truth inside `(min_depth, max_depth)`, optional crop),
with the prediction clamped to `[min_depth, max_depth]`; a batch is the mean over its images:

=============  ========================================================  ===========
name           definition                                                better
=============  ========================================================  ===========
`abs_rel`    `mean(|d - g| / g)`                                     lower
`sq_rel`     `mean((d - g)^2 / g)`                                   lower
`rmse`       `sqrt(mean((d - g)^2))` (metres)                        lower
`rmse_log`   `sqrt(mean((ln d - ln g)^2))` (natural log)             lower
`log10`      `mean(|log10 d - log10 g|)`                             lower
`deltaK`     share of pixels with `max(d/g, g/d) < 1.25^K`, K=1,2,3  higher
=============  ========================================================  ===========

Median scaling (multiply the prediction by `median(g) / median(d)`) is off by default: our
depths are metric. When on, the returned dict also holds the mean `median_scale`.

The focal-stack benchmarks have protocols of their own (`PROTOCOLS`, `protocol_metrics`): the
space the numbers are computed in (DDFF-12 scores disparity), the valid range and caps, MSE,
silog, the thresholds 1.05 and 1.15, and DDFF-12's bumpiness, each as the benchmark's own
evaluation code computes it, so that a number printed here stands next to the paper's table.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TypeVar

import torch
import torch.nn.functional as F
from torch import Tensor

METRIC_NAMES = ("abs_rel", "sq_rel", "rmse", "rmse_log", "log10", "delta1", "delta2", "delta3")
HIGHER_IS_BETTER = frozenset({"delta1", "delta2", "delta3", "delta1.05", "delta1.15",
                              "depth_order"})
LABELS = {
    "abs_rel": "abs rel", "sq_rel": "sq rel", "rmse": "RMSE", "rmse_log": "RMSE log",
    "log10": "log10", "delta1": "d<1.25", "delta2": "d<1.25^2", "delta3": "d<1.25^3",
    "mse": "MSE", "silog": "silog", "delta1.05": "d<1.05", "delta1.15": "d<1.15",
    "bumpiness": "bump", "depth_order": "order",
}
#: KITTI crops as fractions (top, bottom, left, right) of the image height and width.
CROPS = {
    "garg": (0.40810811, 0.99189189, 0.03594771, 0.96405229),
    "eigen": (0.3324324, 0.91351351, 0.0359477, 0.96405229),
}


_F = TypeVar("_F", bound=Callable)


def _maps_by_keyword(fn: _F) -> _F:
    """Refuse positional depth maps: `pred` and `target` swapped silently give wrong numbers
    (Monodepth2's `compute_errors(gt, pred)` has the opposite order to most code)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if args:
            raise TypeError(
                f"{fn.__name__} takes the depth maps by keyword, e.g. "
                f"{fn.__name__}(pred=prediction, target=ground_truth, mask=valid): positional "
                f"maps are too easy to swap (got {len(args)} positional argument(s))"
            )
        return fn(**kwargs)

    return wrapper  # type: ignore[return-value]


def crop_mask(height: int, width: int, crop: str | Sequence[float] | None,
              device: torch.device | None = None) -> Tensor:
    """Boolean `(H, W)` mask of an evaluation crop.

    Args:
        height: image height in pixels.
        width: image width in pixels.
        crop: `None` (everything), `"garg"` or `"eigen"` (KITTI), or fractions
            `(top, bottom, left, right)` of the height and width.

    Example:
        >>> crop_mask(4, 4, (0.5, 1.0, 0.0, 0.5)).int()
        tensor([[0, 0, 0, 0],
                [0, 0, 0, 0],
                [1, 1, 0, 0],
                [1, 1, 0, 0]], dtype=torch.int32)
    """
    mask = torch.zeros(height, width, dtype=torch.bool, device=device)
    if crop is None:
        return mask.fill_(True)
    if isinstance(crop, str):
        if crop not in CROPS:
            raise ValueError(f"crop must be None, one of {sorted(CROPS)} or 4 fractions, "
                             f"got {crop!r}")
        crop = CROPS[crop]
    if len(crop) != 4 or not (0 <= crop[0] < crop[1] <= 1 and 0 <= crop[2] < crop[3] <= 1):
        raise ValueError(f"crop fractions must be (top, bottom, left, right) with "
                         f"0 <= top < bottom <= 1 and 0 <= left < right <= 1, got {crop!r}")
    top, bottom = int(crop[0] * height), int(crop[1] * height)
    left, right = int(crop[2] * width), int(crop[3] * width)
    mask[top:bottom, left:right] = True
    return mask


def _as_batch(name: str, tensor: Tensor) -> Tensor:
    if not isinstance(tensor, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(tensor).__name__}")
    if tensor.ndim == 2:
        return tensor[None, None]
    if tensor.ndim == 3:
        return tensor[None]
    if tensor.ndim == 4 and tensor.shape[1] == 1:
        return tensor
    raise ValueError(f"{name} must have shape (H,W), (1,H,W) or (B,1,H,W), "
                     f"got {tuple(tensor.shape)}")


@_maps_by_keyword
def valid_mask(*, target: Tensor, mask: Tensor | None = None, min_depth: float = 1e-3,
               max_depth: float | None = None, crop: str | Sequence[float] | None = None) -> Tensor:
    """Pixels that count: `mask`, ground truth in `(min_depth, max_depth)`, inside `crop`."""
    target = _as_batch("target", target)
    valid = torch.isfinite(target) & (target > min_depth)
    if max_depth is not None:
        valid &= target < max_depth
    if mask is not None:
        valid &= _as_batch("mask", mask).to(torch.bool)
    return valid & crop_mask(*target.shape[-2:], crop, target.device)


@_maps_by_keyword
def depth_metrics(
    *, pred: Tensor, target: Tensor, mask: Tensor | None = None, min_depth: float = 1e-3,
    max_depth: float | None = None, crop: str | Sequence[float] | None = None,
    median_scaling: bool = False,
) -> dict[str, float]:
    """Depth metrics of `pred` against `target` (both metres), averaged over the batch.

    The maps are keyword-only (a positional call raises `TypeError` with this hint): swapping
    prediction and ground truth would silently give other numbers.

    Args:
        pred: predicted depth `(H,W)`, `(1,H,W)` or `(B,1,H,W)`, metres.
        target: ground truth of the same shape, metres.
        mask: optional boolean mask of valid ground truth (same shape).
        min_depth: ground truth at or below this is ignored; predictions are clamped to it.
        max_depth: depth cap: ground truth at or beyond it is ignored, predictions clamped to it.
        crop: `None`, `"garg"`, `"eigen"` or `(top, bottom, left, right)` fractions.
        median_scaling: scale each prediction by `median(target) / median(pred)` first.

    Returns:
        dict of the `METRIC_NAMES` (plus `median_scale` when `median_scaling`).

    Raises:
        ValueError: if an image has no valid pixel or a prediction is not finite and positive.

    Example:
        >>> m = depth_metrics(pred=torch.tensor([[2.0, 4.0]]), target=torch.tensor([[2.0, 5.0]]))
        >>> round(m["abs_rel"], 4), round(m["rmse"], 4), m["delta1"]
        (0.1, 0.7071, 0.5)
    """
    pred, target = _as_batch("pred", pred), _as_batch("target", target)
    if pred.shape != target.shape:
        raise ValueError(f"pred and target must have the same shape, got {tuple(pred.shape)} "
                         f"and {tuple(target.shape)}")
    valid = valid_mask(target=target, mask=mask, min_depth=min_depth, max_depth=max_depth,
                       crop=crop)
    totals: dict[str, float] = {}
    for d_all, g_all, v in zip(pred.detach(), target.detach(), valid, strict=True):
        d, g = d_all[v].double(), g_all[v].double()
        if g.numel() == 0:
            raise ValueError("an image has no valid ground-truth pixel (check mask, min_depth, "
                             "max_depth and crop)")
        if not bool(torch.all(torch.isfinite(d) & (d > 0))):
            raise ValueError("pred must be finite and > 0 metres at every valid pixel")
        values = {}
        if median_scaling:
            values["median_scale"] = float(g.median() / d.median())
            d = d * values["median_scale"]
        d = d.clamp(min_depth, max_depth) if max_depth is not None else d.clamp_min(min_depth)
        ratio = torch.maximum(d / g, g / d)
        values.update(
            abs_rel=float(((d - g).abs() / g).mean()),
            sq_rel=float(((d - g) ** 2 / g).mean()),
            rmse=float(((d - g) ** 2).mean().sqrt()),
            rmse_log=float(((d.log() - g.log()) ** 2).mean().sqrt()),
            log10=float((d.log10() - g.log10()).abs().mean()),
            delta1=float((ratio < 1.25).double().mean()),
            delta2=float((ratio < 1.25**2).double().mean()),
            delta3=float((ratio < 1.25**3).double().mean()),
        )
        for key, value in values.items():
            totals[key] = totals.get(key, 0.0) + value
    return {key: value / pred.shape[0] for key, value in totals.items()}


@_maps_by_keyword
def best_constant_depth(*, target: Tensor, mask: Tensor | None = None) -> float:
    """The constant depth (metres) with the lowest abs rel: the median of `target` weighted by
    `1 / target` over valid pixels (an oracle baseline; it looks at the ground truth).

    Example:
        >>> best_constant_depth(target=torch.tensor([1.0, 2.0, 4.0]))  # abs rel 0.42; 2 m would give 0.5
        1.0
    """
    g = target.detach().reshape(-1).double()
    if mask is not None:
        g = g[mask.reshape(-1).to(torch.bool)]
    g = g[torch.isfinite(g) & (g > 0)]
    if g.numel() == 0:
        raise ValueError("target has no valid (finite, > 0) depth")
    g, _ = g.sort()
    weights = torch.cumsum(1.0 / g, 0)
    index = int(torch.searchsorted(weights, weights[-1] / 2))
    return float(g[min(index, g.numel() - 1)])


@_maps_by_keyword
def depth_order(*, pred: Tensor, target: Tensor, mask: Tensor | None = None,
                max_depth: float | None = None, crop: str | Sequence[float] | None = None,
                ) -> float:
    """Spearman's rank correlation of `pred` and `target` over the valid pixels of each image,
    averaged over the batch: whether a prediction orders the scene's depths (1: in the same order,
    0: no relation, -1: reversed), whatever its scale and level. Abs rel cannot tell a network that
    learned depth from one that shrinks toward a constant; this can. Ties share their mean rank;
    a constant map scores 0.

    Args:
        pred: predicted depth `(H,W)`, `(1,H,W)` or `(B,1,H,W)`, metres.
        target: ground truth of the same shape, metres.
        mask: optional boolean mask of valid ground truth (same shape).
        max_depth: ground truth at or beyond it is ignored (as in `depth_metrics`).
        crop: `None`, `"garg"`, `"eigen"` or `(top, bottom, left, right)` fractions.

    Raises:
        ValueError: maps of different shapes, or an image with fewer than two valid pixels.

    Example:
        >>> target = torch.tensor([[1.0, 2.0, 3.0, 4.0]])
        >>> round(depth_order(pred=target ** 2, target=target), 6)  # the same order
        1.0
        >>> round(depth_order(pred=1 / target, target=target), 6)  # near and far swapped
        -1.0
    """
    pred, target = _as_batch("pred", pred), _as_batch("target", target)
    if pred.shape != target.shape:
        raise ValueError(f"pred and target must have the same shape, got {tuple(pred.shape)} "
                         f"and {tuple(target.shape)}")
    valid = valid_mask(target=target, mask=mask, max_depth=max_depth, crop=crop)
    total = 0.0
    for d, g, v in zip(pred.detach(), target.detach(), valid, strict=True):
        if int(v.sum()) < 2:
            raise ValueError("an image has fewer than two valid ground-truth pixels")
        ranks = torch.stack([_mean_ranks(d[v].double()), _mean_ranks(g[v].double())])
        ranks = ranks - ranks.mean(1, keepdim=True)
        norms = ranks.norm(dim=1)
        total += float((ranks[0] * ranks[1]).sum() / (norms[0] * norms[1])) \
            if bool((norms > 0).all()) else 0.0
    return total / pred.shape[0]


def _mean_ranks(x: Tensor) -> Tensor:
    """Ranks 0..n-1 of `x`, tied values sharing the mean of their ranks."""
    values, inverse, counts = torch.unique(x, return_inverse=True, return_counts=True)
    first = torch.cumsum(counts, 0) - counts
    return (first + (counts - 1) / 2).to(x.dtype)[inverse]


def confident_half_error(error: Tensor, confidence: Tensor) -> float:
    """How well a confidence map ranks per-pixel errors: the mean `error` over the more
    confident half of the pixels divided by the mean over all of them (1: no better than
    chance; 0: the confident half holds no error). Both tensors hold the same pixels, any shape.

    Example:
        >>> confident_half_error(torch.tensor([0.0, 0.0, 1.0, 3.0]),
        ...                      torch.tensor([0.9, 0.8, 0.2, 0.1]))
        0.0
    """
    if error.shape != confidence.shape or error.numel() == 0:
        raise ValueError(f"error and confidence must be non-empty and of one shape, got "
                         f"{tuple(error.shape)} and {tuple(confidence.shape)}")
    error, confidence = error.detach().flatten().double(), confidence.detach().flatten()
    top = confidence.argsort(descending=True)[: max(1, error.numel() // 2)]
    return float(error[top].mean() / error.mean())


def format_table(results: Mapping[str, Mapping[str, float]],
                 metrics: Sequence[str] = METRIC_NAMES, number_format: str = "{:.3f}") -> str:
    """A paper-style Markdown table: one row per method, one column per metric.

    Arrows mark whether lower or higher is better; a method with a `median_scale` entry is
    marked `(median scaled)`. `number_format` formats each value (e.g. `"{:.4g}"` for
    DDFF-12's MSE, about 1e-3).

    Example:
        >>> print(format_table({"constant": {"abs_rel": 0.2, "delta1": 0.55}},
        ...                    metrics=("abs_rel", "delta1")))
        | method   | abs rel ↓ | d<1.25 ↑ |
        |----------|-----------|----------|
        | constant |     0.200 |    0.550 |
    """
    names = [name + (" (median scaled)" if "median_scale" in row else "")
             for name, row in results.items()]
    headers = ["method"] + [LABELS.get(m, m) + (" ↑" if m in HIGHER_IS_BETTER else " ↓")
                            for m in metrics]
    rows = [[name] + [number_format.format(row[m]) if m in row else "-" for m in metrics]
            for name, row in zip(names, results.values(), strict=True)]
    widths = [max(len(r[i]) for r in [headers, *rows]) for i in range(len(headers))]

    def line(cells: Sequence[str]) -> str:
        first = cells[0].ljust(widths[0])
        rest = [c.rjust(w) for c, w in zip(cells[1:], widths[1:], strict=True)]
        return "| " + " | ".join([first, *rest]) + " |"

    separator = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([line(headers), separator, *(line(r) for r in rows)])


# ---- the focal-stack benchmarks' own protocols -------------------------------------------------

#: Threshold of each delta accuracy: share of pixels with `max(d/g, g/d) < threshold`.
DELTA_THRESHOLDS = {"delta1.05": 1.05, "delta1.15": 1.15, "delta1": 1.25, "delta2": 1.25**2,
                    "delta3": 1.25**3}
#: Every name `protocol_metrics` returns.
PROTOCOL_METRIC_NAMES = ("mse", "rmse", "rmse_log", "abs_rel", "sq_rel", "log10", "silog",
                         *DELTA_THRESHOLDS, "bumpiness")


@dataclass(frozen=True)
class Protocol:
    """How a benchmark scores a depth map (lengths in metres, disparity in pixels).

    Args:
        name: the benchmark.
        metrics: the columns of its paper's table, in order.
        source: the paper table (and evaluation code) the numbers match.
        disparity_scale: score disparity `disparity_scale / depth` (pixels; `f * B` in
            metres times pixels) instead of depth when set.
        valid: ground truth counts inside this closed range (in the scored space).
        cap: prediction and ground truth are clipped to at most this before scoring.
        percent: deltas as percentages (the evaluation code multiplies them by 100).
    """

    name: str
    metrics: tuple[str, ...]
    source: str
    disparity_scale: float | None = None
    valid: tuple[float, float] = (0.0, math.inf)
    cap: float | None = None
    percent: bool = False


_DDFF_COLUMNS = ("mse", "rmse", "rmse_log", "abs_rel", "sq_rel", "delta1", "delta2", "delta3",
                 "bumpiness")
#: The benchmarks' protocols by dataset name.
PROTOCOLS: dict[str, Protocol] = {
    "ddff12": Protocol(
        "ddff12", _DDFF_COLUMNS,
        "Hazirbas et al., Deep Depth From Focus (ACCV 2018), Table 2; the official evaluation "
        "(soyers/ddff-pytorch BaseDDFFEval, also DFV's eval_DDFF12.py): disparity in pixels, "
        "deltas and bumpiness x100. FOSSA's Table 4 prints the deltas as fractions",
        # f_sub * B of the toolbox: 521.4052 px x 1982.02508 / 7317.02064 mm
        disparity_scale=521.4052 * 1982.02508 / 7317.02064 * 1e-3,
        valid=(0.0202, 0.2825), percent=True),
    "fod500": Protocol(
        "fod500", _DDFF_COLUMNS,
        "Yang et al., Deep Depth from Focus with Differential Focus Volume (CVPR 2022), FoD500 "
        "table (eval_FoD500.py): depth in metres clipped at 1.5 m, deltas and bumpiness x100",
        valid=(1e-9, math.inf), cap=1.5, percent=True),
    "zedd": Protocol(
        "zedd", ("delta1.05", "delta1.15", "delta1", "abs_rel", "sq_rel", "rmse", "rmse_log"),
        "Zuo et al., Zero-Shot Depth from Defocus (2026), Table 2 (FOSSA util/metric.py "
        "eval_depth): depth in metres, ground truth in [0.01, 1000] m, deltas as fractions",
        valid=(0.01, 1000.0)),
}


def _scharr(image: Tensor, axis: int) -> Tensor:
    """scikit-image's `scharr_h` (axis 0) or `scharr_v` (axis 1) of `(B,1,H,W)`: the central
    difference `x[i+1] - x[i-1]` along `axis`, smoothed by `[3, 10, 3] / 16` across it, edge
    pixels repeated (scikit-image's `mode="reflect"`)."""
    smooth = torch.tensor([3.0, 10.0, 3.0], dtype=image.dtype, device=image.device) / 16
    edge = torch.tensor([-1.0, 0.0, 1.0], dtype=image.dtype, device=image.device)
    kernel = edge[:, None] * smooth[None, :] if axis == 0 else smooth[:, None] * edge[None, :]
    return F.conv2d(F.pad(image, (1, 1, 1, 1), mode="replicate"), kernel[None, None])


@_maps_by_keyword
def bumpiness(*, pred: Tensor, target: Tensor, mask: Tensor, clip: float = 0.05) -> Tensor:
    """DDFF-12's bumpiness per image `(B,)`: the Frobenius norm of the Hessian of
    `pred - target` (Scharr derivatives, each clipped at `clip`), summed over `mask` and divided
    by its pixel count, x100. Outside `mask` the target counts as 0, as in the official code
    (`BaseDDFFEval`). Both maps in the scored space (DDFF-12: disparity in pixels).

    Image borders follow the current scikit-image (edge pixels repeated); versions before 0.19
    zeroed the outer pixel of each derivative, which changes border pixels only.

    Example:
        >>> target = torch.arange(16.0).reshape(1, 1, 4, 4) / 4
        >>> mask = torch.ones(1, 1, 4, 4, dtype=torch.bool)
        >>> bumpiness(pred=target + 0.5, target=target, mask=mask)  # an offset has no curvature
        tensor([0.], dtype=torch.float64)
    """
    pred, target = _as_batch("pred", pred).double(), _as_batch("target", target).double()
    mask = _as_batch("mask", mask).to(torch.bool)
    diff = pred - torch.where(mask, target, torch.zeros_like(target))
    dx, dy = _scharr(diff, 1), _scharr(diff, 0)
    norm = torch.sqrt(_scharr(dx, 1) ** 2 + _scharr(dx, 0) ** 2 + _scharr(dy, 0) ** 2
                      + _scharr(dy, 1) ** 2).clamp(0, clip)
    count = mask.flatten(1).sum(1).clamp_min(1)
    return (norm * mask).flatten(1).sum(1) / count * 100


@_maps_by_keyword
def protocol_metrics(*, pred: Tensor, target: Tensor, mask: Tensor | None = None,
                     protocol: str | Protocol) -> dict[str, float]:
    """The metrics of a benchmark's protocol (`PROTOCOLS`), averaged over the batch's images
    (each image's value first, as the benchmarks' code does).

    Args:
        pred: predicted depth `(H,W)`, `(1,H,W)` or `(B,1,H,W)`, metres, finite and > 0.
        target: ground-truth depth of the same shape, metres.
        mask: where the ground truth is a measurement (combined with the protocol's range).
        protocol: a name of `PROTOCOLS` or a `Protocol`.

    Returns:
        every name of `PROTOCOL_METRIC_NAMES` (the protocol's table shows `protocol.metrics`),
        in the protocol's space and units, plus `pixels`, the mean count of valid pixels.

    Raises:
        ValueError: for an unknown protocol, shapes that differ, an image without valid
            ground truth, or a prediction that is not finite and positive where it counts.

    Example:
        >>> m = protocol_metrics(pred=torch.tensor([[2.0, 4.0]]), target=torch.tensor([[2.0, 5.0]]),
        ...                      protocol="zedd")
        >>> round(m["abs_rel"], 4), m["delta1.05"], m["delta1"]
        (0.1, 0.5, 0.5)
    """
    if isinstance(protocol, str):
        if protocol not in PROTOCOLS:
            raise ValueError(f"protocol must be one of {sorted(PROTOCOLS)} or a Protocol, got "
                             f"{protocol!r}")
        protocol = PROTOCOLS[protocol]
    pred, target = _as_batch("pred", pred).detach().double(), _as_batch("target", target).detach().double()
    if pred.shape != target.shape:
        raise ValueError(f"pred and target must have the same shape, got {tuple(pred.shape)} "
                         f"and {tuple(target.shape)}")
    valid = torch.isfinite(target) & (target > 0)
    if mask is not None:
        valid &= _as_batch("mask", mask).to(torch.bool)
    if not bool(torch.all(torch.isfinite(pred[valid]) & (pred[valid] > 0))):
        raise ValueError("pred must be finite and > 0 metres at every valid pixel")
    if protocol.disparity_scale is not None:  # score disparity: scale / depth
        pred = protocol.disparity_scale / pred.clamp_min(1e-12)
        target = torch.where(valid, protocol.disparity_scale / target.clamp_min(1e-12), target)
    if protocol.cap is not None:
        pred, target = pred.clamp(max=protocol.cap), target.clamp(max=protocol.cap)
    valid &= (target >= protocol.valid[0]) & (target <= protocol.valid[1])
    scale = 100.0 if protocol.percent else 1.0
    bumps = bumpiness(pred=pred, target=target, mask=valid)
    totals: dict[str, float] = {}
    for i, (d_all, g_all, v) in enumerate(zip(pred, target, valid, strict=True)):
        d, g = d_all[v], g_all[v]
        if g.numel() == 0:
            raise ValueError(f"image {i} has no valid ground-truth pixel for the {protocol.name} "
                             f"protocol (valid range {protocol.valid})")
        log_diff = d.log() - g.log()
        ratio = torch.maximum(d / g, g / d)
        values = {
            "mse": float(((d - g) ** 2).mean()), "rmse": float(((d - g) ** 2).mean().sqrt()),
            "rmse_log": float((log_diff**2).mean().sqrt()),
            "abs_rel": float(((d - g).abs() / g).mean()), "sq_rel": float(((d - g) ** 2 / g).mean()),
            "log10": float((d.log10() - g.log10()).abs().mean()),
            "silog": float(((log_diff**2).mean() - 0.5 * log_diff.mean() ** 2).clamp_min(0).sqrt()),
            **{k: float((ratio < t).double().mean()) * scale for k, t in DELTA_THRESHOLDS.items()},
            "bumpiness": float(bumps[i]), "pixels": float(v.sum()),
        }
        for key, value in values.items():
            totals[key] = totals.get(key, 0.0) + value
    return {key: value / pred.shape[0] for key, value in totals.items()}
