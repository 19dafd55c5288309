"""Image sensors: conversion between sensor metres and pixels."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from .checks import (
    ParamLike,
    broadcast_to_batch,
    check_param_batch,
    check_parameters,
    no_unit_warnings,
    register_physical,
)
from .checks import format_param as _fmt

_UNITS = {"pixel_pitch": "metres", "downsample": ""}


class Sensor(nn.Module):
    """A pixel grid on the image plane.

    Args:
        pixel_pitch: distance between pixel centres of the full-resolution sensor, in metres, > 0
            (e.g. `5.6e-6`). A float, a 0-d or a `(B,)` tensor, or an `nn.Parameter`.
            Values are checked again at every use (an optimiser may move an `nn.Parameter`),
            and a pitch over 1 mm warns ("did you give millimetres?").
        resolution: optional full-resolution `(height, width)` in pixels, for reference.
        cfa: optional colour-filter-array pattern, e.g. `"RGGB"`.
        downsample: factor by which images were downsampled from the sensor (binning, half-size
            raw decoding, resizing), > 0. It multiplies the effective pixel pitch: the paper's
            NYU frames use `Sensor(5.6e-6, downsample=4)`.

    Example:
        >>> sensor = Sensor(5.6e-6, downsample=4)
        >>> round(sensor.effective_pixel_pitch.item(), 10)
        2.24e-05
        >>> sensor.to_pixels(torch.tensor(44.8e-6))
        tensor(2.)
    """

    pixel_pitch: Tensor
    downsample: Tensor

    def __init__(
        self,
        pixel_pitch: ParamLike,
        resolution: tuple[int, int] | None = None,
        cfa: str | None = None,
        downsample: ParamLike = 1.0,
    ):
        super().__init__()
        register_physical(self, _UNITS, {"pixel_pitch": pixel_pitch, "downsample": downsample})
        if resolution is not None:
            if len(resolution) != 2 or any(int(r) <= 0 for r in resolution):
                raise ValueError(
                    f"resolution must be (height, width) in pixels, both > 0, got {resolution!r}"
                )
            resolution = (int(resolution[0]), int(resolution[1]))
        self.resolution = resolution
        self.cfa = cfa

    @classmethod
    def from_effective_pitch(cls, pixel_pitch: ParamLike) -> Sensor:
        """A sensor for images whose effective pitch (sensor pitch x downsampling) is
        `pixel_pitch`, in metres. No "millimetres?" warning: a small image downsampled from a
        large sensor may have a pitch over 1 mm.

        Example:
            >>> Sensor.from_effective_pitch(3e-3).to_pixels(torch.tensor(6e-3))
            tensor(2.)
        """
        with no_unit_warnings():
            return cls(pixel_pitch)

    def extra_repr(self) -> str:
        return (
            f"pixel_pitch={_fmt(self.pixel_pitch)} m, downsample={_fmt(self.downsample)}, "
            f"resolution={self.resolution}, cfa={self.cfa}"
        )

    @property
    def effective_pixel_pitch(self) -> Tensor:
        """Pixel pitch of the images actually used, `pixel_pitch * downsample`, in metres."""
        check_parameters(self, _UNITS)
        return self.pixel_pitch * self.downsample

    def to_pixels(self, length_m: Tensor) -> Tensor:
        """Convert lengths on the sensor from metres to (effective) pixels.

        Computed in `length_m`'s dtype (`ThinLens` gives at least float32).

        Raises:
            ValueError: if `pixel_pitch` or `downsample` is no longer finite and > 0 (e.g. after
                an optimiser step), naming it.
        """
        if length_m.ndim and length_m.shape[0] != 1:  # batch 1 broadcasts against (B,) values
            check_param_batch(self, "length_m", length_m.shape)
        return length_m / broadcast_to_batch(self.effective_pixel_pitch, length_m)

    def to_metres(self, length_px: Tensor) -> Tensor:
        """Convert lengths on the sensor from (effective) pixels to metres."""
        if length_px.ndim and length_px.shape[0] != 1:  # batch 1 broadcasts against (B,) values
            check_param_batch(self, "length_px", length_px.shape)
        return length_px * broadcast_to_batch(self.effective_pixel_pitch, length_px)


def relative_light(f_number: Tensor, reference_f_number: Tensor | float) -> Tensor:
    """The light a shot at `f_number` gathers relative to one at `reference_f_number` with the
    same exposure time: `(reference_f_number / f_number)**2` (the aperture's area), the `light`
    of `noise_std`. Differentiable in `f_number`.

    Example:
        >>> relative_light(torch.tensor([2.8, 5.6]), 2.8)  # the same, two stops down
        tensor([1.0000, 0.2500])
    """
    return (reference_f_number / f_number) ** 2


def noise_std(intensity: Tensor, read: float, shot: float, light: Tensor | float = 1.0) -> Tensor:
    """Standard deviation of a sensor's noise at linear `intensity` (full scale 1): read noise
    `read` and shot noise `sqrt(shot * intensity)` at a reference exposure, for a photo that
    gathered `light` times that exposure's light and was scaled back to the same brightness
    (the read noise divided by `light`, the shot noise by `sqrt(light)`). Stopping down one
    stop (`light` 1/2) doubles the read noise and raises the shot noise by `sqrt(2)`.
    Differentiable in `intensity` and `light`.

    Example:
        >>> noise_std(torch.tensor([0.0, 1.0]), read=0.004, shot=0.0004)
        tensor([0.0040, 0.0204])
        >>> noise_std(torch.tensor([1.0]), read=0.0, shot=0.0004, light=0.25)  # two stops down
        tensor([0.0400])
    """
    variance = read**2 / light**2 + shot * intensity.clamp_min(0) / light
    # no infinite slope where the variance is 0 (no read noise, black pixel)
    return torch.sqrt(torch.as_tensor(variance).clamp_min(torch.finfo(intensity.dtype).tiny))


def add_noise(images: Tensor, read: float, shot: float, light: Tensor | float = 1.0,
              generator: torch.Generator | None = None) -> Tensor:
    """`images` (linear, full scale 1) with Gaussian sensor noise of `noise_std` drawn from
    `generator` (None: the global one of `images`' device); `light` broadcasts against `images`
    (e.g. `(1,F,1,1,1)` for `(B,F,C,H,W)` focal stacks, one value per shot). Differentiable in
    `images` and `light` (the draw is fixed).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> noisy = add_noise(torch.full((1, 3, 64, 64), 0.5), 0.004, 0.0004, generator=g)
        >>> round(float(noisy.std()), 3)  # noise_std at 0.5: sqrt(0.004**2 + 0.0002)
        0.015
    """
    draw = torch.randn(images.shape, generator=generator, dtype=images.dtype,
                       device=images.device if generator is None else generator.device)
    return images + noise_std(images, read, shot, light) * draw.to(images.device)
