"""Where depth from defocus can be trusted: texture to read, and one depth per error window.

Defocus says nothing where a photo holds no texture (or is saturated): `texture_weight` measures
how much band-pass energy there is against a floor. And every method compares windows of pixels
under one blur, which fails across a depth edge: `depth_edge_confidence` falls where the blur of
the depth found varies within a window.
"""

from __future__ import annotations

import math

import kornia
import torch
import torch.nn.functional as F
from torch import Tensor

from optics.checks import check_shape

from .rules import refuse_broken
from .thin_lens import ERROR_WINDOW_PX, box_filter

#: The confidence of `depth_edge_confidence` halves every `BLUR_SPAN_PX * ln 2` pixels by which
#: the blur read varies within an error window.
BLUR_SPAN_PX = 0.5


def band_energy(gray: Tensor, scale: float, window: int = 7) -> Tensor:
    """Local energy `(B,1,H,W)` of the Laplacian of `gray` `(B,1,H,W)` after a Gaussian of
    `scale` pixels (none at 0), averaged over `window x window` pixels.

    Example:
        >>> band_energy(torch.ones(1, 1, 16, 16), 1.0).abs().max() < 1e-6
        tensor(True)
    """
    if scale > 0:
        k = 2 * math.ceil(3 * scale) + 1
        gray = kornia.filters.gaussian_blur2d(gray, (k, k), (scale, scale), border_type="reflect")
    energy = kornia.filters.laplacian(gray, 3, border_type="reflect") ** 2
    return kornia.filters.box_blur(energy, (window, window), border_type="reflect")


def texture_weight(image: Tensor, window: int = 7) -> Tensor:
    """How much defocus can be read at each pixel, in [0, 1] `(B,1,H,W)`: local band-pass
    energy of the photo `(B,3,H,W)` against a floor, zero where a channel is saturated.

    Example:
        >>> flat = torch.full((1, 3, 16, 16), 0.5)
        >>> float(texture_weight(flat).max()) < 0.01
        True
    """
    energy = band_energy(image.mean(1, keepdim=True), 0.0, window)
    floor = 1e-5 + 0.05 * energy.mean((-2, -1), keepdim=True)
    weight = energy / (energy + floor)
    saturated = (image.amax(1, keepdim=True) > 0.98).to(image.dtype)
    saturated = F.max_pool2d(saturated, 5, 1, 2)
    return weight * (1 - saturated)


def texture_confidence(image: Tensor) -> Tensor:
    """How much texture there is to read around each pixel, in [0, 1] `(B,1,H,W)`: the photo's
    `texture_weight` averaged over 5x5 pixels. It weighs the smoothing of the depth and is one
    factor of the returned confidence.

    Example:
        >>> texture_confidence(torch.rand(1, 3, 16, 16)).shape
        torch.Size([1, 1, 16, 16])
    """
    return box_filter(texture_weight(image), 5).clamp(0, 1)


def depth_edge_confidence(blur: Tensor, window: int = ERROR_WINDOW_PX,
                          span_px: float = BLUR_SPAN_PX) -> Tensor:
    """How well the one-blur-per-window model holds at each pixel, in (0, 1] `(B,1,H,W)`: each
    error window is compared under one blur, which fails across a depth edge (the window sees
    two blurs). From the blur maps `(B,F,H,W)` (pixels) of the depth found: `exp(-r / span_px)`,
    `r` the largest range (max - min) of any shot's blur over a `window x window` neighbourhood.

    Example:
        >>> blur = torch.zeros(1, 2, 1, 10)
        >>> blur[..., 5:] = 1.0  # a depth edge: the blur jumps by one pixel
        >>> tuple(round(v, 2) for v in depth_edge_confidence(blur)[0, 0, 0].tolist())
        (1.0, 1.0, 1.0, 0.14, 0.14, 0.14, 0.14, 1.0, 1.0, 1.0)
    """
    check_shape("blur", blur, ["B", "F", "H", "W"])
    refuse_broken([
        (isinstance(window, bool) or not (isinstance(window, int) and window >= 1
                                          and window % 2 == 1),
         lambda: f"window must be an odd number of pixels >= 1, got {window!r}"),
        (not span_px > 0, lambda: f"span_px must be > 0 pixels, got {span_px!r}")])
    pad = window // 2
    padded = F.pad(blur, (pad, pad, pad, pad), mode="replicate")
    spread = F.max_pool2d(padded, window, 1) + F.max_pool2d(-padded, window, 1)
    return torch.exp(-spread.amax(1, keepdim=True) / span_px)
