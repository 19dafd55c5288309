"""A camera as built rather than as designed: its focus distances, f-number and aperture mask off
their design values by the tolerances of a real lens (`CameraTolerance`).

A camera designed for depth (`LearnableCamera`, `defocus train --learn-optics`) is only useful
if its gain survives the lens it is built into: a focus ring set a little off, an iris a third of
a stop from its mark, a printed or displayed aperture code with errors in its transmission.
`CameraTolerance.settings` and `CameraTolerance.mask` give the camera as built; rendering with
them and scoring the network trained for the design tells how much of the design's gain is left
(`defocus evaluate --perturb-focus 0.02 --perturb-f-stops 0.333 --perturb-mask 0.05`, or
`--robustness` for the standard set).
"""

from __future__ import annotations

import dataclasses
import math

import torch

from .aperture import Mask
from .camera import CameraSettings


@dataclasses.dataclass(frozen=True)
class CameraTolerance:
    """How a built camera departs from its design.

    Args:
        focus: relative error of every focus distance (0.02: each shot focused 2 % farther).
        f_stops: error of the f-number in stops (1/3: the iris a third of a stop smaller, the
            f-number times `2 ** (1/6)`).
        mask_noise: standard deviation of Gaussian noise added to an aperture mask's
            transmission, as a share of its peak; the result is clipped to `[0, peak]`.
        seed: the seed of that noise.

    Raises:
        ValueError: a value that is not finite, `focus <= -1` or `mask_noise < 0` (named).

    Example:
        >>> design = CameraSettings(0.035, 2.8, [1.0, 3.0], 1e-5)
        >>> built = CameraTolerance(focus=0.02, f_stops=1 / 3).settings(design)
        >>> built.focus_distance.tolist(), round(float(built.f_number[0]), 3)
        ([1.02, 3.06], 3.143)
    """

    focus: float = 0.0
    f_stops: float = 0.0
    mask_noise: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("focus", "f_stops", "mask_noise"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
        if self.focus <= -1 or self.mask_noise < 0:
            raise ValueError(f"need focus > -1 (a relative error) and mask_noise >= 0, got "
                             f"focus={self.focus!r}, mask_noise={self.mask_noise!r}")

    @property
    def exact(self) -> bool:
        """Whether the camera is built exactly to its design (no departure at all)."""
        return not (self.focus or self.f_stops or self.mask_noise)

    def settings(self, settings: CameraSettings) -> CameraSettings:
        """The shots of `settings` as this camera takes them: focus distances and f-numbers
        off by the tolerance (focal length, pixel pitch and aperture as designed)."""
        return dataclasses.replace(settings,
                                   focus_distance=settings.focus_distance * (1 + self.focus),
                                   f_number=settings.f_number * 2 ** (self.f_stops / 2))

    def mask(self, mask: Mask | None) -> Mask | None:
        """`mask` with its transmission off by `mask_noise` (the same noise for a seed); None
        and a noise of 0 leave it as it is."""
        if mask is None or self.mask_noise == 0:
            return mask
        image = mask.image
        noise = torch.randn(image.shape, generator=torch.Generator().manual_seed(self.seed),
                            dtype=image.dtype).to(image.device)
        peak = image.max()
        return Mask((image + self.mask_noise * peak * noise).clamp(min=0).minimum(peak))

    def describe(self) -> str:
        """The departures in words ("as designed" for none).

        Example:
            >>> CameraTolerance(focus=-0.02, f_stops=1 / 3).describe()
            'focus -2 %, f-number +0.33 stop'
        """
        parts = ([f"focus {100 * self.focus:+g} %"] if self.focus else []) \
            + ([f"f-number {self.f_stops:+.2f} stop"] if self.f_stops else []) \
            + ([f"mask noise {100 * self.mask_noise:g} % (seed {self.seed})"]
               if self.mask_noise else [])
        return ", ".join(parts) if parts else "as designed"


#: The tolerances of `defocus evaluate --robustness`: a focus ring 2 % off either way, an iris a
#: third of a stop off either way, and (for a learned mask) 5 % noise in its transmission.
ROBUSTNESS = (CameraTolerance(), CameraTolerance(focus=0.02), CameraTolerance(focus=-0.02),
              CameraTolerance(f_stops=1 / 3), CameraTolerance(f_stops=-1 / 3),
              CameraTolerance(mask_noise=0.05))
