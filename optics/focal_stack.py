"""Render the focal stack of a scene: one image per shot of its `CameraSettings`."""

from __future__ import annotations

from typing import Any

from torch import Tensor

from .aperture import Aperture
from .camera import CameraSettings
from .checks import check_tensor, values_checked
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
        depth: depth `(B, 1, H, W)` or `(1, 1, H, W)` (one depth map for every image) in
            metres, > 0.
        settings: `(F,)` settings (the same shots for every batch item), `(1, F)` (the same) or
            `(B, F)`.
        aperture: override the settings' aperture (e.g. a measured `Mask`).
        **render_kwargs: passed to `optics.render_defocus` (`mode`, `max_kernel_size`, ...).

    Returns:
        `(B, F, C, H, W)` focused images (dtype of `image`; the CoC is computed in at least
        float32).

    Raises:
        TypeError: if `image` or `depth` is not a floating-point tensor, or `settings` is not a
            `CameraSettings`.
        ValueError: on wrong shapes (a `depth` or `settings` batch other than 1 or `B`, named
            with both shapes), `depth` on another device than `image`, a NaN or infinite value
            in `image` (named, with its position) or an invalid depth.

    Example:
        >>> import torch
        >>> settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 180e-6)
        >>> stack = render_focal_stack(torch.rand(1, 3, 8, 8), torch.full((1, 1, 8, 8), 3.0),
        ...                            settings)
        >>> stack.shape
        torch.Size([1, 2, 3, 8, 8])
        >>> render_focal_stack(torch.rand(4, 3, 8, 8), torch.full((1, 1, 8, 8), 3.0),
        ...                    settings).shape  # one depth map for the four images
        torch.Size([4, 2, 3, 8, 8])
    """
    from .render.renderer import IMAGE_DIMS, per_pixel_map

    check_tensor("image", image, IMAGE_DIMS, values="finite")
    per_pixel_map("depth", depth, image)  # shape (batch 1 or B), type and device, as given
    if not isinstance(settings, CameraSettings):
        raise TypeError(f"settings must be a CameraSettings, got {type(settings).__name__}")
    check_tensor("depth", depth, values="depth")  # before it is repeated per shot: as given
    b, c, h, w = image.shape
    n = settings.n_shots
    if settings.is_batched and settings.shape[0] not in (1, b):
        raise ValueError(f"settings must have shape ({n},), (1, {n}) or ({b}, {n}) to match "
                         f"image {tuple(image.shape)}, got {tuple(settings.shape)}")
    if b == 0:  # nothing to render (CameraSettings hold at least one batch item)
        return image[:, None].expand(b, n, c, h, w).clone()
    if not settings.is_batched or settings.shape[0] != b:  # (F,) or (1, F): the same shots
        settings = (settings[0] if settings.is_batched else settings).batched(b)
    images = image[:, None].expand(b, n, c, h, w).reshape(b * n, c, h, w)
    depths = depth[:, None].expand(b, n, 1, h, w).reshape(b * n, 1, h, w)
    with values_checked():  # the image, the depth and the settings were checked: trusted
        # Settings in at least float32: a pitch of micrometres underflows in float16.
        settings = settings.to(device=image.device, dtype=compute_dtype(image.dtype))
        rendered = settings.camera(aperture).render(images, depths, **render_kwargs)
    return rendered.reshape(b, n, c, h, w)
