"""Direct optimisation baseline: fit one scene's depth map through the renderer, no network.

The depth map is parameterised as `depth_min + (depth_max - depth_min) * sigmoid(logits)`
(logits on a grid `downsample` times coarser than the image, upsampled bilinearly) and fitted
with Adam so that the all-in-focus image rendered at that depth matches each focused image
(`DefocusLoss`), with an edge-aware smoothness prior. Where the image has no
texture the focused images carry no depth information and the prior fills in.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from optics import CameraSettings
from optics.checks import check_shape

from .losses import DefocusLoss


def fit_depth_direct(
    image: Tensor, focused: Tensor, settings: CameraSettings, depth_min: float,
    depth_max: float, steps: int = 200, lr: float = 0.1, smoothness_weight: float = 0.05,
    downsample: int = 2, loss: DefocusLoss | None = None, progress: bool = False,
) -> Tensor:
    """Fit depth `(B,1,H,W)` in metres to all-in-focus and focused images by gradient descent.

    Args:
        image: all-in-focus images `(B,3,H,W)`, linear.
        focused: focused images `(B,F,3,H,W)`.
        settings: the `(B,F)` (or `(F,)`) camera settings of the focused images.
        depth_min: nearest depth, metres.
        depth_max: farthest depth, metres (the fit starts half-way in sigmoid space).
        steps: Adam steps.
        lr: Adam learning rate on the logits.
        smoothness_weight: weight of the edge-aware smoothness prior.
        downsample: the logits live on a grid this many times coarser than the image (>= 1).
        loss: the data term; `DefocusLoss` with the paper's weights and
            `smoothness_weight` by default.
        progress: show a tqdm bar.

    Returns:
        the fitted depth (no gradient), metres.

    Example:
        >>> from optics import render_focal_stack
        >>> settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 180e-6)
        >>> image = torch.rand(1, 3, 16, 16)
        >>> focused = render_focal_stack(image, torch.full((1, 1, 16, 16), 4.0), settings)
        >>> depth = fit_depth_direct(image, focused, settings, 1.5, 7.0, steps=60)
        >>> abs(float(depth.median()) - 4.0) < 0.4
        True
    """
    from optics.progress import progress_bar

    check_shape("image", image, ["B", "3", "H", "W"])
    check_shape("focused", focused, ["B", "F", "3", "H", "W"])
    if not 0 < depth_min < depth_max:
        raise ValueError(f"need 0 < depth_min < depth_max metres, got {depth_min!r}, "
                         f"{depth_max!r}")
    if int(downsample) < 1 or int(steps) < 1:
        raise ValueError(f"downsample and steps must be >= 1, got {downsample!r}, {steps!r}")
    loss = loss or DefocusLoss(smoothness_weight=smoothness_weight)
    b, _, h, w = image.shape
    grid = (max(1, -(-h // int(downsample))), max(1, -(-w // int(downsample))))
    logits = torch.zeros(b, 1, *grid, dtype=image.dtype, device=image.device, requires_grad=True)
    optimizer = torch.optim.Adam([logits], lr=lr)

    def depth_of(z: Tensor) -> Tensor:
        z = F.interpolate(z, size=(h, w), mode="bilinear", align_corners=False)
        return depth_min + (depth_max - depth_min) * torch.sigmoid(z)

    for _ in progress_bar(range(int(steps)), desc="direct fit", disable=not progress):
        optimizer.zero_grad(set_to_none=True)
        total = loss(depth_of(logits), image, focused, settings)["loss"]
        total.backward()
        optimizer.step()
    with torch.no_grad():
        return depth_of(logits)
