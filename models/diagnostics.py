"""Is the self-supervised loss right? Its value at the true depth against the alternatives.

A loss that trains depth without labels is only as good as its image formation model: on real
pairs with depth, the rendered photo at the *true* depth must reproduce the real one better than
at any wrong depth. `loss_at_depths` scores, scene by scene, the true depth, its *mirror* across
the focus plane (the depth of the same blur on the other side: `1/d' = 2/f - 1/d`, clamped to the
range), the two ends of the depth range and constant depths. If the true depth does not score
best, no network trained through that loss can find it: the model of the pair is wrong
(unregistered photos, an exposure difference, a blur floor, the wrong PSF).

A camera calibrated by the blur's squared error need not be the one the loss agrees with: the
paper's loss (SSIM, L1, sharpness) may prefer a larger or smaller blur at the true depth.
`blur_scale_losses` measures the loss at the true depth with every CoC scaled, and
`match_blur_scale` picks the scale the loss prefers on the training scenes (by dividing the
camera's effective pixel pitch by it; `write_blur_matched_camera` writes the camera JSON so
scaled), so that the true depth scores best under the loss that trains the network.

With one focus plane the blur itself can hold the side of the plane only through an aperture
without point symmetry (`optics.Aperture.oriented`): `side_told` measures how well it does.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from os import PathLike
from typing import Any

import kornia
import torch
from torch import Tensor

from optics import Aperture, CameraSettings, collate

from .depth_from_photos.side import mirror_depth
from .depth_from_photos.sweep import blur_errors

#: a self-supervised loss: `(depth (B,1,H,W), image (B,3,H,W), focused (B,F,3,H,W), settings)`
#: -> a dict with "loss" (e.g. `models.losses.DefocusLoss`)
Loss = Callable[..., Mapping[str, Tensor]]


def candidate_depths(sample: Mapping[str, Any], depth_range: tuple[float, float],
                     constants: Sequence[float] = ()) -> dict[str, Tensor]:
    """The depth maps `loss_at_depths` scores for one batched sample: `"true"`, `"mirror"`,
    `"near end"`, `"far end"`, `"focus"` and one `"constant X m"` per constant."""
    depth = sample["depth"]
    focus = float(sample["camera"].focus_distance.reshape(-1)[0])
    out = {"true": depth, "mirror": mirror_depth(depth, focus, depth_range)}
    for name, value in (("near end", depth_range[0]), ("far end", depth_range[1]),
                        ("focus", focus), *((f"constant {c:g} m", c) for c in constants)):
        out[name] = torch.full_like(depth, float(value))
    return out


def loss_at_depths(samples: Iterable[Mapping[str, Any]], loss: Loss,
                   depth_range: tuple[float, float], constants: Sequence[float] = (),
                   ) -> list[dict[str, float]]:
    """The self-supervised `loss` of each sample at the true depth and at the alternatives of
    `candidate_depths`, scene by scene.

    Args:
        samples: unbatched samples with `image`, `focused`, `camera` and `depth` (metres).
        loss: the loss to judge, called as `loss(depth, image, focused, camera)["loss"]`.
        depth_range: `(near, far)` metres: the range ends, and where the mirror is clamped.
        constants: more constant depths to score, metres.

    Returns:
        one dict per sample: `"id"` (if the sample has one) and the loss per candidate name.

    Example:
        >>> from models.losses import DefocusLoss
        >>> from optics import CameraSettings, render_focal_stack
        >>> camera = CameraSettings(0.05, 2.0, [2.0], 30e-6)
        >>> image = torch.rand(3, 32, 32)
        >>> depth = torch.full((1, 32, 32), 4.0)
        >>> depth[..., 16:] = 1.2
        >>> batched = CameraSettings(0.05, 2.0, [[2.0]], 30e-6)
        >>> focused = render_focal_stack(image[None], depth[None], batched)[0]
        >>> sample = {"image": image, "focused": focused, "camera": camera, "depth": depth}
        >>> row = loss_at_depths([sample], DefocusLoss(), (0.5, 10.0))[0]
        >>> min(row, key=row.get)
        'true'
    """
    rows = []
    for sample in samples:
        batch = collate([sample])
        row: dict[str, Any] = {} if "id" not in sample else {"id": sample["id"]}
        with torch.no_grad():
            for name, depth in candidate_depths(batch, depth_range, constants).items():
                terms = loss(depth, batch["image"], batch["focused"], batch["camera"])
                row[name] = float(terms["loss"])
        rows.append(row)
    return rows


#: the CoC scales `match_blur_scale` tries by default
BLUR_SCALES = (0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6)


def blur_scale_losses(samples: Iterable[Mapping[str, Any]], loss: Loss,
                      scales: Sequence[float] = BLUR_SCALES) -> dict[float, float]:
    """The loss at the true depth with every CoC scaled by each of `scales` (the samples'
    effective pixel pitch divided by it), averaged over the samples, each sample's losses
    divided by its loss at scale 1 so that every scene counts alike.

    Args:
        samples: unbatched samples with `image`, `focused`, `camera` and `depth` (metres).
        loss: the loss, called as `loss(depth, image, focused, camera)["loss"]`.
        scales: the CoC scales to score, each > 0.

    Example:
        >>> from models.losses import DefocusLoss
        >>> from optics import CameraSettings, render_focal_stack
        >>> camera = CameraSettings(0.05, 2.0, [2.0], 30e-6)
        >>> image = torch.rand(3, 32, 32, generator=torch.Generator().manual_seed(0))
        >>> depth = torch.full((1, 32, 32), 4.0)
        >>> depth[..., 16:] = 1.2
        >>> focused = render_focal_stack(image[None], depth[None], camera.batched())[0]
        >>> sample = {"image": image, "focused": focused, "camera": camera, "depth": depth}
        >>> losses = blur_scale_losses([sample], DefocusLoss(), (0.8, 1.0, 1.25))
        >>> min(losses, key=losses.get)
        1.0
    """
    bad = [s for s in scales if not s > 0]
    if not scales or bad:
        raise ValueError(f"scales must be a non-empty sequence of numbers > 0, got {scales!r}")
    totals = dict.fromkeys(scales, 0.0)
    count = 0
    for sample in samples:
        batch = collate([sample])
        camera = batch["camera"]
        values = {}
        with torch.no_grad():
            for scale in {1.0, *scales}:
                scaled = camera.replace(pixel_pitch=camera.pixel_pitch / scale)
                terms = loss(batch["depth"], batch["image"], batch["focused"], scaled)
                values[scale] = float(terms["loss"])
        for scale in scales:
            totals[scale] += values[scale] / max(values[1.0], 1e-12)
        count += 1
    if count == 0:
        raise ValueError("blur_scale_losses needs at least one sample")
    return {scale: total / count for scale, total in totals.items()}


def match_blur_scale(samples: Iterable[Mapping[str, Any]], loss: Loss,
                     scales: Sequence[float] = BLUR_SCALES) -> float:
    """The CoC scale of `scales` at which `loss` scores the true depth best on `samples` (see
    `blur_scale_losses`): divide the camera's effective pixel pitch by it to train with the
    blur the loss agrees with. Choose it on training scenes, never on the scored ones.

    Example:
        >>> from models.losses import DefocusLoss
        >>> from optics import CameraSettings, render_focal_stack
        >>> true = CameraSettings(0.05, 2.0, [2.0], 30e-6)
        >>> image, depth = torch.rand(3, 32, 32), torch.full((1, 32, 32), 4.0)
        >>> focused = render_focal_stack(image[None], depth[None], true.batched())[0]
        >>> stated = true.replace(pixel_pitch=true.pixel_pitch / 1.3)  # says 1.3x the real blur
        >>> match_blur_scale([{"image": image, "focused": focused, "camera": stated,
        ...                    "depth": depth}], DefocusLoss(), (0.77, 1.0, 1.3))
        0.77
    """
    losses = blur_scale_losses(samples, loss, scales)
    return min(losses, key=losses.get)


def write_blur_matched_camera(samples: Iterable[Mapping[str, Any]], camera: str | PathLike,
                              out: str | PathLike, loss: Loss,
                              scales: Sequence[float] = BLUR_SCALES) -> float:
    """Write the camera JSON `camera` to `out` with its blur scaled to what `loss` prefers on
    `samples` (`match_blur_scale`; samples rendered with that camera, e.g. training scenes):
    its effective pixel pitch divided by the scale, its extra values kept and the scale added
    as `loss_blur_scale`. Returns the scale.

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> from models.losses import DefocusLoss
        >>> from optics import render_focal_stack
        >>> folder = Path(tempfile.mkdtemp())
        >>> true = CameraSettings(0.05, 2.0, [2.0], 30e-6)
        >>> stated = true.replace(pixel_pitch=true.pixel_pitch / 1.3)  # says 1.3x the real blur
        >>> stated.to_json(folder / "camera.json", reference_f_number=8.0)
        >>> image, depth = torch.rand(3, 32, 32), torch.full((1, 32, 32), 4.0)
        >>> focused = render_focal_stack(image[None], depth[None], true.batched())[0]
        >>> sample = {"image": image, "focused": focused, "camera": stated, "depth": depth}
        >>> write_blur_matched_camera([sample], folder / "camera.json", folder / "matched.json",
        ...                           DefocusLoss(), (0.77, 1.0, 1.3))
        0.77
        >>> CameraSettings.read_json(folder / "matched.json")[1]
        {'reference_f_number': 8.0, 'loss_blur_scale': 0.77}
    """
    scale = match_blur_scale(samples, loss, scales)
    settings, extra = CameraSettings.read_json(camera)
    settings.replace(pixel_pitch=settings.pixel_pitch / scale).to_json(
        out, **extra, loss_blur_scale=scale)
    return scale


def true_depth_wins(row: Mapping[str, Any], tolerance: float = 0.02) -> bool:
    """Whether the true depth's loss is within `tolerance` (relative) of the best constant's
    (the range ends, the focus plane and the named constants of `loss_at_depths`).

    Example:
        >>> true_depth_wins({"true": 1.01, "mirror": 0.9, "far end": 1.0})
        True
    """
    constants = [v for k, v in row.items() if k not in ("id", "true", "mirror")]
    return not constants or row["true"] <= (1 + tolerance) * min(constants)


def side_told(image: Tensor, focused: Tensor, aperture: Aperture, signed_coc_px: Tensor,
              mask: Tensor | None = None, window: int = 15, levels: int = 12,
              min_blur_px: float = 1.0) -> tuple[float, int]:
    """How well one focused photo's blur tells the side of the focus plane, given its size:
    per pixel, whether the all-in-focus `image` `(1,3,H,W)` blurred through `aperture` at the
    pixel's true signed CoC (`signed_coc_px` `(1,1,H,W)`, positive beyond the plane) matches
    `focused` `(1,3,H,W)` better than at the mirrored one (`blur_errors` averaged over
    `window`-pixel squares, the magnitude rounded to one of `levels` between 0.5 px and the
    largest). A point-symmetric aperture blurs both alike: a tie counts half, so it scores 0.5.

    Returns:
        (the share of the counted pixels whose side is told right, how many were counted: those
        of `mask` blurred by more than `min_blur_px`).

    Example:
        >>> from optics import Disk
        >>> image = torch.rand(1, 3, 24, 24, dtype=torch.float64)
        >>> coc = torch.full((1, 1, 24, 24), 3.0, dtype=torch.float64)
        >>> side_told(image, image, Disk(), coc)
        (0.5, 576)
    """
    magnitude = signed_coc_px[0, 0].abs()
    steps = torch.linspace(0.5, max(float(magnitude.max()), 0.5), levels, dtype=image.dtype,
                           device=image.device)
    blurs = torch.cat([steps, -steps]) if aperture.oriented else steps  # symmetric: one side
    errors = kornia.filters.box_blur(blur_errors(image, focused, aperture, blurs),
                                     (window, window))[0]
    level = (magnitude[None] - steps[:, None, None]).abs().argmin(0)[None]
    beyond = errors[:levels].gather(0, level)[0]
    before = errors[levels:].gather(0, level)[0] if aperture.oriented else beyond
    right = torch.where(beyond < before, signed_coc_px[0, 0] > 0, signed_coc_px[0, 0] < 0)
    told = torch.where(beyond == before, 0.5, right.to(image.dtype))
    counted = magnitude > min_blur_px
    if mask is not None:
        counted &= mask.reshape(magnitude.shape).bool()
    count = int(counted.sum())
    return (float(told[counted].mean()) if count else math.nan), count
