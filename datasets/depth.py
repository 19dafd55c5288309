"""Depth-map helpers for loaders: masks of valid measurements and filling the unknown pixels.

The sample format asks for depth > 0 everywhere with a `mask` of real measurements, because
focus synthesis needs a depth at every pixel while evaluation must only use measured ones.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .io import DataFormatError


def valid_depth_mask(depth: Tensor) -> Tensor:
    """`True` where `depth` (metres) is a measurement: finite and > 0 (0 marks "no return")."""
    return torch.isfinite(depth) & (depth > 0)


def require_valid_depth(mask: Tensor, source: str) -> None:
    """Raise `DataFormatError` naming `source` (the file, and frame) if `mask` marks no valid
    depth pixel: focused images rendered from such a frame would show invented depth.

    Example:
        >>> require_valid_depth(torch.zeros(1, 2, 2, dtype=torch.bool), "'d.png'")
        Traceback (most recent call last):
        ...
        datasets.io.DataFormatError: 'd.png': no valid depth pixel ...
    """
    if not bool(mask.any()):
        raise DataFormatError(
            f"{source}: no valid depth pixel (every value is 0, negative, NaN or inf), so no "
            f"focused image can be rendered from it; leave this frame out of the split"
        )


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
