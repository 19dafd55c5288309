"""Joint transforms of a sample: the image, its focused images, depth and mask move together.

Geometric transforms (crop, resize, flip) are applied identically to `image`, `focused`,
`depth` and `mask` so they stay pixel-aligned. Resizing changes the *effective* pixel pitch
(the `camera` settings' pixel pitch) by the resize factor, so CoC sizes in pixels stay physically right;
cropping and flipping do not. Colour augmentation multiplies every image (all-in-focus and focused)
by the same per-channel gains: a linear blur commutes with that, so the focused images remain the
renders of the augmented all-in-focus image.

As in torchvision's transforms v2, `JointAugment.make_params` samples once and
`JointAugment.apply` applies the same parameters to every entry.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

from .io import is_size, require_args

#: Sample entries laid out as images `(..., H, W)`.
SPATIAL_KEYS = ("image", "focused", "depth", "mask", "hint")


def crop_sample(sample: dict[str, Any], top: int, left: int, height: int, width: int) -> dict:
    """Crop every spatial entry of `sample` to rows `top:top+height`, columns `left:left+width`.

    Raises:
        ValueError: the window does not fit inside the image.

    Example:
        >>> s = crop_sample({"image": torch.rand(3, 8, 10), "depth": torch.ones(1, 8, 10)}, 1, 2, 4, 5)
        >>> s["image"].shape, s["depth"].shape
        (torch.Size([3, 4, 5]), torch.Size([1, 4, 5]))
    """
    h, w = sample["image"].shape[-2:]
    if top < 0 or left < 0 or height <= 0 or width <= 0 or top + height > h or left + width > w:
        raise ValueError(
            f"crop (top={top}, left={left}, height={height}, width={width}) must fit inside the "
            f"{h}x{w} image"
        )
    out = dict(sample)
    for key in SPATIAL_KEYS:
        if key in sample:
            out[key] = sample[key][..., top : top + height, left : left + width]
    return out


def resize_sample(sample: dict[str, Any], size: Sequence[int]) -> dict:
    """Resize `sample` to `size = (height, width)` pixels and scale the effective pixel pitch.

    Images use antialiased bilinear resampling; depth and mask use nearest neighbour (no depth is
    invented across object edges and the mask stays exact). The effective pixel pitch of the
    `camera` settings (metres) is multiplied by the geometric mean of the two resize factors.

    Example:
        >>> from optics import CameraSettings
        >>> s = {"image": torch.rand(3, 8, 8), "depth": torch.ones(1, 8, 8),
        ...      "camera": CameraSettings(0.05, 2.0, [2.0], 1e-5).to(torch.float32)}
        >>> r = resize_sample(s, (4, 4))
        >>> r["image"].shape, r["camera"].pixel_pitch
        (torch.Size([3, 4, 4]), tensor([2.0000e-05]))
    """
    height, width = (int(s) for s in size)
    h, w = sample["image"].shape[-2:]
    if (h, w) == (height, width):
        return dict(sample)
    out = dict(sample)
    for key in SPATIAL_KEYS:
        if key not in sample:
            continue
        value = sample[key]
        flat = value.reshape(-1, *value.shape[-3:]) if value.ndim == 4 else value[None]
        if key in ("image", "focused"):
            # non-negative weights that sum to 1: no overshoot to clip, and linear highlights
            # above 1 keep their value
            flat = F.interpolate(flat, size=(height, width), mode="bilinear", align_corners=False,
                                 antialias=True)
        else:
            flat = F.interpolate(flat.to(torch.float32) if key == "mask" else flat,
                                 size=(height, width), mode="nearest-exact")
            flat = flat.bool() if key == "mask" else flat
        out[key] = flat.reshape(*value.shape[:-2], height, width)
    if "camera" in sample:
        camera = sample["camera"]
        factor = math.sqrt((h / height) * (w / width))
        out["camera"] = camera.replace(pixel_pitch=camera.pixel_pitch * factor)
    return out


def hflip_sample(sample: dict[str, Any]) -> dict:
    """Mirror every spatial entry left to right (the PSFs are symmetric, so renders stay valid)."""
    out = dict(sample)
    for key in SPATIAL_KEYS:
        if key in sample:
            out[key] = sample[key].flip(-1)
    return out


@dataclass
class JointAugment:
    """Random augmentation that keeps image, focused images, depth and mask aligned.

    Args:
        crop_size: `(height, width)` of a random crop in pixels, or None for no crop.
        hflip: probability of a left-right flip.
        gain: per-channel colour gains are drawn from `[1 - gain, 1 + gain]` and applied to the
            all-in-focus and every focused image alike (results clamped to [0, 1]); 0 disables.

    Example:
        >>> aug = JointAugment(crop_size=(4, 4), hflip=0.5, gain=0.1)
        >>> sample = {"image": torch.rand(3, 6, 8), "focused": torch.rand(2, 3, 6, 8),
        ...           "depth": torch.rand(1, 6, 8) + 1, "mask": torch.ones(1, 6, 8, dtype=torch.bool)}
        >>> out = aug(sample, generator=torch.Generator().manual_seed(0))
        >>> out["image"].shape, out["focused"].shape, out["depth"].shape
        (torch.Size([3, 4, 4]), torch.Size([2, 3, 4, 4]), torch.Size([1, 4, 4]))
    """

    crop_size: tuple[int, int] | None = None
    hflip: float = 0.5
    gain: float = 0.0

    def __post_init__(self) -> None:
        require_args(
            ("crop_size", self.crop_size, is_size(self.crop_size),
             "(height, width) in pixels, both > 0"),
            ("hflip", self.hflip, 0.0 <= self.hflip <= 1.0, "a probability in [0, 1]"),
            ("gain", self.gain, 0.0 <= self.gain < 1.0, "in [0, 1)"))
        self.crop_size = None if self.crop_size is None else tuple(int(s) for s in self.crop_size)

    def make_params(
        self, height: int, width: int, generator: torch.Generator | None = None
    ) -> dict[str, Any]:
        """Sample the crop window, the flip and the colour gains once, for an image of that size."""
        params: dict[str, Any] = {}
        if self.crop_size is not None:
            ch, cw = self.crop_size
            if ch > height or cw > width:
                raise ValueError(f"crop_size {self.crop_size} is larger than the image {height}x{width}")
            top = int(torch.randint(0, height - ch + 1, (), generator=generator))
            left = int(torch.randint(0, width - cw + 1, (), generator=generator))
            params["crop"] = (top, left, ch, cw)
        params["flip"] = bool(torch.rand((), generator=generator) < self.hflip)
        if self.gain > 0:
            params["gains"] = 1 + self.gain * (2 * torch.rand(3, generator=generator) - 1)
        return params

    def apply(self, sample: dict[str, Any], params: dict[str, Any]) -> dict:
        """Apply sampled `params` to every entry of `sample`."""
        if "crop" in params:
            sample = crop_sample(sample, *params["crop"])
        if params.get("flip"):
            sample = hflip_sample(sample)
        if "gains" in params:
            sample = dict(sample)
            for key in ("image", "focused"):
                if key in sample:
                    gains = params["gains"].to(sample[key]).reshape(3, 1, 1)
                    sample[key] = (sample[key] * gains).clamp(0, 1)
        return sample

    def __call__(self, sample: dict[str, Any], generator: torch.Generator | None = None) -> dict:
        h, w = sample["image"].shape[-2:]
        return self.apply(sample, self.make_params(h, w, generator))
