"""`CalibrationPair`: a sharp reference, the defocused photo of the same view and its depth."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..checks import check_tensor


@dataclass
class CalibrationPair:
    """A sharp reference, the defocused photo of the same view and the depth it shows.

    Args:
        sharp: the sharp reference `(3,H,W)` or `(1,3,H,W)`, linear (e.g. a stopped-down shot).
        blurred: the defocused photo, same shape, linear.
        depth: distance of the planar target in metres (a float), or a depth map `(1,H,W)` or
            `(1,1,H,W)` in metres.
        name: a label for tables and figures.

    Raises:
        ValueError: if the images differ in shape, hold NaN or infinite values, or one of them is
            constant (an all-black frame, a lens cap: no texture to measure blur on), or the
            depth is not positive and finite.
    """

    sharp: Tensor
    blurred: Tensor
    depth: float | Tensor
    name: str = ""

    def __post_init__(self) -> None:
        label = f"pair {self.name!r}" if self.name else "pair"
        for attr in ("sharp", "blurred"):
            value = getattr(self, attr)
            check_tensor(f"{label}: {attr}", value, floating=True)  # an image in [0, 1]
            value = value.unsqueeze(0) if value.ndim == 3 else value
            check_tensor(f"{label}: {attr}", value, ["1", "C", "H", "W"], values="finite")
            _check_not_constant(f"{label}: {attr}", value)
            setattr(self, attr, value)
        if self.sharp.shape != self.blurred.shape:
            raise ValueError(
                f"{label}: sharp and blurred images must have the same shape, got "
                f"{tuple(self.sharp.shape)} and {tuple(self.blurred.shape)}"
            )
        self.depth = _depth_map(label, self.depth, self.sharp) if isinstance(
            self.depth, Tensor) else _distance(label, self.depth)

    def depth_map(self, like: Tensor) -> Tensor:
        """The depth as a `(1,1,H,W)` map in metres on `like`'s device and dtype."""
        if isinstance(self.depth, Tensor):
            return self.depth.to(like)
        return torch.full((1, 1, *like.shape[-2:]), self.depth, dtype=like.dtype, device=like.device)

    @property
    def typical_depth(self) -> float:
        """The target distance, or the median of the depth map, in metres."""
        return self.depth if isinstance(self.depth, float) else float(self.depth.median())


def _check_not_constant(name: str, image: Tensor) -> None:
    """A constant image (all zero, saturated, a lens cap) shows no blur: refuse it."""
    low, high = float(image.min()), float(image.max())
    if high - low <= 1e-12 * max(abs(high), 1.0):
        raise ValueError(
            f"{name} is constant (every pixel {low:.4g}), so it shows no blur to measure (an "
            "all-black or saturated frame, a lens cap?); shoot a textured, well-exposed target"
        )


def _depth_map(label: str, depth: Tensor, sharp: Tensor) -> Tensor:
    depth = depth if depth.ndim == 4 else depth.reshape(1, *depth.shape)
    height, width = sharp.shape[-2:]  # the images' size
    check_tensor(f"{label}: depth map", depth, ["1", "1", str(height), str(width)],
                 values="positive", unit="metres")
    return depth


def _distance(label: str, depth: object) -> float:
    distance = float(depth)  # type: ignore[arg-type]
    if not (math.isfinite(distance) and distance > 0):
        raise ValueError(
            f"{label}: depth (target distance) must be finite and > 0 metres, got {depth!r}"
        )
    return distance
