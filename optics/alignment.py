"""Sub-pixel alignment of the shots of a focal stack.

Photos taken one after another move by a pixel or so (a tripod settles, a mirror slaps). Read as
defocus, a shift looks like blur: a one-pixel misalignment adds about a pixel to the blur read
everywhere. `estimate_shift` measures the translation between two photos even when one of them is
defocused: a symmetric PSF does not move the centroid of anything, and the Lucas-Kanade normal
equations below are blind to a symmetric blur (their right-hand side pairs the odd image gradient
with the even blur difference, which sums to zero). `translate` applies a sub-pixel shift without
blurring (a phase ramp in the Fourier domain, the image mirrored at its borders first), unlike
bilinear resampling, whose averaging of neighbours is itself a blur of up to half a pixel.
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Sequence

import kornia
import torch
import torch.nn.functional as F
from torch import Tensor

from .checks import check_finite, check_shape, check_tensor, is_real_number
from .fourier import fast_length, irfft2, rfft2

#: Gaussian smoothing (pixels) of the images whose motion is estimated, by default.
_SIGMA_PX = 1.5
#: Lucas-Kanade iterations per pyramid level of `estimate_shift` and `estimate_motion`.
_SHIFT_ITERATIONS, _MOTION_ITERATIONS = 10, 20


def _check_image(name: str, image: Tensor, dims: Sequence[str] = ("B", "C", "H", "W")) -> None:
    """Refuse `image` unless it is a floating-point tensor of shape `dims` without a NaN or an
    infinity (one NaN spreads over the whole image through the Fourier transform)."""
    check_shape(name, image, dims)
    if not image.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor (float16, bfloat16, float32 or "
                        f"float64), got dtype {image.dtype}; convert it first, e.g. "
                        f"{name}.float() / 255 for 8-bit pixels")
    check_finite(name, image)


def _check_values(name: str, value: Tensor, described: str, *shapes: tuple[int, ...]) -> None:
    """Refuse `value` unless it is a real tensor of one of `shapes` holding finite values."""
    real = isinstance(value, Tensor) and not (value.is_complex() or value.dtype == torch.bool)
    if not real or tuple(value.shape) not in shapes:
        got = (f"shape {tuple(value.shape)}" if real else f"dtype {value.dtype}"
               if isinstance(value, Tensor) else type(value).__name__)
        raise (ValueError if real else TypeError)(
            f"{name} must be a tensor of real numbers {described}, got {got}")
    check_finite(name, value)


def _working(image: Tensor) -> Tensor:
    """`image` in at least float32: the FFT and the resampling have no half-precision kernels
    on every device, and a bfloat16 phase ramp would be off by a percent."""
    return image.to(torch.promote_types(image.dtype, torch.float32))


def translate(image: Tensor, shift: Tensor) -> Tensor:
    """`image` `(B,C,H,W)` moved by `shift` `(B,2)` pixels `(dy, dx)`: `out(p) = image(p - shift)`.

    Exact for band-limited content: the shift is a phase ramp in the Fourier domain (no
    interpolation blur). The image is mirrored at its borders first, so content entering the
    frame is a reflection rather than the opposite border. Differentiable in `image` and `shift`.
    Computed in at least float32 (a `float16`/`bfloat16` image is returned in its dtype); an
    image 1 pixel high (wide) moves along its length only.

    Raises:
        TypeError: for an image that is not floating-point, or a shift that is not a real tensor.
        ValueError: on wrong shapes, or a NaN or infinite value in `image` or `shift`.

    Example:
        >>> image = torch.rand(1, 3, 16, 16)
        >>> moved = translate(image, torch.tensor([[1.0, -2.0]]))
        >>> torch.allclose(moved[..., 4:12, 4:12], image[..., 3:11, 6:14], atol=1e-4)
        True
    """
    _check_image("image", image)
    b = image.shape[0]
    _check_values("shift", shift, f"(B, 2) = ({b}, 2) pixels (dy, dx)", (b, 2))
    return _translate(image, shift)


def _translate(image: Tensor, shift: Tensor) -> Tensor:
    if image.numel() == 0:
        return image.clone()
    work = _working(image)
    h, w = work.shape[-2:]
    shift = shift.to(work)
    reach = int(math.ceil(float(shift.detach().abs().max())))
    pad_y, pad_x = min(h - 1, reach + 16), min(w - 1, reach + 16)
    # the far side padded further, up to a length the FFT is fast at (a prime length such as
    # 4034 = 2 x 2017 takes it ten times longer)
    after_y, after_x = _pad_after(h, pad_y), _pad_after(w, pad_x)
    padded = _periodic_padding(work, pad_y, pad_x, after_y, after_x)
    hp, wp = padded.shape[-2:]
    fy = torch.fft.fftfreq(hp, device=work.device, dtype=work.dtype)[:, None]
    fx = torch.fft.rfftfreq(wp, device=work.device, dtype=work.dtype)[None, :]
    angle = -2 * math.pi * (fy * shift[:, 0, None, None] + fx * shift[:, 1, None, None])
    ramp = torch.polar(torch.ones_like(angle), angle)[:, None]
    out = irfft2(rfft2(padded) * ramp, (hp, wp), slice(pad_y, pad_y + h))
    return out[..., pad_x:pad_x + w].to(image.dtype)


def _pad_after(n: int, pad: int) -> int:
    """Padding after `n` pixels with `pad` before: up to a `fast_length` (a mirror reaches at
    most `n - 1` pixels: a small image keeps its even padding)."""
    after = fast_length(n + 2 * pad) - n - pad
    return after if pad and after < n else pad


def _periodic_padding(image: Tensor, pad_y: int, pad_x: int, after_y: int | None = None,
                      after_x: int | None = None) -> Tensor:
    """`image` mirrored by `pad_y`, `pad_x` pixels before (and `after_y`, `after_x` after; by
    default as many) and faded to its mean over the mirrored part (a raised cosine): the padded
    frame repeats smoothly, so its Fourier transform rings at no edge (a plain mirror still
    jumps where the frame wraps around). A pad of 0 leaves that axis as it is (an image 1 pixel
    high or wide)."""
    after_y = pad_y if after_y is None else after_y
    after_x = pad_x if after_x is None else after_x
    if pad_y < 1 and pad_x < 1:
        return image
    h, w = image.shape[-2:]
    padded = F.pad(image, (pad_x, after_x, pad_y, after_y), mode="reflect")
    mean = image.mean((-2, -1), keepdim=True)

    def fade(n: int, before: int, after: int) -> Tensor:
        def ramp(pad: int) -> Tensor:
            return 0.5 - 0.5 * torch.cos(math.pi * torch.arange(
                1, pad + 1, dtype=image.dtype, device=image.device) / (pad + 1))
        return torch.cat([ramp(before), torch.ones(n, dtype=image.dtype, device=image.device),
                          ramp(after).flip(0)])

    taper = fade(h, pad_y, after_y)[:, None] * fade(w, pad_x, after_x)[None, :]
    return mean + (padded - mean) * taper


def _smoothed_grey(image: Tensor, sigma: float) -> Tensor:
    k = 2 * math.ceil(3 * sigma) + 1
    grey = kornia.filters.gaussian_blur2d(image.mean(1, keepdim=True), (k, k), (sigma, sigma),
                                          border_type="reflect")
    return grey / grey.mean((-2, -1), keepdim=True).clamp_min(1e-8)


def warp(image: Tensor, shift: Tensor, zoom: Tensor | None = None,
         angle: Tensor | None = None) -> Tensor:
    """`image` `(B,C,H,W)` magnified by `zoom` `(B,)` and turned by `angle` `(B,)` radians
    about its centre `c`, then moved by `shift` `(B,2)` pixels `(dy, dx)`:
    `out(p) = image(c + R(-angle) (p - c - shift) / zoom)`, with `R(a)` the rotation taking the
    x axis (right) toward the y axis (down), i.e. clockwise on screen for a positive angle.

    Without a zoom or an angle (a zoom within 1e-4 of 1, an angle within 1e-6 rad) this is
    `translate` (no interpolation blur); otherwise bicubic resampling, which blurs fine detail
    slightly. Computed in at least float32 (a `float16`/`bfloat16` image is returned in its
    dtype).

    Raises:
        TypeError: for an image that is not floating-point, or a shift, zoom or angle that is not
            a real tensor.
        ValueError: on wrong shapes, a NaN or infinite value in `image`, `shift`, `zoom` or
            `angle`, or a zoom <= 0.

    Example:
        >>> image = torch.rand(1, 1, 8, 8)
        >>> torch.equal(warp(image, torch.zeros(1, 2)), translate(image, torch.zeros(1, 2)))
        True
        >>> quarter = warp(image, torch.zeros(1, 2), angle=torch.tensor([torch.pi / 2]))
        >>> torch.allclose(quarter, image.rot90(-1, (-2, -1)), atol=1e-5)
        True
    """
    _check_image("image", image)
    b = image.shape[0]
    _check_values("shift", shift, f"(B, 2) = ({b}, 2) pixels (dy, dx)", (b, 2))
    if zoom is not None:
        _check_values("zoom", zoom, f"(B,) = ({b},) magnifications", (b,))
        check_tensor("zoom", zoom, values="positive")
    if angle is not None:
        _check_values("angle", angle, f"(B,) = ({b},) radians", (b,))
    return _warp(image, shift, zoom, angle)


def _warp(image: Tensor, shift: Tensor, zoom: Tensor | None, angle: Tensor | None) -> Tensor:
    b, c, h, w = image.shape
    zoom = torch.ones(b, device=image.device) if zoom is None else zoom
    angle = torch.zeros(b, device=image.device) if angle is None else angle
    if image.numel() == 0 or (bool(((zoom - 1).abs() < 1e-4).all())
                              and bool((angle.abs() < 1e-6).all())):
        return _translate(image, shift)
    work = _working(image)
    zoom, angle, shift = zoom.to(work), angle.to(work), shift.to(work)
    # sample at q = c + R(-angle) (p - c - shift) / zoom, written in align_corners=False
    # coordinates about the centre (x_n = 2 (x - c_x) / w, y_n = 2 (y - c_y) / h)
    cos, sin = torch.cos(angle) / zoom, torch.sin(angle) / zoom
    theta = torch.stack([
        torch.stack([cos, sin * h / w, -2 * (cos * shift[:, 1] + sin * shift[:, 0]) / w], -1),
        torch.stack([-sin * w / h, cos, -2 * (cos * shift[:, 0] - sin * shift[:, 1]) / h], -1),
    ], 1)
    grid = F.affine_grid(theta, [b, c, h, w], align_corners=False)
    out = F.grid_sample(work, grid, mode="bicubic", padding_mode="border", align_corners=False)
    return out.to(image.dtype)


def _lucas_kanade(reference: Tensor, moving: Tensor, motion: Tensor, iterations: int,
                  margin: int) -> Tensor:
    # reference, moving (1,1,H,W) smoothed grey; motion (dy, dx) or (dy, dx, zoom, angle) with
    # moving ~ warp(reference, (dy, dx), zoom, angle). A Hann taper over the inner window: the
    # blur's terms cancel over the window only if they fade out at its edges.
    inner = (..., slice(margin, -margin), slice(margin, -margin))
    target = reference[inner][0, 0].double()
    h, w = target.shape
    taper = torch.outer(torch.hann_window(h + 2, periodic=False, dtype=torch.float64)[1:-1],
                        torch.hann_window(w + 2, periodic=False, dtype=torch.float64)[1:-1])
    taper = taper.to(target.device)
    zoomed = len(motion) == 4
    full_h, full_w = reference.shape[-2:]
    y = torch.arange(full_h, dtype=torch.float64, device=target.device)[:, None] - (full_h - 1) / 2
    x = torch.arange(full_w, dtype=torch.float64, device=target.device)[None, :] - (full_w - 1) / 2
    radial_y, radial_x = (t.expand(full_h, full_w)[inner[1:]] for t in (y, x))
    for _ in range(iterations):
        # back(p) = moving(c + zoom R(angle) (p - c) + shift) ~ reference(p)
        back = _undo_motion(moving, motion)
        grad = kornia.filters.spatial_gradient(back, normalized=True)[0, 0]  # (2: dx, dy, H, W)
        gx, gy = grad[0][inner[1:]].double(), grad[1][inner[1:]].double()
        level = back[inner][0, 0].double()
        # r - back ~ gy dy + gx dx (+ radial dzoom + tangential dangle) + gain * back + offset:
        # exposure differences fitted alongside
        terms = [gy, gx] + ([gy * radial_y + gx * radial_x, gy * radial_x - gx * radial_y]
                            if zoomed else [])
        columns = torch.stack([*terms, level, torch.ones_like(level)]).flatten(1)
        normal = (columns * taper.flatten()) @ columns.T
        if float(torch.linalg.eigvalsh(normal[:2, :2])[0]) <= 1e-8 * float(taper.sum()):
            break  # under 1e-4 of the mean intensity per pixel along some direction: no texture
        rhs = (columns * taper.flatten()) @ (target - level).flatten()
        step = torch.linalg.lstsq(normal, rhs[:, None]).solution[:len(terms), 0]
        motion = motion + step.to(motion)
        if float(step[:2].abs().max()) < 1e-3 and (not zoomed or float(step[2:].abs().max())
                                                    < 1e-6):
            break
    return motion


def undo_motion(moving: Tensor, motion: Tensor) -> Tensor:
    """`moving(c + zoom R(angle) (p - c) + shift)` for `motion` `(dy, dx)` or
    `(dy, dx, zoom, angle)` (pixels, radians; as `estimate_motion` and `align_shots` give it):
    `moving` `(1,C,H,W)` brought back onto the reference.

    Raises:
        TypeError: for an image that is not floating-point, or a motion that is not a real tensor.
        ValueError: on wrong shapes, a NaN or infinite value in `moving` or `motion`, or a
            zoom <= 0.

    Example:
        >>> image = torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0))
        >>> moved = translate(image, torch.tensor([[1.0, 0.0]]))
        >>> back = undo_motion(moved, torch.tensor([1.0, 0.0]))
        >>> torch.allclose(back[..., 2:-2, :], image[..., 2:-2, :], atol=1e-6)
        True
    """
    _check_image("moving", moving, ("1", "C", "H", "W"))
    _check_values("motion", motion, "(2,) pixels (dy, dx) or (4,) (dy, dx, zoom, angle)",
                  (2,), (4,))
    if len(motion) == 4:
        check_tensor("motion[2] (the zoom)", motion[2:3], values="positive")
    return _undo_motion(moving, motion)


def _undo_motion(moving: Tensor, motion: Tensor) -> Tensor:
    if len(motion) == 2:
        return _translate(moving, -motion[None])
    zoom, angle = motion[2:3], motion[3:4]
    # warp(s', 1 / zoom, -angle) samples moving at c + zoom R(angle) (p - c - s'), which is
    # c + zoom R(angle) (p - c) + shift for s' = -R(-angle) shift / zoom
    cos, sin = torch.cos(angle), torch.sin(angle)
    dy, dx = motion[0:1], motion[1:2]
    shift = -torch.stack([cos * dy - sin * dx, cos * dx + sin * dy], -1) / zoom
    return _warp(moving, shift, 1 / zoom, -angle)


def _smallest_size(sigma_px: float) -> int:
    # the smoothing mirrors ceil(3 sigma) pixels at each border, and Lucas-Kanade needs a
    # margin of at least a pixel, a third of the size at most
    return max(4, math.ceil(3 * sigma_px) + 1)


def _check_pair(names: tuple[str, str], reference: Tensor, moving: Tensor, sigma_px: float,
                moving_dims: Sequence[str] = ("B", "C", "H", "W")) -> None:
    """Refuse images whose motion cannot be estimated: `reference` `(B,C,H,W)` and `moving`
    (`moving_dims`) checked, of one batch size and one image size, with a channel and at least
    `_smallest_size(sigma_px)` pixels each way."""
    _check_image(names[0], reference)
    _check_image(names[1], moving, moving_dims)
    if reference.shape[0] != moving.shape[0] or reference.shape[-2:] != moving.shape[-2:]:
        raise ValueError(f"{names[0]} {tuple(reference.shape)} and {names[1]} "
                         f"{tuple(moving.shape)} must have one batch size and one image size")
    smallest = _smallest_size(sigma_px)
    if min(reference.shape[-2:]) < smallest or 0 in (reference.shape[1], moving.shape[-3]):
        raise ValueError(f"{names[0]} {tuple(reference.shape)} and {names[1]} "
                         f"{tuple(moving.shape)} are too small to estimate a motion from: they "
                         f"need a channel and at least {smallest}x{smallest} pixels (for "
                         f"sigma_px={sigma_px:g})")


def _checked_estimate(reference: Tensor, moving: Tensor, iterations: int, sigma_px: float,
                      zoomed: bool) -> Tensor:
    """`_estimate` after checking its arguments (`estimate_shift`, `estimate_motion`)."""
    if isinstance(iterations, bool) or not isinstance(iterations, numbers.Integral) \
            or not is_real_number(sigma_px):
        raise TypeError(f"iterations must be an int >= 1 and sigma_px a number > 0 (pixels), "
                        f"got {iterations!r} and {sigma_px!r}")
    if iterations < 1 or not (math.isfinite(sigma_px) and sigma_px > 0):
        raise ValueError(f"need iterations >= 1 and a finite sigma_px > 0, got {iterations!r}, "
                         f"{sigma_px!r}")
    _check_pair(("reference", "moving"), reference, moving, sigma_px)
    for name, image in (("reference", reference), ("moving", moving)) if zoomed else ():
        if image.dtype in (torch.float16, torch.bfloat16):
            raise TypeError(
                f"{name} has dtype {image.dtype}; estimate_motion needs float32 or float64 "
                f"images: the zoom it returns (within about 2 % of 1) would be rounded to "
                f"{torch.finfo(image.dtype).eps:g} in {image.dtype}; pass {name}.float()")
    return _estimate(reference, moving, iterations, sigma_px, zoomed)


def _estimate(reference: Tensor, moving: Tensor, iterations: int, sigma_px: float,
              zoomed: bool) -> Tensor:
    """Lucas-Kanade over a pyramid, `(B,2)` shifts or `(B,4)` motions; the images unchecked."""
    dtype = torch.promote_types(reference.dtype, moving.dtype)
    work = torch.promote_types(dtype, torch.float32)
    smallest = _smallest_size(sigma_px)
    motions = [reference.new_zeros((0, 4 if zoomed else 2), dtype=dtype)]  # B may be 0
    with torch.no_grad():
        for ref, mov in zip(reference.to(work), moving.to(work), strict=True):
            levels = max(0, min(4, int(math.log2(max(1, min(ref.shape[-2:]) // 16)))))
            motion = torch.tensor([0.0, 0.0, 1.0, 0.0] if zoomed else [0.0, 0.0],
                                  dtype=work, device=ref.device)
            for level in range(levels, -1, -1):
                factor = 2**level
                r = F.avg_pool2d(ref[None], factor) if factor > 1 else ref[None]
                m = F.avg_pool2d(mov[None], factor) if factor > 1 else mov[None]
                if min(r.shape[-2:]) < smallest:
                    continue  # a level too coarse for the smoothing
                margin = min(math.ceil(3 * sigma_px) + 4, (min(r.shape[-2:]) - 1) // 3)
                per_level = motion.clone()
                per_level[:2] /= factor
                per_level = _lucas_kanade(_smoothed_grey(r, sigma_px), _smoothed_grey(m, sigma_px),
                                          per_level, iterations, margin)
                motion = per_level.clone()
                motion[:2] *= factor
            motions.append(motion[None].to(dtype))
    return torch.cat(motions)


def estimate_shift(reference: Tensor, moving: Tensor, iterations: int = _SHIFT_ITERATIONS,
                   sigma_px: float = _SIGMA_PX) -> Tensor:
    """The translation `(B,2)` pixels `(dy, dx)` of `moving` relative to `reference`, both
    `(B,C,H,W)`: `moving(p) ~ reference(p - shift)` up to a symmetric blur, exposure and noise.

    Lucas-Kanade on Gaussian-smoothed grey images (`sigma_px`), coarse to fine over a small
    pyramid (shifts of several pixels converge), each level iterated until the update is under a
    thousandth of a pixel. A textureless pair gives a zero shift. Computed in at least float32
    and returned in the images' dtype (`float16`/`bfloat16` round the shift).

    Raises:
        TypeError: for images that are not floating-point, or settings of the wrong type.
        ValueError: on wrong or mismatched shapes, a NaN or infinite pixel, images smaller than
            `max(4, ceil(3 sigma_px) + 1)` pixels either way (6 by default), or
            `iterations < 1` or `sigma_px <= 0`.

    Example:
        >>> image = torch.rand(1, 3, 64, 64)
        >>> moved = translate(image, torch.tensor([[0.4, -0.7]]))
        >>> estimate_shift(image, moved).round(decimals=2)
        tensor([[ 0.4000, -0.7000]])
    """
    return _checked_estimate(reference, moving, iterations, sigma_px, zoomed=False)


def estimate_motion(reference: Tensor, moving: Tensor, iterations: int = _MOTION_ITERATIONS,
                    sigma_px: float = _SIGMA_PX) -> Tensor:
    """The translation, magnification and rotation `(B,4)` `(dy, dx, zoom, angle)` (pixels,
    ratio, radians) of `moving` relative to `reference`:
    `moving ~ warp(reference, (dy, dx), zoom, angle)` up to a symmetric blur, exposure and noise.
    A lens whose image scale changes with focus ("focus breathing") magnifies each focused photo
    a little (about 0.1-2 %), and a hand-held camera turns a little between shots;
    `estimate_shift` ignores both.

    Raises:
        TypeError: as `estimate_shift`, and for `float16`/`bfloat16` images (the zoom needs
            more precision than they hold near 1; pass `.float()` images).
        ValueError: as `estimate_shift`.

    Example:
        >>> image = kornia.filters.gaussian_blur2d(torch.rand(1, 1, 96, 96), (9, 9), (2.0, 2.0))
        >>> moved = warp(image, torch.tensor([[0.5, -0.3]]), torch.tensor([1.01]),
        ...              torch.tensor([0.01]))
        >>> estimate_motion(image, moved).round(decimals=2)
        tensor([[ 0.5000, -0.3000,  1.0100,  0.0100]])
    """
    return _checked_estimate(reference, moving, iterations, sigma_px, zoomed=True)


#: The largest motion between the photos of one view that `align_shots` undoes: a zoom
#: within this share of 1 (focus breathing is 0.1-2 %), a rotation within this many radians
#: and a shift within this share of the image's smaller side. Beyond them the estimate has
#: failed (photos of different views, or without texture in common).
MAX_ALIGN_ZOOM, MAX_ALIGN_ANGLE, MAX_ALIGN_SHIFT = 0.1, 0.1, 0.25


def _plausible(motion: Tensor, size: Sequence[int]) -> Tensor:
    """`(B,)`: which `(dy, dx, zoom, angle)` motions lie within the `MAX_ALIGN_*` bounds."""
    return (torch.isfinite(motion).all(1) & ((motion[:, 2] - 1).abs() <= MAX_ALIGN_ZOOM)
            & (motion[:, 3].abs() <= MAX_ALIGN_ANGLE)
            & (motion[:, :2].abs().amax(1) <= MAX_ALIGN_SHIFT * min(size)))


#: Largest displacement (pixels, at the image corners) a zoom and a rotation together may
#: cause and still be ignored: under it they are noise, and undoing them would resample (blur)
#: the photo.
ZOOM_TOLERANCE_PX = 0.25


def align_shots(image: Tensor, focused: Tensor) -> tuple[Tensor, Tensor]:
    """Focused photos `(B,F,C,H,W)` moved (and, where the lens breathes or the camera turned,
    scaled and rotated) onto the all-in-focus `image` `(B,C,H,W)`.

    Each photo's `estimate_motion` is undone by `warp`. A zoom and rotation that move the
    corners by less than `ZOOM_TOLERANCE_PX` are taken for noise: the photo is then only moved,
    by its `estimate_shift`, with `translate` (no resampling blur). Computed in at least
    float32; `float16`/`bfloat16` photos come back in their dtype, and so do the motions
    (rounded: the zoom to about 1e-3 in float16, 8e-3 in bfloat16).

    Returns:
        `(aligned (B,F,C,H,W), motions (B,F,4))`, the `(dy, dx, zoom, angle)` of each focused
        photo relative to `image` (zoom 1 and angle 0 where they were ignored).

    Raises:
        TypeError: for images that are not floating-point.
        ValueError: on wrong or mismatched shapes, no focused photo (`F = 0`), a NaN or infinite
            pixel, or images smaller than 6x6 pixels.

    Example:
        >>> image = kornia.filters.gaussian_blur2d(torch.rand(1, 3, 48, 48), (7, 7), (1.0, 1.0))
        >>> focused = translate(image, torch.tensor([[1.0, 0.5]]))[:, None]
        >>> aligned, motions = align_shots(image, focused)
        >>> torch.allclose(aligned[0, :, :, 8:-8, 8:-8], image[:, :, 8:-8, 8:-8], atol=1e-2)
        True
    """
    _check_pair(("image", "focused"), image, focused, _SIGMA_PX, ("B", "F", "C", "H", "W"))
    b, n = focused.shape[:2]
    if n == 0:
        raise ValueError(f"focused must hold at least one photo (F >= 1 in (B, F, C, H, W)), "
                         f"got shape {tuple(focused.shape)}")
    dtype = torch.promote_types(image.dtype, focused.dtype)
    if b == 0:
        return focused.clone(), focused.new_zeros((0, n, 4), dtype=dtype)
    work = torch.promote_types(dtype, torch.float32)
    reference = image.to(work)
    half_diagonal = math.hypot(*focused.shape[-2:]) / 2
    aligned, motions = [], []
    for i in range(n):
        shots = focused[:, i].to(work)
        # the images were checked once above: not again for every shot
        motion = _estimate(reference, shots, _MOTION_ITERATIONS, _SIGMA_PX, zoomed=True)
        corner = ((motion[:, 2] - 1).abs() + motion[:, 3].abs()) * half_diagonal
        small = (corner < ZOOM_TOLERANCE_PX) | ~_plausible(motion, focused.shape[-2:])
        if bool(small.any()):  # nothing to undo but the translation, estimated as such
            motion[small, :2] = _estimate(reference[small], shots[small], _SHIFT_ITERATIONS,
                                          _SIGMA_PX, zoomed=False)
            motion[small, 2:] = torch.tensor([1.0, 0.0], dtype=motion.dtype,
                                             device=motion.device)
        lost = ~_plausible(motion, focused.shape[-2:])
        if bool(lost.any()):
            warnings.warn(f"focused photo {i} could not be aligned to the reference (estimated "
                          f"shift {motion[lost][0, :2].tolist()} pixels): it is used as it is; "
                          "do the photos show one view?", stacklevel=2)
            motion[lost] = torch.tensor([0.0, 0.0, 1.0, 0.0], dtype=motion.dtype,
                                        device=motion.device)
        aligned.append(torch.cat([_undo_motion(shots[j:j + 1], motion[j]) for j in range(b)]))
        motions.append(motion)
    return torch.stack(aligned, 1).to(focused.dtype), torch.stack(motions, 1).to(dtype)
