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

The focal-stack benchmarks score with protocols of their own: `models.protocols`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from typing import TypeVar

import torch
from torch import Tensor

from optics.checks import check_depth_bounds

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


def maps_by_keyword(fn: _F) -> _F:
    """Decorate a metric so that it refuses positional depth maps: `pred` and `target` swapped
    silently give wrong numbers (Monodepth2's `compute_errors(gt, pred)` has the opposite order
    to most code)."""

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
    given, crop = crop, CROPS.get(crop, ()) if isinstance(crop, str) else crop
    if len(crop) != 4 or not (0 <= crop[0] < crop[1] <= 1 and 0 <= crop[2] < crop[3] <= 1):
        raise ValueError(f"crop must be None, one of {sorted(CROPS)} or 4 fractions (top, "
                         "bottom, left, right) with 0 <= top < bottom <= 1 and 0 <= left < "
                         f"right <= 1, got {given!r}")
    top, bottom = int(crop[0] * height), int(crop[1] * height)
    left, right = int(crop[2] * width), int(crop[3] * width)
    mask[top:bottom, left:right] = True
    return mask


def as_map_batch(name: str, tensor: Tensor) -> Tensor:
    """A depth map or mask of shape `(H,W)`, `(1,H,W)` or `(B,1,H,W)` as `(B,1,H,W)`, `B >= 1`;
    anything else refused naming `name` (the metrics' and the protocols' input check).

    Example:
        >>> as_map_batch("target", torch.ones(4, 5)).shape
        torch.Size([1, 1, 4, 5])
    """
    if not isinstance(tensor, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(tensor).__name__}")
    batch = tensor[(None,) * (4 - tensor.ndim)] if tensor.ndim in (2, 3) else tensor
    if batch.ndim != 4 or batch.shape[1] != 1 or batch.shape[0] == 0:
        maps = batch.ndim == 4 and batch.shape[1] == 1
        raise ValueError(f"{name} must " + ("hold at least one image (B >= 1), got an empty "
                         "batch of shape" if maps else "have shape (H,W), (1,H,W) or (B,1,H,W), "
                         "got") + f" {tuple(tensor.shape)}")
    return batch


def same_shape_batches(**maps: Tensor) -> list[Tensor]:
    """The maps as `(B,1,H,W)` batches (`as_map_batch`), refused unless all of one shape.

    Example:
        >>> same_shape_batches(pred=torch.ones(2, 3), target=torch.ones(3, 2))
        Traceback (most recent call last):
        ...
        ValueError: pred and target must have the same shape, got (1, 1, 2, 3) and (1, 1, 3, 2)
    """
    batches = [as_map_batch(name, tensor) for name, tensor in maps.items()]
    if len({tuple(b.shape) for b in batches}) > 1:
        names, shapes = list(maps), [str(tuple(b.shape)) for b in batches]
        raise ValueError(f"{', '.join(names[:-1])} and {names[-1]} must have the same shape, got "
                         f"{', '.join(shapes[:-1])} and {shapes[-1]}")
    return batches


def refuse_empty_images(valid: Tensor, least: int = 1, why: str = "") -> None:
    """Raise `ValueError` naming the first image of the `(B,1,H,W)` map `valid` with fewer
    than `least` (1 or 2) valid ground-truth pixels; `why` ends the message.

    Example:
        >>> refuse_empty_images(torch.zeros(1, 1, 2, 2, dtype=torch.bool))
        Traceback (most recent call last):
        ...
        ValueError: image 0 has no valid ground-truth pixel
    """
    short = (valid.flatten(1).sum(1) < least).nonzero()
    if len(short):
        amount = "no valid ground-truth pixel" if least == 1 else \
            "fewer than two valid ground-truth pixels"
        raise ValueError(f"image {int(short[0])} has {amount}{why}")


def refuse_bad_pixels(name: str, tensor: Tensor, bad: Tensor, allowed: str) -> None:
    """Raise `ValueError` if any pixel of the boolean map `bad` is set: `name` must be `allowed`
    there; the message gives how many are not and the first one's value and index.

    Example:
        >>> depth = torch.tensor([[1.0, -2.0]])
        >>> refuse_bad_pixels("depth", depth, depth <= 0, "> 0 metres")
        Traceback (most recent call last):
        ...
        ValueError: depth must be > 0 metres, got 1 value(s) that are not, the first -2.0 at index (0, 1)
    """
    if bool(bad.any()):
        first = tuple(int(i) for i in bad.nonzero()[0].tolist())
        raise ValueError(f"{name} must be {allowed}, got {int(bad.sum())} value(s) that are not, "
                         f"the first {float(tensor[first])!r} at index {first}")


def check_prediction(pred: Tensor, valid: Tensor, positive: bool = True) -> None:
    """Refuse a prediction that is not finite (and > 0 metres when `positive`) at a `valid`
    pixel; pixels outside `valid` may hold anything.

    Example:
        >>> pred = torch.tensor([[2.0, float("nan")]])
        >>> check_prediction(pred, torch.tensor([[True, False]]))  # the NaN is not scored
    """
    good = torch.isfinite(pred) & (pred > 0) if positive else torch.isfinite(pred)
    allowed = "finite and > 0 metres" if positive else "finite"
    refuse_bad_pixels("pred", pred, valid & ~good, f"{allowed} at every valid pixel")


@maps_by_keyword
def valid_mask(*, target: Tensor, mask: Tensor | None = None, min_depth: float = 1e-3,
               max_depth: float | None = None, crop: str | Sequence[float] | None = None) -> Tensor:
    """Pixels that count: `mask`, ground truth in `(min_depth, max_depth)`, inside `crop`.

    Raises:
        ValueError: for `min_depth < 0` (or not finite), or `max_depth <= min_depth`.

    Example:
        >>> valid_mask(target=torch.tensor([[0.0, 2.0, float("nan")]])).int()
        tensor([[[[0, 1, 0]]]], dtype=torch.int32)
    """
    check_depth_bounds(min_depth, max_depth, why=" (ground truth at or below it is ignored, so "
                       "that every scored depth is > 0)", high_optional=True)
    target = as_map_batch("target", target)
    valid = torch.isfinite(target) & (target > min_depth)
    if max_depth is not None:
        valid &= target < max_depth
    if mask is not None:
        valid &= as_map_batch("mask", mask).to(torch.bool)
    return valid & crop_mask(*target.shape[-2:], crop, target.device)


@maps_by_keyword
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
            Finite and >= 0 (0 keeps every positive depth: the metrics need `g > 0`).
        max_depth: depth cap: ground truth at or beyond it is ignored, predictions clamped to it.
        crop: `None`, `"garg"`, `"eigen"` or `(top, bottom, left, right)` fractions.
        median_scaling: scale each prediction by `median(target) / median(pred)` first.

    Returns:
        dict of the `METRIC_NAMES` (plus `median_scale` when `median_scaling`).

    Raises:
        ValueError: for an empty batch, `min_depth < 0` or `max_depth <= min_depth`, if an
            image has no valid pixel or a prediction is not finite and positive at a valid pixel.

    Example:
        >>> m = depth_metrics(pred=torch.tensor([[2.0, 4.0]]), target=torch.tensor([[2.0, 5.0]]))
        >>> round(m["abs_rel"], 4), round(m["rmse"], 4), m["delta1"]
        (0.1, 0.7071, 0.5)
    """
    pred, target = same_shape_batches(pred=pred, target=target)
    valid = valid_mask(target=target, mask=mask, min_depth=min_depth, max_depth=max_depth,
                       crop=crop)
    check_prediction(pred.detach(), valid)
    refuse_empty_images(valid, why=" (check mask, min_depth, max_depth and crop)")
    totals: dict[str, float] = {}
    for d_all, g_all, v in zip(pred.detach(), target.detach(), valid, strict=True):
        d, g = d_all[v].double(), g_all[v].double()
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


@maps_by_keyword
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
    valid = torch.isfinite(g) & (g > 0)
    refuse_empty_images(valid[None, None], why=" (finite, > 0) in target")
    g = g[valid]
    g, _ = g.sort()
    weights = torch.cumsum(1.0 / g, 0)
    index = int(torch.searchsorted(weights, weights[-1] / 2))
    return float(g[min(index, g.numel() - 1)])


@maps_by_keyword
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
        ValueError: maps of different shapes, an empty batch, an image with fewer than two valid
            pixels, or a prediction that is not finite at a valid pixel (its order is undefined).

    Example:
        >>> target = torch.tensor([[1.0, 2.0, 3.0, 4.0]])
        >>> round(depth_order(pred=target ** 2, target=target), 6)  # the same order
        1.0
        >>> round(depth_order(pred=1 / target, target=target), 6)  # near and far swapped
        -1.0
    """
    pred, target = same_shape_batches(pred=pred, target=target)
    valid = valid_mask(target=target, mask=mask, max_depth=max_depth, crop=crop)
    check_prediction(pred.detach(), valid, positive=False)
    refuse_empty_images(valid, least=2)
    total = 0.0
    for d, g, v in zip(pred.detach(), target.detach(), valid, strict=True):
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


def at_depth_limits(depth: Tensor, depth_min: float, depth_max: float,
                    tolerance: float = 1e-3) -> Tensor:
    """The share of the pixels of `depth` at `depth_min` or `depth_max` (within `tolerance` of
    the range), a 0-d tensor: near 1, a network collapsed to the limits of its output.

    Example:
        >>> at_depth_limits(torch.tensor([1.0, 5.0, 10.0, 9.999]), 1.0, 10.0)
        tensor(0.7500)
    """
    tol = tolerance * (depth_max - depth_min)
    depth = depth.detach()
    return ((depth <= depth_min + tol) | (depth >= depth_max - tol)).float().mean()


def confident_half_error(error: Tensor, confidence: Tensor) -> float:
    """How well a confidence map ranks per-pixel errors: the mean `error` over the more
    confident half of the pixels divided by the mean over all of them (1: no better than
    chance; 0: the confident half holds no error). Both tensors hold the same pixels, any shape.

    The errors must be finite and >= 0, and not all 0: without any error the ratio is 0 / 0
    (every ranking is as good as any other), so such a map is refused rather than scored NaN.
    The confidence must not be NaN (it has no rank).

    Raises:
        ValueError: for maps of other shapes or empty ones, an error that is negative, not
            finite or 0 everywhere, or a NaN confidence.

    Example:
        >>> confident_half_error(torch.tensor([0.0, 0.0, 1.0, 3.0]),
        ...                      torch.tensor([0.9, 0.8, 0.2, 0.1]))
        0.0
    """
    if error.shape != confidence.shape or error.numel() == 0:
        raise ValueError(f"error and confidence must be non-empty and of one shape, got "
                         f"{tuple(error.shape)} and {tuple(confidence.shape)}")
    error, confidence = error.detach().flatten().double(), confidence.detach().flatten()
    refuse_bad_pixels("error", error, ~(torch.isfinite(error) & (error >= 0)),
                       "finite and >= 0 at every pixel")
    refuse_bad_pixels("confidence", confidence, torch.isnan(confidence), "a number (not NaN)")
    if not bool(error.sum() > 0):
        raise ValueError(f"error must not be 0 at every pixel (the ratio to its mean would be "
                         f"0 / 0), got {error.numel()} pixel(s) of error 0")
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
