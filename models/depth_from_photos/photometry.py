"""What the photos' sensor adds: exposure and white-balance differences between shots, and noise.

Depth from defocus compares photos; two shots of one scene differ also by their exposure (and
white balance) and by noise, and both must be removed before the blur is read. `match_exposure`
scales one photo's channels to another's means. `noise_model` measures a photo's noise (a
variance affine in intensity: read plus shot noise) from the photo itself, so that the share of
it that a blur averages away can be subtracted from the errors that compare blurred photos.
"""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F
from torch import Tensor

from optics.checks import check_shape

from .thin_lens import box_filter

# Immerkaer's noise operator: zero on any plane, on white noise of variance s^2 its response has
# variance 36 s^2.
_NOISE_OPERATOR = ((1.0, -2.0, 1.0), (-2.0, 4.0, -2.0), (1.0, -2.0, 1.0))
#: Low quantile of the local variance estimates within an intensity band taken as noise.
_QUANTILE = 0.1


def match_exposure(image: Tensor, focused: Tensor) -> Tensor:
    """`focused` `(B,3,H,W)` scaled per channel to the mean of `image` (exposure and white
    balance differences between shots removed).

    Example:
        >>> image = torch.rand(1, 3, 8, 8)
        >>> torch.allclose(match_exposure(image, 0.5 * image), image)
        True
    """
    return focused * exposure_gain(image.mean((-2, -1), keepdim=True), focused)


def exposure_gain(means: Tensor, focused: Tensor) -> Tensor:
    """The per-channel gain `(...,C,1,1)` that `match_exposure` scales `focused` `(...,C,H,W)` by:
    the reference's channel `means` `(...,C,1,1)` over `focused`'s own.

    Example:
        >>> exposure_gain(torch.ones(3, 1, 1), torch.full((3, 4, 4), 0.5)).flatten().tolist()
        [2.0, 2.0, 2.0]
    """
    return means / focused.mean((-2, -1), keepdim=True).clamp_min(1e-6)


#: The most values (pixels x channels) `noise_model` sorts per photo stack.
NOISE_SAMPLES = 2**22


def _local_noise(image: Tensor, window: int = 7) -> tuple[Tensor, Tensor]:
    """Per-pixel noise-variance estimates and local mean intensities of `(N,1,H,W)`."""
    n, _, h, w = image.shape
    operator = torch.tensor(_NOISE_OPERATOR, dtype=image.dtype, device=image.device)
    # the N photos as the channels of one depthwise convolution: on a CPU many times faster
    # than a batch of one-channel ones
    response = F.conv2d(image.reshape(1, n, h, w), operator.expand(n, 1, 3, 3), groups=n)
    response = response.reshape(n, 1, h - 2, w - 2)
    return box_filter(response**2, window) / 36, box_filter(image[..., 1:-1, 1:-1], window)


def _quantiles(ordered: Tensor, q: Tensor) -> Tensor:
    """`torch.quantile(values, q)` (linear interpolation) of the `ordered` (sorted) values."""
    ranks = q * (ordered.numel() - 1)
    below = ranks.long()
    return ordered[below].lerp(ordered[ranks.ceil().long()], ranks - below)


def _quantile_unsorted(values: Tensor, q: float) -> Tensor:
    """`torch.quantile(values, q)` of a flat tensor from two order statistics (no sort)."""
    rank = q * (values.numel() - 1)
    below, above = math.floor(rank), math.ceil(rank)
    low = torch.kthvalue(values, below + 1).values
    high = low if above == below else torch.kthvalue(values, above + 1).values
    return low.lerp(high, torch.tensor(rank - below, dtype=values.dtype))


@functools.cache
def _quantile_of_pure_noise() -> float:
    """`_QUANTILE` of `_local_noise`'s estimates on white noise of unit variance (measured once)."""
    g = torch.Generator().manual_seed(0)
    white, _ = _local_noise(torch.randn(1, 1, 256, 256, generator=g, dtype=torch.float64))
    return float(torch.quantile(white.flatten(), _QUANTILE))


def noise_model(image: Tensor, bins: int = 12) -> Tensor:
    """The noise of a photo `(B,C,H,W)` (linear intensity): `(B,2)` coefficients `(a, b)` of the
    per-pixel variance `a + b * intensity` (read noise plus shot noise). Photos of one sensor
    stacked along the channels are pooled: the defocused ones, with less texture to mistake for
    noise, then set the estimate.

    Per intensity band, the low tail (10th percentile) of the local variance of Immerkaer's
    operator responses is texture-free enough to be noise; its ratio to the noise variance is
    that percentile for pure white noise, measured once. A least-squares line through the bands,
    kept non-negative, gives `a` and `b`.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> flat = torch.linspace(0.1, 0.9, 128).expand(1, 3, 128, 128)
        >>> noisy = flat + torch.randn(1, 3, 128, 128, generator=g) * (1e-4 + 1e-3 * flat).sqrt()
        >>> a, b = noise_model(noisy)[0].tolist()
        >>> 0.5e-3 < b < 2e-3 and a < 5e-4
        True
    """
    check_shape("image", image, ["B", "C", "H", "W"])
    if min(image.shape[-2:]) < 16:
        return torch.zeros(image.shape[0], 2, dtype=image.dtype, device=image.device)
    out = []
    for photo in image.detach().to(torch.promote_types(image.dtype, torch.float32)):
        # the operator's responses in the photo's dtype, their statistics in float64
        variance, level = (t.flatten() for t in _local_noise(photo[:, None]))
        # a regular subsample of a large stack: its order statistics are as good, and sorting
        # it is the costliest step
        stride = math.ceil(level.numel() / NOISE_SAMPLES)
        variance, level = variance[::stride].double(), level[::stride].double()
        # the bands are runs of the intensities sorted once; their statistics are order
        # statistics of each run (`torch.quantile`'s and `torch.median`'s values exactly)
        ordered, order = torch.sort(level)
        edges = _quantiles(ordered, torch.linspace(0, 1, bins + 1, dtype=level.dtype,
                                                   device=level.device))
        starts = torch.searchsorted(ordered, edges[:-1], right=False).tolist()
        ends = torch.searchsorted(ordered, edges[1:], right=True).tolist()
        xs, ys = [], []
        for start, end in zip(starts, ends, strict=True):
            if end - start < 50:
                continue
            xs.append(float(ordered[start + (end - start - 1) // 2]))  # the lower median
            band = variance[order[start:end]]
            ys.append(float(_quantile_unsorted(band, _QUANTILE)) / _quantile_of_pure_noise())
        x, y = torch.tensor(xs, dtype=torch.float64), torch.tensor(ys, dtype=torch.float64)
        design = torch.stack([torch.ones_like(x), x], 1)
        a, b = torch.linalg.lstsq(design, y[:, None]).solution.flatten().tolist()
        if b < 0:
            a, b = float(y.mean()), 0.0
        if a < 0:
            a, b = 0.0, float((x * y).sum() / (x * x).sum().clamp_min(1e-30))
        out.append([a, b])
    return torch.tensor(out, dtype=image.dtype, device=image.device)


def noise_variance(photo: Tensor, noise: Tensor) -> Tensor:
    """Per-pixel noise variance `(B,1,H,W)` of `photo` `(B,C,H,W)` summed over its channels, for
    the `noise_model` coefficients `noise` `(B,2)`, at the photo's local mean (5x5 pixels).

    Example:
        >>> noise_variance(torch.full((1, 3, 8, 8), 0.5), torch.tensor([[1e-4, 1e-3]]))[0, 0, 0, 0]
        tensor(0.0018)
    """
    return (noise[:, :1, None, None] + noise[:, 1:, None, None]
            * box_filter(photo, 5).clamp_min(0)).sum(1, keepdim=True)
