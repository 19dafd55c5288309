"""Self-supervised depth-from-defocus losses (Gur & Wolf 2019).

The depth predicted from the all-in-focus image is rendered, through each focused image's camera,
into a synthetic focused image that is compared with the real one:

- photometric: `ssim_weight * (1 - SSIM)/2 + (1 - ssim_weight) * L1` (paper: 0.85), Kornia's
  SSIM (`ssim_map`), averaged over the focus settings;
- sharpness: L1 between the sharpness maps (Sobel gradient magnitude) of the rendered and the real
  focused images (paper weight 0.1);
- smoothness: edge-aware first-order smoothness of the mean-normalised depth, down-weighted at
  image edges (paper weight 0.001).
"""

from __future__ import annotations

import functools
from typing import Any

import kornia
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from optics import Aperture, CameraSettings, render_focal_stack
from optics.checks import check_shape


def photometric_loss(rendered: Tensor, target: Tensor, ssim_weight: float = 0.85,
                     window_size: int = 7) -> Tensor:
    """`ssim_weight * (1 - SSIM)/2 + (1 - ssim_weight) * L1`, averaged over pixels and images.

    Args:
        rendered: `(..., C, H, W)` images in [0, 1].
        target: same shape as `rendered`.
        ssim_weight: weight of the SSIM term in [0, 1] (paper: 0.85).
        window_size: odd SSIM window width in pixels.

    Example:
        >>> x = torch.rand(2, 3, 16, 16)
        >>> round(float(photometric_loss(x, x)), 6)
        0.0
    """
    if rendered.shape != target.shape:
        raise ValueError(f"rendered and target must have the same shape, got "
                         f"{tuple(rendered.shape)} and {tuple(target.shape)}")
    if not 0.0 <= ssim_weight <= 1.0:
        raise ValueError(f"ssim_weight must be in [0, 1], got {ssim_weight!r}")
    r = rendered.reshape(-1, *rendered.shape[-3:])
    t = target.reshape(-1, *target.shape[-3:])
    ssim = ((1 - ssim_map(r, t, window_size)) / 2).clamp(0, 1).mean()
    return ssim_weight * ssim + (1 - ssim_weight) * (r - t).abs().mean()


def ssim_map(x: Tensor, y: Tensor, window_size: int = 7, max_val: float = 1.0) -> Tensor:
    """SSIM `(B, C, H, W)` of two image batches: Kornia's `kornia.metrics.ssim` (Gaussian window
    of sigma 1.5 px, reflected borders, `'same'` padding), its five local moments filtered in
    one pass.

    Kornia filters the five moments one after another: 65 operations for the forward pass (47
    for the backward). Filtered together as one stack they take 29 (`benchmarks/loss.py`),
    which a GPU training step, bound by the host issuing its operations, feels.

    Args:
        x: `(B, C, H, W)` images.
        y: same shape as `x`.
        window_size: odd width of the Gaussian window, pixels.
        max_val: the images' dynamic range.

    Example:
        >>> import kornia
        >>> x, y = torch.rand(2, 3, 16, 16), torch.rand(2, 3, 16, 16)
        >>> bool(torch.allclose(ssim_map(x, y), kornia.metrics.ssim(x, y, 7), atol=1e-4))
        True
    """
    check_shape("x", x, ["B", "C", "H", "W"])
    if y.shape != x.shape:
        raise ValueError(f"x and y must have the same shape, got {tuple(x.shape)} and "
                         f"{tuple(y.shape)}")
    if window_size < 1 or window_size % 2 == 0:
        raise ValueError(f"window_size must be an odd number of pixels >= 1, got {window_size!r}")
    dtype = torch.promote_types(torch.promote_types(x.dtype, y.dtype), torch.float32)
    x, y = x.to(dtype), y.to(dtype)
    stack = torch.cat([x, y, x * x, y * y, x * y], 1)
    row = _gaussian_window(window_size, x.device, dtype).expand(stack.shape[1], 1, 1, window_size)
    half = window_size // 2
    with torch.autocast(device_type=x.device.type, enabled=False):
        rows = F.conv2d(F.pad(stack, [half] * 4, mode="reflect"), row, groups=stack.shape[1])
        moments = F.conv2d(rows, row.transpose(-1, -2), groups=stack.shape[1])
    mu_x, mu_y, xx, yy, xy = moments.chunk(5, 1)
    c1, c2 = (0.01 * max_val) ** 2, (0.03 * max_val) ** 2
    mu_xy = mu_x * mu_y
    mu_xx, mu_yy = mu_x * mu_x, mu_y * mu_y
    numerator = (2 * mu_xy + c1) * (2 * (xy - mu_xy) + c2)
    denominator = (mu_xx + mu_yy + c1) * (xx - mu_xx + yy - mu_yy + c2)
    return numerator / (denominator + 1e-12)


def _gaussian_window(window_size: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    """Kornia's SSIM window `(1, 1, 1, window_size)` (sigma 1.5 px): made once per device in eager
    mode, a constant of the graph under `torch.compile`."""
    if torch.compiler.is_compiling():
        return _make_gaussian_window(window_size, device, dtype)
    return _cached_gaussian_window(window_size, device, dtype)


def _make_gaussian_window(window_size: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    kernel = kornia.filters.get_gaussian_kernel1d(window_size, 1.5, dtype=torch.float64)
    return kernel.to(device, dtype).reshape(1, 1, 1, window_size)


@functools.lru_cache(maxsize=32)
def _cached_gaussian_window(window_size: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    with torch.inference_mode(False):  # an inference tensor could not be saved for a backward
        return _make_gaussian_window(window_size, device, dtype)


def sharpness_map(image: Tensor) -> Tensor:
    """Local sharpness `(..., 1, H, W)`: Sobel gradient magnitude of the channel mean."""
    flat = image.reshape(-1, *image.shape[-3:]).mean(-3, keepdim=True)
    return kornia.filters.sobel(flat).reshape(*image.shape[:-3], 1, *image.shape[-2:])


def sharpness_loss(rendered: Tensor, target: Tensor) -> Tensor:
    """Mean L1 distance between the sharpness maps of `rendered` and `target`."""
    return (sharpness_map(rendered) - sharpness_map(target)).abs().mean()


def edge_aware_smoothness(depth: Tensor, image: Tensor) -> Tensor:
    """Edge-aware smoothness: `mean(|d_x d*| exp(-|d_x I|)) + mean(|d_y d*| exp(-|d_y I|))`.

    `d*` is the depth divided by its per-image mean (scale free) and `|d I|` the channel mean
    of the image's absolute differences.

    Args:
        depth: `(B,1,H,W)` metres.
        image: `(B,C,H,W)`.

    Example:
        >>> float(edge_aware_smoothness(torch.full((1, 1, 8, 8), 3.0), torch.rand(1, 3, 8, 8)))
        0.0
    """
    check_shape("depth", depth, ["B", "1", "H", "W"])
    d = depth / depth.mean((2, 3), keepdim=True)
    dx, dy = (d[..., :, 1:] - d[..., :, :-1]).abs(), (d[..., 1:, :] - d[..., :-1, :]).abs()
    ix = (image[..., :, 1:] - image[..., :, :-1]).abs().mean(1, keepdim=True)
    iy = (image[..., 1:, :] - image[..., :-1, :]).abs().mean(1, keepdim=True)
    return (dx * torch.exp(-ix)).mean() + (dy * torch.exp(-iy)).mean()


class DefocusLoss(nn.Module):
    """The paper's self-supervised loss: photometric + sharpness + smoothness.

    Args:
        ssim_weight: SSIM share of the photometric term (paper: 0.85).
        sharpness_weight: weight of the sharpness-map L1 term (paper: 0.1).
        smoothness_weight: weight of the edge-aware depth smoothness (paper: 0.001).
        window_size: SSIM window width in pixels.
        aperture: PSF shape used to render, overriding the settings' aperture (None: use the
            aperture of the `CameraSettings` passed to `forward`).
        **render_kwargs: passed to `optics.render_defocus` (`mode`, ...).

    Example:
        >>> loss = DefocusLoss()
        >>> settings = CameraSettings(0.05, 2.0, [[2.0, 6.0]], 180e-6)
        >>> image, depth = torch.rand(1, 3, 16, 16), torch.full((1, 1, 16, 16), 3.0)
        >>> focused = render_focal_stack(image, depth, settings)
        >>> round(float(loss(depth, image, focused, settings)["loss"]), 6)
        0.0
    """

    def __init__(self, ssim_weight: float = 0.85, sharpness_weight: float = 0.1,
                 smoothness_weight: float = 0.001, window_size: int = 7,
                 aperture: Aperture | None = None, **render_kwargs: Any):
        super().__init__()
        self.ssim_weight = float(ssim_weight)
        self.sharpness_weight = float(sharpness_weight)
        self.smoothness_weight = float(smoothness_weight)
        self.window_size = int(window_size)
        self.aperture = aperture
        self.render_kwargs = render_kwargs

    def forward(self, depth: Tensor, image: Tensor, focused: Tensor,
                settings: CameraSettings) -> dict[str, Tensor]:
        """Loss terms for predicted `depth` `(B,1,H,W)` metres, all-in-focus `image`
        `(B,3,H,W)`, real `focused` images `(B,F,3,H,W)` and their `(B,F)` settings.

        Returns:
            dict with `loss` (the weighted total), `photometric`, `sharpness`, `smoothness`.
        """
        check_shape("focused", focused, ["B", "F", "C", "H", "W"])
        rendered = render_focal_stack(image, depth, settings, self.aperture, **self.render_kwargs)
        photometric = photometric_loss(rendered, focused, self.ssim_weight, self.window_size)
        sharpness = sharpness_loss(rendered, focused)
        smoothness = edge_aware_smoothness(depth, image)
        total = (photometric + self.sharpness_weight * sharpness
                 + self.smoothness_weight * smoothness)
        return {"loss": total, "photometric": photometric, "sharpness": sharpness,
                "smoothness": smoothness}

    def extra_repr(self) -> str:
        return (f"ssim_weight={self.ssim_weight}, sharpness_weight={self.sharpness_weight}, "
                f"smoothness_weight={self.smoothness_weight}, window_size={self.window_size}")


def supervised_depth_loss(depth: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean relative L1 error `|depth - target| / target` over valid pixels (a baseline that
    uses depth labels; not part of the self-supervised recipe).

    Example:
        >>> float(supervised_depth_loss(torch.full((1, 1, 2, 2), 3.0), torch.full((1, 1, 2, 2), 2.0)))
        0.5
    """
    error = (depth - target).abs() / target
    if mask is None:
        return error.mean()
    mask = mask.to(error.dtype)
    return (error * mask).sum() / mask.sum().clamp_min(1.0)
