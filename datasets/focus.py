"""Focus synthesis: render the focused images of a scene from its all-in-focus image and depth."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import torch
from torch import Tensor

from optics import Aperture, Camera


@dataclass(frozen=True)
class CameraPreset:
    """A dataset's camera: one lens and sensor, several focus settings (all lengths in metres).

    Args:
        focal_length: metres.
        pixel_pitch: *effective* pixel pitch of the dataset's images, metres (sensor pitch times
            the downsampling from sensor to image).
        focus_distances: focus distance of each focused image, metres.
        f_numbers: f-number of each focused image (one value is repeated).
        depth_cap: largest valid depth in metres (evaluation cap).
        min_depth: smallest valid depth in metres.
    """

    focal_length: float
    pixel_pitch: float
    focus_distances: Sequence[float]
    f_numbers: Sequence[float] = field(default=(2.8,))
    depth_cap: float = 10.0
    min_depth: float = 1e-3

    def settings(self, dtype: torch.dtype = torch.float32) -> dict[str, Tensor]:
        """Per-focused-image settings, each a ``(F,)`` tensor (the samples' ``camera`` entry)."""
        n = len(self.focus_distances)
        f_numbers = list(self.f_numbers) * n if len(self.f_numbers) == 1 else list(self.f_numbers)
        if len(f_numbers) != n:
            raise ValueError(
                f"f_numbers must hold 1 or {n} values (one per focus distance), got {self.f_numbers}"
            )
        return {
            "focal_length": torch.full((n,), self.focal_length, dtype=dtype),
            "f_number": torch.tensor(f_numbers, dtype=dtype),
            "focus_distance": torch.tensor(list(self.focus_distances), dtype=dtype),
            "pixel_pitch": torch.full((n,), self.pixel_pitch, dtype=dtype),
        }


def render_focal_stack(
    image: Tensor,
    depth: Tensor,
    settings: Mapping[str, Tensor],
    aperture: Aperture | None = None,
    **render_kwargs,
) -> Tensor:
    """Render one scene under ``F`` camera settings.

    Args:
        image: all-in-focus image ``(3,H,W)`` or ``(1,3,H,W)``, linear in [0, 1].
        depth: depth ``(1,H,W)`` or ``(1,1,H,W)`` in metres, > 0.
        settings: ``(F,)`` tensors as from :meth:`CameraPreset.settings`.
        aperture: PSF shape (Gaussian, ``sigma = CoC/2``, by default).
        **render_kwargs: passed to :func:`optics.render_defocus` (``mode``, ...).

    Returns:
        ``(F,3,H,W)`` focused images.

    Example:
        >>> preset = CameraPreset(0.035, 22.4e-6, focus_distances=(2.0, 8.0))
        >>> stack = render_focal_stack(torch.rand(3, 16, 16), torch.full((1, 16, 16), 3.0),
        ...                            preset.settings())
        >>> stack.shape
        torch.Size([2, 3, 16, 16])
    """
    image = image if image.ndim == 4 else image[None]
    depth = depth if depth.ndim == 4 else depth[None]
    n = int(torch.as_tensor(settings["focus_distance"]).numel())
    camera = Camera.from_settings(
        {k: torch.as_tensor(v).to(image).reshape(-1) for k, v in settings.items()}, aperture
    )
    return camera.render(image.expand(n, -1, -1, -1), depth.expand(n, -1, -1, -1), **render_kwargs)
