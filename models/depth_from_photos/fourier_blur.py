"""Many blurs of one photo, fast: the photo transformed once, each PSF applied as a product.

A depth sweep blurs a photo by the PSF of every candidate depth. `FourierBlur` pads the photo
(mirrored at its borders, then to a size whose only prime factors are 2, 3 and 5) and keeps its
spectrum, so each further blur costs one product and one inverse transform. `psf_kernel` samples
an aperture's PSF at a CoC diameter, and `with_floor` adds the small Gaussian that both sides of
every comparison go through: errors of a fraction of a pixel (quantisation, resampling) weigh
less than the blur being read.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from optics import Aperture
from optics.fourier import fast_length, irfft2, rfft2, runs_in_scipy

#: Gaussian (sigma, pixels) applied to both sides of every comparison (`with_floor`).
FLOOR_SIGMA_PX = 0.5
#: A kernel within this many machine epsilons (of its peak) of its point reflection is taken as
#: point-symmetric, its transfer function as real: sampled disks and Gaussians differ from their
#: reflection by at most 12 (rounding), an odd polygon's by millions.
SYMMETRY_EPS = 64
#: The prime factors of the padded sizes of `FourierBlur` (`optics.fourier.fast_length`).
FFT_PRIMES = (2, 3, 5)


class FourierBlur:
    """Whole-image convolutions of one `(B,C,H,W)` image with many kernels: the image is mirrored
    at its borders by `pad` pixels (and its edge repeated beyond what a small image can mirror)
    and transformed once.

    Example:
        >>> image = torch.rand(1, 3, 20, 30)
        >>> blur = FourierBlur(image, pad=4)
        >>> delta = torch.ones(1, 1)
        >>> torch.allclose(blur.apply(blur.transfer(delta)), image, atol=1e-5)
        True
    """

    def __init__(self, image: Tensor, pad: int):
        self.h, self.w = image.shape[-2:]
        self.pad_y, self.pad_x = pad, pad
        my, mx = min(pad, self.h - 1), min(pad, self.w - 1)
        padded = F.pad(image, (mx, mx, my, my), mode="reflect")
        # then the edge repeated: beyond what a small image can mirror, and on to a size whose
        # only prime factors are 2, 3 and 5 (several times faster transforms)
        extra_y = fast_length(self.h + 2 * pad, FFT_PRIMES) - self.h - 2 * pad
        extra_x = fast_length(self.w + 2 * pad, FFT_PRIMES) - self.w - 2 * pad
        padded = F.pad(padded, (pad - mx, pad - mx + extra_x, pad - my, pad - my + extra_y),
                       mode="replicate")
        self.size = padded.shape[-2:]
        self.spectrum = rfft2(padded)
        self._product: Tensor | None = None  # the CPU's product buffer, reused by every apply

    def transfer(self, kernel: Tensor) -> Tensor:
        """Transfer function of `kernel` `(K,K)` (centred) on the padded grid: real where the
        kernel is point-symmetric (a disk, a Gaussian: its imaginary part is rounding only),
        which halves the products of `apply`."""
        k = kernel.shape[-1]
        if k > min(self.size):
            raise ValueError(f"a {k}-pixel kernel does not fit the padded {tuple(self.size)}")
        # the kernel wrapped around the grid's corners (its centre at (0, 0)): what rolling a
        # corner-placed kernel by -(k // 2) gives. Only its k rows are transformed along the
        # width (the others are zero), then every column along the height: the 2-D transform
        # without the work on zero rows
        h, width = k // 2, self.size[1]
        rows = kernel.new_zeros(k, width)
        rows[:, :k - h] = kernel[:, h:]
        if h:
            rows[:, -h:] = kernel[:, :h]
        spectra = torch.fft.rfft(rows)
        grid = spectra.new_zeros(self.size[0], spectra.shape[-1])
        grid[:k - h] = spectra[h:]
        if h:
            grid[-h:] = spectra[:h]
        transfer = torch.fft.fft(grid, dim=0)
        asymmetry = float((kernel - kernel.flip((0, 1))).abs().max())
        return transfer.real if asymmetry <= SYMMETRY_EPS * torch.finfo(kernel.dtype).eps \
            * float(kernel.abs().max()) else transfer

    def apply(self, transfer: Tensor) -> Tensor:
        """The image `(B,C,H,W)` convolved with the kernel whose `transfer` this is: the
        product with the spectrum, and its inverse transform (`optics.fourier.irfft2`) of the
        rows kept only. On scipy's path both take place in one buffer, reused call after call."""
        scipy = runs_in_scipy(self.spectrum, transfer)
        if scipy and self._product is None:
            self._product = torch.empty_like(self.spectrum)
        out = self._product if scipy else None
        if transfer.is_complex():
            product = torch.mul(self.spectrum, transfer, out=out)
        else:  # a real transfer scales the real and imaginary parts alike
            product = torch.view_as_complex(torch.mul(
                torch.view_as_real(self.spectrum), transfer[..., None],
                out=None if out is None else torch.view_as_real(out)))
        blurred = irfft2(product, self.size, slice(self.pad_y, self.pad_y + self.h),
                         overwrite=scipy)
        return blurred[..., self.pad_x:self.pad_x + self.w]

    def squared_error(self, kernel: Tensor, reference: Tensor) -> Tensor:
        """`(B,H,W)`: the image convolved with `kernel` `(K,K)` against `reference`
        `(B,C,H,W)`, squared and summed over the channels (in place of the blurred image: no
        further copy)."""
        return self.apply(self.transfer(kernel)).sub_(reference).square_().sum(1)


def with_floor(kernel: Tensor) -> Tensor:
    """`kernel` `(K,K)` convolved with the sampled Gaussian of `FLOOR_SIGMA_PX` (spatially, so
    that the result does not depend on the size of the image it is applied to).

    Example:
        >>> k = with_floor(torch.ones(1, 1))
        >>> k.shape, round(float(k.sum()), 6)
        (torch.Size([5, 5]), 1.0)
    """
    half = math.ceil(4 * FLOOR_SIGMA_PX)
    offsets = torch.arange(-half, half + 1, dtype=kernel.dtype, device=kernel.device)
    line = torch.exp(-(offsets**2) / (2 * FLOOR_SIGMA_PX**2))
    gaussian = torch.outer(line, line) / line.sum() ** 2
    padded = F.pad(kernel[None, None], (2 * half,) * 4)
    return F.conv2d(padded, gaussian[None, None])[0, 0]


def psf_kernel(aperture: Aperture, blur_px: float, like: Tensor) -> Tensor:
    """The PSF `(K,K)` of `aperture` at a CoC diameter of `blur_px` pixels, with the dtype and
    device of `like`; a delta under a twentieth of a pixel.

    Example:
        >>> from optics import Disk
        >>> psf_kernel(Disk(), 0.01, torch.zeros(1)).shape
        torch.Size([1, 1])
    """
    if abs(blur_px) < 0.05:  # signed for an oriented aperture
        return torch.ones(1, 1, dtype=like.dtype, device=like.device)
    return aperture.kernel(torch.tensor(blur_px, dtype=like.dtype, device=like.device))[0]
