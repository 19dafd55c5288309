"""Run a fully convolutional network on a large image in overlapping tiles."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from torch import Tensor


def check_tiling(tile: int, overlap: int) -> None:
    """Raise `ValueError` unless `tile > 0` and `overlap >= 0` pixels."""
    if tile <= 0 or overlap < 0:
        raise ValueError(f"tile must be > 0 and overlap >= 0 pixels, got tile={tile!r} and "
                         f"overlap={overlap!r}")


def apply_in_tiles(fn: Callable[..., Tensor], inputs: Sequence[Tensor | None], tile: int,
                   overlap: int) -> Tensor:
    """`fn(*inputs)` computed tile by tile over the last two (spatial) dimensions.

    Each tile keeps a centre of `tile` pixels square and sees `overlap` pixels of context on every
    side that is not an image border, so seams see the same context as the inside.

    Args:
        fn: maps spatial crops of `inputs` (same order; None stays None) to `(B, C, h, w)`.
        inputs: tensors whose last two dimensions are the image's `(H, W)`, or None.
        tile: side of a tile's kept centre, pixels (> 0).
        overlap: context around each tile, pixels (>= 0).

    Returns:
        `(B, C, H, W)`, the tiles' centres put together.

    Example:
        >>> import torch
        >>> x = torch.rand(1, 1, 20, 30)
        >>> blur = lambda t: torch.nn.functional.avg_pool2d(t, 3, 1, 1)
        >>> torch.allclose(apply_in_tiles(blur, [x], tile=8, overlap=2), blur(x))
        True
    """
    check_tiling(tile, overlap)
    h, w = next(t for t in inputs if t is not None).shape[-2:]
    out = None
    for top in range(0, h, tile):
        for left in range(0, w, tile):
            t0, l0 = max(top - overlap, 0), max(left - overlap, 0)
            t1, l1 = min(top + tile + overlap, h), min(left + tile + overlap, w)
            part = fn(*(None if t is None else t[..., t0:t1, l0:l1] for t in inputs))
            if out is None:
                out = part.new_empty(*part.shape[:-2], h, w)
            bottom, right = min(top + tile, h), min(left + tile, w)
            out[..., top:bottom, left:right] = part[..., top - t0:bottom - t0,
                                                    left - l0:right - l0]
    return out
