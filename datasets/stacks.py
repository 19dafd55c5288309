"""Focal-stack benchmarks in their release formats: what DDFF-12, FoD500, ZEDD and Mobile Depth
share.

Their shots are real (rendered or photographed), so nothing is synthesised: each loader reads
the `F` shots of a scene with each shot's settings (`optics.CameraSettings`, metres) and, where
the benchmark has it, the depth in metres with its valid-pixel mask. Samples follow
`datasets.base` and add one key:

====================  ======  ==========================================================
key                   type    meaning
====================  ======  ==========================================================
`has_all_in_focus`  bool    True: `image` is a real all-in-focus shot (ZEDD's f/16
                              photo). False: the benchmark has none, and `image` is the
                              shots fused by local sharpness (`fuse_by_sharpness`), a
                              stand-in for display that a method must not take for one
====================  ======  ==========================================================

Scenes without depth (Mobile Depth, ZEDD's test split) have `mask` all False and depth filled
with a constant, as `datasets.lightfield` does.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from optics.checks import check_shape

from .base import DepthDataset


def fuse_by_sharpness(focused: Tensor, window: int = 7) -> Tensor:
    """The shots `(F,3,H,W)` fused into one image `(3,H,W)`: each pixel from the shot with the
    most local contrast (squared Laplacian of the grey image, averaged over `window` pixels).

    A stand-in all-in-focus image for stacks without one (classic focus stacking); it is not
    a measurement and its seams show where the sharpest shot changes.

    Example:
        >>> sharp = torch.rand(3, 16, 16)
        >>> blurred = torch.full((3, 16, 16), 0.5)
        >>> torch.equal(fuse_by_sharpness(torch.stack([blurred, sharp])), sharp)
        True
    """
    check_shape("focused", focused, ["F", "3", "H", "W"])
    if window < 1 or window % 2 == 0:
        raise ValueError(f"window must be an odd number of pixels >= 1, got {window}")
    grey = focused.mean(1, keepdim=True)
    kernel = torch.tensor([[0.0, 1.0, 0.0], [1.0, -4.0, 1.0], [0.0, 1.0, 0.0]],
                          dtype=grey.dtype, device=grey.device)
    laplacian = F.conv2d(F.pad(grey, (1, 1, 1, 1), mode="replicate"), kernel[None, None])
    energy = F.avg_pool2d(laplacian**2, window, stride=1, padding=window // 2,
                          count_include_pad=False)
    best = energy.argmax(0, keepdim=True).expand(1, 3, -1, -1)
    return focused.gather(0, best)[0]


class FocalStackDataset(DepthDataset):
    """Base of the focal-stack benchmarks: real shots and their settings, never synthesised.

    Subclasses implement `load_stack` returning `image` (None where the benchmark has no
    all-in-focus shot: the shots fused by `fuse_by_sharpness` stand in, and
    `has_all_in_focus` is False), `focused`, `camera`, `depth` and `mask` at native
    resolution; `DepthDataset` then crops, resizes (scaling the pixel pitch) and augments.
    `depth_range` is the `(near, far)` metres the benchmark's scenes lie within.
    """

    depth_range: tuple[float, float] = (0.1, 10.0)

    def load_stack(self, index: int) -> dict[str, Any]:
        """Native-resolution `image` (or None), `focused`, `camera`, `depth` and `mask`."""
        raise NotImplementedError

    def load(self, index: int) -> dict[str, Any]:
        sample = self.load_stack(index)
        sample["has_all_in_focus"] = sample.get("image") is not None
        if sample.get("image") is None:
            sample["image"] = fuse_by_sharpness(sample["focused"])
        return sample

    def _finish(self, sample: dict[str, Any]) -> dict[str, Any]:
        out = super()._finish(sample)
        out["has_all_in_focus"] = bool(sample.get("has_all_in_focus", True))
        return out
