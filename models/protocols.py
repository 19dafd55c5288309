"""The focal-stack benchmarks' own protocols (`PROTOCOLS`, `protocol_metrics`).

Each benchmark's paper scores depth its own way: the space the numbers are computed in (DDFF-12
scores disparity), the valid range and caps, MSE, silog, the thresholds 1.05 and 1.15, and
DDFF-12's bumpiness. `protocol_metrics` computes them as the benchmark's own evaluation code
does, so that a number printed here stands next to the paper's table. The depth metrics of the
Eigen et al. protocol are `models.metrics`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from .metrics import (
    as_map_batch,
    check_prediction,
    maps_by_keyword,
    refuse_bad_pixels,
    refuse_empty_images,
    same_shape_batches,
)

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


def as_protocol(protocol: str | Protocol) -> Protocol:
    """The `Protocol` named `protocol` (a `Protocol` as it is).

    Example:
        >>> as_protocol("zedd").valid
        (0.01, 1000.0)
    """
    if isinstance(protocol, Protocol):
        return protocol
    if not isinstance(protocol, str) or protocol not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {sorted(PROTOCOLS)} or a Protocol, got "
                         f"{protocol!r}")
    return PROTOCOLS[protocol]


def _scharr(image: Tensor, axis: int) -> Tensor:
    """scikit-image's `scharr_h` (axis 0) or `scharr_v` (axis 1) of `(B,1,H,W)`: the central
    difference `x[i+1] - x[i-1]` along `axis`, smoothed by `[3, 10, 3] / 16` across it, edge
    pixels repeated (scikit-image's `mode="reflect"`)."""
    smooth = torch.tensor([3.0, 10.0, 3.0], dtype=image.dtype, device=image.device) / 16
    edge = torch.tensor([-1.0, 0.0, 1.0], dtype=image.dtype, device=image.device)
    kernel = edge[:, None] * smooth[None, :] if axis == 0 else smooth[:, None] * edge[None, :]
    return F.conv2d(F.pad(image, (1, 1, 1, 1), mode="replicate"), kernel[None, None])


#: DDFF-12's clip of the Hessian's norm in `bumpiness` (disparity pixels).
BUMPINESS_CLIP = 0.05


@maps_by_keyword
def bumpiness(*, pred: Tensor, target: Tensor, mask: Tensor,
              clip: float = BUMPINESS_CLIP) -> Tensor:
    """DDFF-12's bumpiness per image `(B,)`: the Frobenius norm of the Hessian of
    `pred - target` (Scharr derivatives, each clipped at `clip`), summed over `mask` and divided
    by its pixel count, x100. Outside `mask` the target counts as 0, as in the official code
    (`BaseDDFFEval`). Both maps in the scored space (DDFF-12: disparity in pixels).

    Both maps must be finite inside `mask`. Outside it a prediction that is not finite (NaN,
    infinite) counts as 0, like the target there, instead of spreading through the Scharr
    filters into the valid pixels nearby: the result is the one of a prediction of 0 at those
    pixels, and the one of any finite value there where the filters (2 pixels each way) reach
    no pixel of `mask`. Finite predictions outside `mask` count as they are (official code).

    Image borders follow the current scikit-image (edge pixels repeated); versions before 0.19
    zeroed the outer pixel of each derivative, which changes border pixels only.

    Example:
        >>> target = torch.arange(16.0).reshape(1, 1, 4, 4) / 4
        >>> mask = torch.ones(1, 1, 4, 4, dtype=torch.bool)
        >>> bumpiness(pred=target + 0.5, target=target, mask=mask)  # an offset has no curvature
        tensor([0.], dtype=torch.float64)
    """
    pred, target, mask = same_shape_batches(pred=pred, target=target, mask=mask)
    pred, target, mask = pred.double(), target.double(), mask.to(torch.bool)
    check_prediction(pred, mask, positive=False)
    refuse_bad_pixels("target", target, mask & ~torch.isfinite(target),
                       "finite at every pixel of mask")
    return _bumpiness(pred, target, mask, clip)


def _bumpiness(pred: Tensor, target: Tensor, mask: Tensor, clip: float) -> Tensor:
    """`bumpiness` of `(B,1,H,W)` float64 maps already checked."""
    zero = torch.zeros_like(target)
    diff = torch.where(mask, pred - target, torch.where(torch.isfinite(pred), pred, zero))
    dx, dy = _scharr(diff, 1), _scharr(diff, 0)
    norm = torch.sqrt(_scharr(dx, 1) ** 2 + _scharr(dx, 0) ** 2 + _scharr(dy, 0) ** 2
                      + _scharr(dy, 1) ** 2).clamp(0, clip)
    count = mask.flatten(1).sum(1).clamp_min(1)
    return (norm * mask).flatten(1).sum(1) / count * 100


@maps_by_keyword
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

    The prediction must be finite and > 0 at the valid pixels (measured, in the protocol's
    range); elsewhere it may hold anything: a NaN or infinity there counts as 0 in `bumpiness`
    (see there) and changes no other metric.

    Raises:
        ValueError: for an unknown protocol, shapes that differ, an empty batch, an image without
            valid ground truth, or a prediction that is not finite and positive where it counts.

    Example:
        >>> m = protocol_metrics(pred=torch.tensor([[2.0, 4.0]]), target=torch.tensor([[2.0, 5.0]]),
        ...                      protocol="zedd")
        >>> round(m["abs_rel"], 4), m["delta1.05"], m["delta1"]
        (0.1, 0.5, 0.5)
    """
    protocol = as_protocol(protocol)
    pred, target = (t.detach().double() for t in same_shape_batches(pred=pred, target=target))
    valid = torch.isfinite(target) & (target > 0)
    if mask is not None:
        valid &= as_map_batch("mask", mask).to(torch.bool)
    if protocol.disparity_scale is not None:  # score disparity: scale / depth
        target = torch.where(valid, protocol.disparity_scale / target.clamp_min(1e-12), target)
    if protocol.cap is not None:
        target = target.clamp(max=protocol.cap)
    valid &= (target >= protocol.valid[0]) & (target <= protocol.valid[1])
    check_prediction(pred, valid)
    refuse_empty_images(valid, why=f" for the {protocol.name} protocol (valid range "
                        f"{protocol.valid})")
    if protocol.disparity_scale is not None:
        pred = protocol.disparity_scale / pred.clamp_min(1e-12)
    if protocol.cap is not None:
        pred = pred.clamp(max=protocol.cap)
    scale = 100.0 if protocol.percent else 1.0
    bumps = _bumpiness(pred, target, valid, BUMPINESS_CLIP)  # the maps are checked above
    totals: dict[str, float] = {}
    for i, (d_all, g_all, v) in enumerate(zip(pred, target, valid, strict=True)):
        d, g = d_all[v], g_all[v]
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
