"""Per-pixel PSF rendering (reference implementation; see issue 3 for the fast one)."""

from __future__ import annotations

import torch
from torch import Tensor

from ._checks import check_shape
from .aperture import Aperture, Gaussian


def render_defocus(
    image: Tensor,
    coc_px: Tensor,
    psf: Aperture | None = None,
    mode: str = "scatter",
    depth: Tensor | None = None,
    max_kernel_size: int = 63,
) -> Tensor:
    """Blur ``image`` (B,C,H,W) with a per-pixel PSF of CoC diameter ``coc_px`` (B,1,H,W) pixels."""
    psf = Gaussian() if psf is None else psf
    check_shape("image", image, ["B", "C", "H", "W"])
    check_shape("coc_px", coc_px, ["B", "1", "H", "W"])
    size = min(psf.kernel_size(coc_px.detach().max()), max_kernel_size)
    half = size // 2
    b, c, h, w = image.shape
    ones = torch.ones(1, 1, h, w, dtype=image.dtype, device=image.device)
    pad = (half, half, half, half)
    img_p = torch.nn.functional.pad(image, pad)
    valid_p = torch.nn.functional.pad(ones, pad)
    coc_p = torch.nn.functional.pad(coc_px, pad)
    num = torch.zeros_like(image)
    den = torch.zeros_like(coc_px)
    for dy in range(-half, half + 1):
        for dx in range(-half, half + 1):
            sl = (..., slice(half + dy, half + dy + h), slice(half + dx, half + dx + w))
            src = coc_p[sl] if mode == "scatter" else coc_px
            off_y = torch.tensor(float(dy), dtype=image.dtype, device=image.device)
            off_x = torch.tensor(float(dx), dtype=image.dtype, device=image.device)
            wgt = psf.profile(off_y, off_x, src) * valid_p[sl]
            num = num + wgt * img_p[sl]
            den = den + wgt
    return num / den
