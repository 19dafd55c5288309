"""Real 2-D Fourier transforms of images, fast on a CPU: the transform lengths they are fast at
(`fast_length`), and the forward and inverse transforms (`rfft2`, `irfft2`), scipy's on a CPU
where no gradient is asked for (the planes shared among `torch.get_num_threads()` threads, in
place, the inverse of the rows kept only: about 2.5x faster on megapixel images than
`torch.fft`, whose fresh buffers page-fault on every call), `torch.fft`'s elsewhere. The
translations of `optics.alignment` and the many blurs of one photo of
`models.depth_from_photos.fourier_blur` run through them.

The threads are this module's own, each running a single-threaded scipy transform, and they end
with the call: scipy's `workers` would keep a thread pool alive whose fork handler now and then
hangs the next `fork()` of the process (a `DataLoader` starting its workers after a depth was
estimated).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.fft
import torch
from torch import Tensor


def fast_length(n: int, primes: tuple[int, ...] = (2, 3, 5, 7)) -> int:
    """The smallest length >= `n` whose only prime factors are `primes`: a length the FFT is
    fast at (a prime length such as 2017 takes it many times longer).

    Example:
        >>> fast_length(4034), fast_length(1084), fast_length(97, (2, 3, 5))  # 2 x 2017, 4 x 271
        (4050, 1120, 100)
    """
    best = n
    while True:
        m = best
        for p in primes:
            while m % p == 0:
                m //= p
        if m == 1:
            return best
        best += 1


def runs_in_scipy(*tensors: Tensor) -> bool:
    """Whether work on `tensors` runs in scipy (these transforms, the filters of
    `models.depth_from_photos.thin_lens`): on a CPU, no gradient asked of any of them.

    Example:
        >>> runs_in_scipy(torch.zeros(2)), runs_in_scipy(torch.zeros(2, requires_grad=True))
        (True, False)
    """
    return all(t.device.type == "cpu" for t in tensors) and not (
        torch.is_grad_enabled() and any(t.requires_grad for t in tensors))


def rfft2(image: Tensor) -> Tensor:
    """`torch.fft.rfft2(image)` over the last two dimensions of `image` `(..., H, W)`.

    Example:
        >>> x = torch.rand(2, 6, 8)
        >>> torch.allclose(rfft2(x), torch.fft.rfft2(x), atol=1e-5)
        True
    """
    if not runs_in_scipy(image):
        return torch.fft.rfft2(image)
    x = image.detach().numpy()
    shape = (*x.shape[:-1], x.shape[-1] // 2 + 1)
    return torch.from_numpy(_by_planes(scipy.fft.rfft2, x, shape,
                                       np.result_type(x.dtype, np.complex64)))


def irfft2(spectrum: Tensor, size: tuple[int, int], rows: slice | None = None,
           overwrite: bool = False) -> Tensor:
    """`torch.fft.irfft2(spectrum, s=size)[..., rows, :]`: the inverse of `rfft2` for an image of
    `size` `(H, W)`, of the rows `rows` only (all by default). With `overwrite` the spectrum
    may be overwritten: scipy's path then takes the column transforms in its memory instead of
    a new array's.

    Example:
        >>> x = torch.rand(2, 6, 8)
        >>> torch.allclose(irfft2(rfft2(x), (6, 8), slice(1, 4)), x[:, 1:4], atol=1e-6)
        True
    """
    rows = slice(None) if rows is None else rows
    if not runs_in_scipy(spectrum):
        return torch.fft.irfft2(spectrum, s=size)[..., rows, :]
    spectrum = spectrum.detach().numpy()
    kept = len(range(size[0])[rows])

    def inverse(part: np.ndarray) -> np.ndarray:
        columns = scipy.fft.ifft(part, axis=-2, overwrite_x=overwrite)
        return scipy.fft.irfft(columns[..., rows, :], n=size[1])

    return torch.from_numpy(_by_planes(inverse, spectrum, (*spectrum.shape[:-2], kept, size[1]),
                                       np.finfo(spectrum.dtype).dtype))


def _by_planes(transform: Callable[[np.ndarray], np.ndarray], x: np.ndarray,
               shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    """`transform(x)` of `shape` and `dtype`, for `x` `(..., H, W)` and a `transform` of each
    plane `(H, W)` alone: the planes are shared among `torch.get_num_threads()` threads (scipy
    releases the GIL), each writing its part of the result."""
    planes = x.reshape(-1, *x.shape[-2:])
    threads = min(torch.get_num_threads(), len(planes))
    if threads <= 1:
        return transform(x)
    out = np.empty((len(planes), *shape[-2:]), dtype)
    bounds = np.linspace(0, len(planes), threads + 1).round().astype(int)

    def part(start: int, stop: int) -> None:
        out[start:stop] = transform(planes[start:stop])

    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(part, bounds[:-1], bounds[1:]))
    return out.reshape(shape)
