"""The render window's taps: in-image offsets, the Gaussian's per-source table and the
distance tables of the clamped-distance apertures, shared by the operators and kernels of
`optics.render`.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch import Tensor


def axis_slices(shift: int, size: int) -> tuple[slice, slice] | None:
    """Slices `(source, output)` along an axis of `size` pixels for `output = source + shift`.

    `None` when no pixel pair is inside the image.
    """
    if abs(shift) >= size:
        return None
    if shift >= 0:
        return slice(0, size - shift), slice(shift, size)
    return slice(-shift, size), slice(0, size + shift)


def window_taps(half: int, height: int, width: int) -> Iterator[tuple[int, int, tuple, tuple]]:
    """Yield `(dy, dx, source_index, output_index)` for every in-image offset of the window."""
    for dy in range(-half, half + 1):
        rows = axis_slices(dy, height)
        if rows is None:
            continue
        for dx in range(-half, half + 1):
            cols = axis_slices(dx, width)
            if cols is None:
                continue
            yield dy, dx, (..., rows[0], cols[0]), (..., rows[1], cols[1])


def gaussian_table(sigma: Tensor, half: int) -> Tensor:
    """`exp(-d^2 / (2 sigma^2))` for `d = 0..half`, stacked: `(half+1, *sigma.shape)`."""
    d = torch.arange(half + 1, device=sigma.device, dtype=sigma.dtype)
    d = d.view(-1, *([1] * sigma.ndim))
    return torch.exp(-(d * d) / (2 * sigma * sigma))


def window(dist: Tensor, half: int) -> Tensor:
    """The centre `(2 half + 1)^2` of a square distance table, on the CPU, contiguous (the
    renderer builds the table at least `2 half + 1` wide).

    Example:
        >>> window(torch.arange(25.0).view(5, 5), 1)
        tensor([[ 6.,  7.,  8.],
                [11., 12., 13.],
                [16., 17., 18.]])
    """
    m = (dist.shape[-1] - 1) // 2
    return dist[m - half : m + half + 1, m - half : m + half + 1].detach().cpu().contiguous()


def distinct(table: Tensor) -> tuple[Tensor, Tensor]:
    """The distinct values of a distance table and how often each occurs (in its dtype).

    Example:
        >>> distinct(torch.tensor([[1.0, 0.0], [1.0, 1.0]]))
        (tensor([0., 1.]), tensor([1., 3.]))
    """
    dists, counts = torch.unique(table, return_counts=True)
    return dists.contiguous(), counts.to(table.dtype).contiguous()
