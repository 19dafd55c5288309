"""Depth-map helpers for loaders: masks of valid measurements and filling the unknown pixels.

The sample format asks for depth > 0 everywhere with a `mask` of real measurements, because
focus synthesis needs a depth at every pixel while evaluation must only use measured ones.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from .io import DataFormatError


def valid_depth_mask(depth: Tensor) -> Tensor:
    """`True` where `depth` (metres) is a measurement: finite and > 0 (0 marks "no return")."""
    return torch.isfinite(depth) & (depth > 0)


def require_valid_depth(mask: Tensor, source: str, depth: Tensor | None = None,
                        median_metres: tuple[float, float] = (0.0, math.inf),
                        what: str = "its depths") -> None:
    """Raise `DataFormatError` naming `source` (the file, and frame) if `mask` marks no valid
    depth pixel (focused images rendered from such a frame would show invented depth), or if
    the median of `depth`'s positive finite values lies outside `median_metres`: millimetres,
    disparity or another unit read as metres would scale every depth silently.

    Example:
        >>> require_valid_depth(torch.zeros(1, 2, 2, dtype=torch.bool), "'d.png'")
        Traceback (most recent call last):
        ...
        datasets.io.DataFormatError: 'd.png': no valid depth pixel ...
        >>> depth = torch.tensor([1200.0, 800.0])
        >>> require_valid_depth(depth > 0, "'d.exr'", depth, (0, 10))
        Traceback (most recent call last):
        ...
        datasets.io.DataFormatError: 'd.exr': its depths have median 800 m; expected metres with a median in 0-10 m (millimetres? another unit?)
    """
    positive = None if depth is None else depth[valid_depth_mask(depth)]
    median = float(positive.median()) if positive is not None and positive.numel() else None
    low, high = median_metres
    why = ("no valid depth pixel (every value is 0, negative, NaN or inf), so no focused image "
           "can be rendered from it; leave this frame out of the split" if not bool(mask.any())
           else f"{what} have median {median:.4g} m; expected metres with a median in "
           f"{low:g}-{high:g} m (millimetres? another unit?)"
           if median is not None and not low <= median <= high else None)
    if why:
        raise DataFormatError(f"{source}: {why}")


def fill_unknown(depth: Tensor, mask: Tensor, value: float | None = None) -> Tensor:
    """Set the pixels outside `mask` to `value` metres (default: the largest valid depth).

    With no valid pixel at all, `value` must be given (a `ValueError` otherwise: loaders refuse
    such frames with `require_valid_depth` first).

    Example:
        >>> fill_unknown(torch.tensor([2.0, 0.0, 5.0]), torch.tensor([True, False, True]))
        tensor([2., 5., 5.])
    """
    if value is None:
        if not bool(mask.any()):
            raise ValueError("fill_unknown: no valid depth pixel to fill from; pass value= or "
                             "refuse the frame (require_valid_depth)")
        value = float(depth[mask].max())
    return torch.where(mask, depth, torch.full_like(depth, value))


def densify_nearest(depth: Tensor, mask: Tensor) -> Tensor:
    """Fill every pixel outside `mask` with the depth of the nearest valid pixel (per image).

    Used for sparse LiDAR depth (KITTI) before focus synthesis; the mask still marks the real
    measurements for evaluation. Works on `(..., H, W)`.

    Example:
        >>> densify_nearest(torch.tensor([[3.0, 0.0, 0.0, 7.0]]), torch.tensor([[1, 0, 0, 1]]).bool())
        tensor([[3., 3., 7., 7.]])
    """
    from scipy.ndimage import distance_transform_edt

    flat_depth = depth.reshape(-1, *depth.shape[-2:])
    flat_mask = mask.reshape(-1, *mask.shape[-2:])
    out = flat_depth.clone()
    for i in range(flat_depth.shape[0]):
        known = flat_mask[i].cpu().numpy()
        if not known.any():
            raise ValueError(f"densify_nearest: image {i} has no valid depth pixel to spread; "
                             "refuse the frame (require_valid_depth)")
        # Index of the nearest known pixel for every pixel (distance to "not unknown").
        _, (rows, cols) = distance_transform_edt(~known, return_indices=True)
        index = torch.from_numpy(np.ravel_multi_index((rows, cols), known.shape)).to(depth.device)
        out[i] = flat_depth[i].reshape(-1)[index.reshape(-1)].reshape(known.shape)
    return out.reshape(depth.shape)
