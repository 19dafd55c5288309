"""Shared fixtures: devices and dtypes to parametrise over, and a brute-force renderer."""

import pytest
import torch

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture(params=[torch.float32, torch.float64], ids=["float32", "float64"])
def dtype(request):
    return request.param


@pytest.fixture(params=DEVICES)
def device(request):
    return torch.device(request.param)


def _brute_force_render(image, coc, psf, scatter):
    """Independent double loop over output and source pixels, from `psf.kernel` (float64)."""
    _, c, h, w = image.shape
    half = psf.half_width(float(coc.max()))
    out = torch.zeros_like(image)
    for py in range(h):
        for px in range(w):
            num, den = torch.zeros(c, dtype=image.dtype), 0.0
            for qy in range(max(0, py - half), min(h, py + half + 1)):
                for qx in range(max(0, px - half), min(w, px + half + 1)):
                    # scatter: the source's PSF (normalised over its full discrete window);
                    # gather: the output's PSF, at the same offset output - source
                    owner = coc[0, 0, qy, qx] if scatter else coc[0, 0, py, px]
                    wgt = psf.kernel(owner, 2 * half + 1)[0][half + py - qy, half + px - qx]
                    num += wgt * image[0, :, qy, qx]
                    den += float(wgt)
            out[0, :, py, px] = num / den
    return out


@pytest.fixture
def brute_force_render():
    """`f(image, coc, psf, scatter)`: the rendering by an independent double loop (batch 0)."""
    return _brute_force_render
