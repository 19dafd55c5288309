"""Middlebury stereo scenes: real images with real depth from disparity.

scikit-image ships one of them, the *motorcycle* scene (Middlebury 2014, quarter size), so it is
the library's offline real-data default.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

#: Calibration of scikit-image's motorcycle scene: focal length in pixels, baseline in metres,
#: disparity offset in pixels (Middlebury 2014 ``calib.txt`` scaled to the shipped resolution).
MOTORCYCLE_CALIB = {"focal_length_px": 994.978, "baseline_m": 0.193, "doffs_px": 31.086}


def disparity_to_depth(
    disparity: Tensor, focal_length_px: float, baseline_m: float, doffs_px: float = 0.0
) -> tuple[Tensor, Tensor]:
    """Depth in metres from stereo disparity in pixels: ``Z = f_px * B / (d + doffs)``.

    Returns ``(depth, mask)``; unknown disparities (``inf`` or NaN, as Middlebury stores them) are
    masked out and their depth set to the largest valid depth, so the map stays finite.

    Example:
        >>> depth, mask = disparity_to_depth(torch.tensor([10.0, float("inf")]), 1000.0, 0.1, 0.0)
        >>> depth, mask
        (tensor([10., 10.]), tensor([ True, False]))
    """
    mask = torch.isfinite(disparity) & (disparity + doffs_px > 0)
    depth = (
        focal_length_px
        * baseline_m
        / torch.where(mask, disparity + doffs_px, torch.ones_like(disparity))
    )
    fill = depth[mask].max() if bool(mask.any()) else torch.ones((), dtype=depth.dtype)
    return torch.where(mask, depth, fill), mask


def load_motorcycle(dtype: torch.dtype = torch.float32) -> dict[str, Tensor]:
    """The motorcycle scene shipped with scikit-image, as tensors.

    Returns:
        dict with ``image`` ``(1,3,H,W)`` in [0,1] (sRGB-decoded to linear intensity), ``depth``
        ``(1,1,H,W)`` metres (2.1-5.0 m), ``mask`` ``(1,1,H,W)`` bool (known disparity), and the
        calibration under ``calib``.
    """
    from skimage import data

    left, _, disparity = data.stereo_motorcycle()
    srgb = torch.from_numpy(np.ascontiguousarray(left)).to(dtype).permute(2, 0, 1)[None] / 255.0
    linear = torch.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    depth, mask = disparity_to_depth(torch.from_numpy(disparity).to(dtype), **MOTORCYCLE_CALIB)
    return {
        "image": linear,
        "depth": depth[None, None],
        "mask": mask[None, None],
        "calib": MOTORCYCLE_CALIB,
    }
