"""Render the focal stack of a scene: one image per shot of its `CameraSettings`."""

from __future__ import annotations

from typing import Any

from torch import Tensor

from .aperture import Aperture
from .camera import CameraSettings
from .checks import check_finite, check_shape
from .lens import compute_dtype


def render_focal_stack(
    image: Tensor,
    depth: Tensor,
    settings: CameraSettings,
    aperture: Aperture | None = None,
    **render_kwargs: Any,
) -> Tensor:
    """Render `image` seen at `depth` through each of the `F` shots of `settings`.

    This is the one focal-stack renderer: focus synthesis for datasets and the self-supervised
    loss both call it. Differentiable in the image, the depth and every camera setting.

    Args:
        image: all-in-focus image `(B, C, H, W)`, linear intensity.
        depth: depth `(B, 1, H, W)` in metres, > 0.
        settings: `(F,)` settings (the same shots for every batch item) or `(B, F)`.
        aperture: override the settings' aperture (e.g. a measured `Mask`).
        **render_kwargs: passed to `optics.render_defocus` (`mode`, `max_kernel_size`, ...).

    Returns:
        `(B, F, C, H, W)` focused images (dtype of `image`; the CoC is computed in at least
        float32).

    Raises:
        ValueError: on wrong shapes, or a NaN or infinite value in `image` (named, with its
            position) or an invalid depth.

    Example:
        >>> import torch
        >>> settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 180e-6)
        >>> stack = render_focal_stack(torch.rand(1, 3, 8, 8), torch.full((1, 1, 8, 8), 3.0),
        ...                            settings)
        >>> stack.shape
        torch.Size([1, 2, 3, 8, 8])
    """
    check_shape("image", image, ["B", "C", "H", "W"])
    check_shape("depth", depth, ["B", "1", "H", "W"])
    check_finite("image", image)
    if not isinstance(settings, CameraSettings):
        raise TypeError(f"settings must be a CameraSettings, got {type(settings).__name__}")
    b, c, h, w = image.shape
    if depth.shape[0] != b or depth.shape[-2:] != image.shape[-2:]:
        raise ValueError(f"depth {tuple(depth.shape)} does not match image {tuple(image.shape)}")
    settings = settings.batched(b)
    if settings.shape[0] != b:
        raise ValueError(f"settings hold {settings.shape[0]} batch items, image {b}")
    n = settings.n_shots
    # Settings in at least float32: a pitch of micrometres underflows in float16.
    camera = settings.to(device=image.device, dtype=compute_dtype(image.dtype)).camera(aperture)
    images = image[:, None].expand(b, n, c, h, w).reshape(b * n, c, h, w)
    depths = depth[:, None].expand(b, n, 1, h, w).reshape(b * n, 1, h, w)
    return camera.render(images, depths, **render_kwargs).reshape(b, n, c, h, w)
