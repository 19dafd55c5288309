"""Run a fully convolutional network on a large image in overlapping tiles (`apply_in_tiles`),
and a trained depth network on a batch of photos, whole or tiled (`run_network`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch import Tensor, nn


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
        tile: side of a tile's kept centre, pixels (> 0, see `check_tiling`).
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


def run_network(network: nn.Module, image: Tensor, focused: Tensor | None = None,
                settings: Any = None, max_pixels: int | None = None, tile: int = 1024,
                overlap: int = 64, aperture: Any = None) -> Tensor:
    """Depth `(B,1,H,W)` metres of a trained depth network on a batch, in eval mode and without
    gradients: the one place where a network meets photos for evaluation and prediction.

    The network is called as `network(image, focused, settings)`; a network of
    `models.networks.build_network` reads what its input mode needs (`assemble_input`: the
    all-in-focus image alone in `"aif"` mode). Above `max_pixels` pixels (None: never) the
    batch goes through in overlapping tiles (`apply_in_tiles`; the networks are fully
    convolutional, but their group normalisation sees each tile's statistics; a network that
    reads its rows is given each tile's rows in the whole photo).

    Args:
        network: the depth network.
        image: all-in-focus photos `(B,3,H,W)`, on the network's device.
        focused: focused photos `(B,F,3,H,W)` or None.
        settings: their `CameraSettings` or None.
        max_pixels: whole images up to this many pixels go through in one piece.
        tile: side of a tile's kept centre, pixels (checked where it is chosen).
        overlap: context around each tile, pixels.
        aperture: the photos' PSF where their settings cannot name it (a coded aperture), for
            a network that sweeps (`SmallDepthNet(sweep=K)`); None: the settings'.

    Example:
        >>> from models.networks import build_network
        >>> net = build_network("small", "aif", 0, 1.0, 10.0, width=4)
        >>> run_network(net, torch.rand(1, 3, 20, 20), max_pixels=100, tile=8, overlap=4).shape
        torch.Size([1, 1, 20, 20])
    """
    was_training = network.training
    extra = {} if aperture is None else {"aperture": aperture}
    network.eval()
    try:
        with torch.no_grad():
            if max_pixels is None or image.shape[-2] * image.shape[-1] <= max_pixels:
                return network(image, focused, settings, **extra)
            if getattr(network, "position", False):  # each tile's rows in the whole photo
                rows = network.row_map(*image.shape[-2:], image.device, image.dtype)
                return apply_in_tiles(lambda x, f, r: network(x, f, settings, rows=r, **extra),
                                      [image, focused, rows], tile, overlap)
            return apply_in_tiles(lambda x, f: network(x, f, settings, **extra),
                                  [image, focused], tile, overlap)
    finally:
        network.train(was_training)
