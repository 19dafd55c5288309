"""Measuring blur: spatially invariant FFT blurs, each pair's own CoC and the thin-lens curve."""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import Tensor

from ..aperture import Aperture
from ..checks import is_real_number, require

if TYPE_CHECKING:
    from .pair import CalibrationPair

#: Golden-section iterations of `measure_blur` after its grid search.
GOLDEN_STEPS = 20


def optimal_gain(rendered: Tensor, target: Tensor) -> Tensor:
    """Least-squares gain `g` minimising `|target - g rendered|^2`.

    Example:
        >>> optimal_gain(torch.tensor([1.0, 2.0]), torch.tensor([2.0, 4.0]))
        tensor(2.)
    """
    return (rendered * target).sum() / (rendered * rendered).sum().clamp_min(1e-30)


def crop(image: Tensor, margin: int) -> Tensor:
    """`image` without a border `margin` pixels wide on each side (the last two dimensions).

    Example:
        >>> crop(torch.zeros(1, 3, 10, 12), 2).shape
        torch.Size([1, 3, 6, 8])
    """
    return image[..., margin : image.shape[-2] - margin, margin : image.shape[-1] - margin]


class ConstantBlur:
    """Spatially invariant blurs of one image by FFT: the renderer's result for a constant CoC away
    from the borders (an exactness anchor of `optics.render_defocus`), much faster, and
    differentiable in the kernel.

    Args:
        image: `(B, C, H, W)` image to blur.
        pad: replicate padding in pixels; the kernels are `2 pad + 1` wide.

    Example:
        >>> blur = ConstantBlur(torch.ones(1, 1, 8, 8, dtype=torch.float64), 3)
        >>> out = blur(Gaussian(), 2.0)
        >>> out.shape, round(float(out.mean()), 6)
        (torch.Size([1, 1, 8, 8]), 1.0)
    """

    def __init__(self, image: Tensor, pad: int):
        self.pad = pad
        padded = F.pad(image, (pad, pad, pad, pad), mode="replicate")
        self.size = padded.shape[-2:]
        self.spectrum = torch.fft.rfft2(padded)

    def __call__(self, aperture: Aperture, coc_px: float | Tensor) -> Tensor:
        # the kernel where the aperture's tensors live (a shape's buffers may stay on the CPU
        # while the photos are on a GPU), then onto the photos' device
        tensors = [*aperture.parameters(), *aperture.buffers()]
        where = tensors[0].device if tensors else self.spectrum.device
        coc = torch.as_tensor(coc_px, dtype=self.spectrum.real.dtype, device=where).reshape(-1)
        kernel = aperture.kernel(coc, kernel_size=2 * self.pad + 1)[0].to(self.spectrum.device)
        placed = F.pad(kernel, (0, self.size[1] - kernel.shape[1], 0, self.size[0] - kernel.shape[0]))
        placed = torch.roll(placed, (-self.pad, -self.pad), dims=(0, 1))
        out = torch.fft.irfft2(self.spectrum * torch.fft.rfft2(placed), s=self.size)
        return out[..., self.pad : -self.pad, self.pad : -self.pad]


class _BlurMismatch:
    """Mean squared residual of a pair for one constant CoC, the gain solved in closed form."""

    def __init__(self, pair: CalibrationPair, aperture: Aperture, max_coc_px: float,
                 margin_px: int | None):
        sharp = pair.sharp.to(torch.float64)
        if margin_px is None:
            margin_px = min(aperture.half_width(max_coc_px) + 1, min(sharp.shape[-2:]) // 4)
        self.margin = margin_px
        self.aperture = aperture
        self.blur = ConstantBlur(sharp, aperture.half_width(max_coc_px) + 1)
        self.target = crop(pair.blurred.to(torch.float64), margin_px)

    def __call__(self, coc: float) -> float:
        rendered = crop(self.blur(self.aperture, coc), self.margin)
        gain = optimal_gain(rendered, self.target)
        return float(((self.target - gain * rendered) ** 2).mean())


def _golden_section(loss: Callable[[float], float], lo: float, hi: float) -> float:
    """The minimum of `loss` in `[lo, hi]` after `GOLDEN_STEPS` golden-section steps."""
    ratio = (math.sqrt(5) - 1) / 2
    a, b = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    fa, fb = loss(a), loss(b)
    for _ in range(GOLDEN_STEPS):
        if fa < fb:
            hi, b, fb = b, a, fa
            a = hi - ratio * (hi - lo)
            fa = loss(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + ratio * (hi - lo)
            fb = loss(b)
    return (a + b) / 2


def measure_blur(
    pair: CalibrationPair,
    aperture: Aperture,
    max_coc_px: float = 24.0,
    margin_px: int | None = None,
) -> float:
    """One pair's CoC diameter in pixels, as a spatially invariant blur of the reference.

    A grid search over `[0, max_coc_px]` followed by a golden-section refinement, with the
    exposure gain solved in closed form. For a planar target this is the pair's true blur; for a
    depth map it is a typical value (used to start `calibrate`).

    Args:
        pair: the pair.
        aperture: PSF shape (its scale, for a Gaussian, defines what "CoC" means).
        max_coc_px: largest CoC diameter searched, pixels.
        margin_px: border left out, pixels (by default the largest PSF's half width, at most a
            quarter of the image).

    Returns:
        the CoC diameter in pixels.

    Example:
        >>> sharp = torch.rand(1, 3, 48, 48, dtype=torch.float64)
        >>> blurred = Camera(ThinLens(0.05, 2.0, 2.0), Sensor(2e-5), Disk()).render(
        ...     sharp, torch.full((1, 1, 48, 48), 3.0, dtype=torch.float64))
        >>> round(measure_blur(CalibrationPair(sharp, blurred, 3.0), Disk()), 1)
        10.7
    """
    from .pair import CalibrationPair

    for name, value, cls in (("pair", pair, CalibrationPair), ("aperture", aperture, Aperture)):
        if not isinstance(value, cls):
            hint = f" (e.g. Disk(), or optics.parse_aperture({aperture!r}) for a spec)" \
                if name == "aperture" else ""
            raise TypeError(f"{name} must be an optics.{cls.__name__}{hint}, got "
                            f"{type(value).__name__}")
    if not (is_real_number(max_coc_px) and math.isfinite(max_coc_px) and max_coc_px > 0):
        raise ValueError(f"max_coc_px must be a finite number > 0 (pixels), got {max_coc_px!r}")
    if margin_px is not None:
        largest = (min(pair.sharp.shape[-2:]) - 1) // 2
        if isinstance(margin_px, bool) or not isinstance(margin_px, numbers.Integral) \
                or not 0 <= margin_px <= largest:
            raise ValueError(f"margin_px must be None or a whole number of pixels from 0 to "
                             f"{largest} (it must leave some of the {tuple(pair.sharp.shape[-2:])} "
                             f"image), got {margin_px!r}")
    loss = _BlurMismatch(pair, aperture, max_coc_px, margin_px)
    grid = [0.0] + torch.logspace(math.log10(0.5), math.log10(max_coc_px), 24).tolist()
    losses = [loss(c) for c in grid]
    best = min(range(len(grid)), key=losses.__getitem__)
    return _golden_section(loss, grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)])


def fit_thin_lens_curve(
    depths: Sequence[float], coc_px: Sequence[float], focus_distance: float | None = None
) -> tuple[float, float]:
    """Fit `coc(D) = A |1 - D_f / D|` to measured blur (pixels) at depths `D` (metres).

    Args:
        depths: depths in metres.
        coc_px: CoC diameters in pixels.
        focus_distance: `D_f` if known (metres); else searched on a fine logarithmic grid.

    Returns:
        `(A, D_f)`: the CoC in pixels at infinite depth, and the focus distance in metres.

    Example:
        >>> d = [1.0, 1.5, 4.0]
        >>> a, df = fit_thin_lens_curve(d, [8 * abs(1 - 2 / x) for x in d])
        >>> round(a, 3), round(df, 2)
        (8.0, 2.0)
    """
    depth = torch.as_tensor(list(depths), dtype=torch.float64).reshape(-1)
    coc = torch.as_tensor(list(coc_px), dtype=torch.float64).reshape(-1)
    if depth.numel() != coc.numel() or depth.numel() < (2 if focus_distance is None else 1):
        raise ValueError(f"depths and coc_px must hold one value per measurement, at least "
                         f"{2 if focus_distance is None else 1} (2 to fit the focus distance), got "
                         f"{depth.numel()} and {coc.numel()}")
    require("depths", depth, "depth")  # numbers: always checked
    require("coc_px", coc, "coc", "pixels")
    if focus_distance is not None and not (is_real_number(focus_distance)
                                           and math.isfinite(focus_distance)
                                           and focus_distance > 0):
        raise ValueError(f"focus_distance must be None or a finite number > 0 (metres), got "
                         f"{focus_distance!r}")
    finite = depth[torch.isfinite(depth)]
    if focus_distance is None:
        if finite.numel() == 0:
            raise ValueError("depths must hold a finite depth to fit the focus distance, got "
                             f"{depth.tolist()}")
        candidates = torch.logspace(
            math.log10(float(finite.min()) / 4), math.log10(float(finite.max()) * 4), 4001,
            dtype=torch.float64,
        )
    else:
        candidates = torch.tensor([float(focus_distance)], dtype=torch.float64)
    u = (1 - candidates[:, None] / depth[None]).abs()
    scale = (u * coc).sum(1) / (u * u).sum(1).clamp_min(1e-30)
    error = ((coc - scale[:, None] * u) ** 2).sum(1)
    best = int(error.argmin())
    return float(scale[best]), float(candidates[best])
