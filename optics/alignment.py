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

import kornia
import torch
import torch.nn.functional as F
from torch import Tensor

from .checks import check_shape


def translate(image: Tensor, shift: Tensor) -> Tensor:
    """`image` `(B,C,H,W)` moved by `shift` `(B,2)` pixels `(dy, dx)`: `out(p) = image(p - shift)`.

    Exact for band-limited content: the shift is a phase ramp in the Fourier domain (no
    interpolation blur). The image is mirrored at its borders first, so content entering the
    frame is a reflection rather than the opposite border. Differentiable in `image` and `shift`.

    Example:
        >>> image = torch.rand(1, 3, 16, 16)
        >>> moved = translate(image, torch.tensor([[1.0, -2.0]]))
        >>> torch.allclose(moved[..., 4:12, 4:12], image[..., 3:11, 6:14], atol=1e-4)
        True
    """
    check_shape("image", image, ["B", "C", "H", "W"])
    b, _, h, w = image.shape
    if shift.shape != (b, 2):
        raise ValueError(f"shift must be (B, 2) = ({b}, 2) pixels (dy, dx), got "
                         f"{tuple(shift.shape)}")
    if not bool(torch.isfinite(shift).all()):
        raise ValueError(f"shift must be finite pixels, got {shift.detach().tolist()}")
    shift = shift.to(image)
    reach = int(math.ceil(float(shift.detach().abs().max()))) if shift.numel() else 0
    pad_y, pad_x = min(h - 1, reach + 16), min(w - 1, reach + 16)
    padded = _periodic_padding(image, pad_y, pad_x)
    hp, wp = padded.shape[-2:]
    fy = torch.fft.fftfreq(hp, device=image.device, dtype=image.dtype)[:, None]
    fx = torch.fft.rfftfreq(wp, device=image.device, dtype=image.dtype)[None, :]
    angle = -2 * math.pi * (fy * shift[:, 0, None, None] + fx * shift[:, 1, None, None])
    ramp = torch.polar(torch.ones_like(angle), angle)[:, None]
    out = torch.fft.irfft2(torch.fft.rfft2(padded) * ramp, s=(hp, wp))
    return out[..., pad_y:pad_y + h, pad_x:pad_x + w]


def _periodic_padding(image: Tensor, pad_y: int, pad_x: int) -> Tensor:
    """`image` mirrored by `pad_y`, `pad_x` pixels and faded to its mean over the mirrored part
    (a raised cosine): the padded frame repeats smoothly, so its Fourier transform rings at no
    edge (a plain mirror still jumps where the frame wraps around)."""
    if pad_y < 1 or pad_x < 1:
        return image
    padded = F.pad(image, (pad_x, pad_x, pad_y, pad_y), mode="reflect")
    mean = image.mean((-2, -1), keepdim=True)

    def fade(n: int, pad: int) -> Tensor:
        ramp = 0.5 - 0.5 * torch.cos(math.pi * torch.arange(1, pad + 1, dtype=image.dtype,
                                                             device=image.device) / (pad + 1))
        return torch.cat([ramp, torch.ones(n, dtype=image.dtype, device=image.device),
                          ramp.flip(0)])

    h, w = image.shape[-2:]
    taper = fade(h, pad_y)[:, None] * fade(w, pad_x)[None, :]
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
    slightly.

    Example:
        >>> image = torch.rand(1, 1, 8, 8)
        >>> torch.equal(warp(image, torch.zeros(1, 2)), translate(image, torch.zeros(1, 2)))
        True
        >>> quarter = warp(image, torch.zeros(1, 2), angle=torch.tensor([torch.pi / 2]))
        >>> torch.allclose(quarter, image.rot90(-1, (-2, -1)), atol=1e-5)
        True
    """
    b = image.shape[0]
    zoom = torch.ones(b, device=image.device) if zoom is None else zoom
    angle = torch.zeros(b, device=image.device) if angle is None else angle
    if bool(((zoom - 1).abs() < 1e-4).all()) and bool((angle.abs() < 1e-6).all()):
        return translate(image, shift)
    check_shape("image", image, ["B", "C", "H", "W"])
    _, c, h, w = image.shape
    zoom, angle, shift = zoom.to(image).reshape(b), angle.to(image).reshape(b), shift.to(image)
    # sample at q = c + R(-angle) (p - c - shift) / zoom, written in align_corners=False
    # coordinates about the centre (x_n = 2 (x - c_x) / w, y_n = 2 (y - c_y) / h)
    cos, sin = torch.cos(angle) / zoom, torch.sin(angle) / zoom
    theta = torch.stack([
        torch.stack([cos, sin * h / w, -2 * (cos * shift[:, 1] + sin * shift[:, 0]) / w], -1),
        torch.stack([-sin * w / h, cos, -2 * (cos * shift[:, 0] - sin * shift[:, 1]) / h], -1),
    ], 1)
    grid = F.affine_grid(theta, [b, c, h, w], align_corners=False)
    return F.grid_sample(image, grid, mode="bicubic", padding_mode="border", align_corners=False)


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
        back = undo_motion(moving, motion)
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

    Example:
        >>> image = torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0))
        >>> moved = translate(image, torch.tensor([[1.0, 0.0]]))
        >>> back = undo_motion(moved, torch.tensor([1.0, 0.0]))
        >>> torch.allclose(back[..., 2:-2, :], image[..., 2:-2, :], atol=1e-6)
        True
    """
    if len(motion) == 2:
        return translate(moving, -motion[None])
    zoom, angle = motion[2:3], motion[3:4]
    # warp(s', 1 / zoom, -angle) samples moving at c + zoom R(angle) (p - c - s'), which is
    # c + zoom R(angle) (p - c) + shift for s' = -R(-angle) shift / zoom
    cos, sin = torch.cos(angle), torch.sin(angle)
    dy, dx = motion[0:1], motion[1:2]
    shift = -torch.stack([cos * dy - sin * dx, cos * dx + sin * dy], -1) / zoom
    return warp(moving, shift, 1 / zoom, -angle)


def _estimate(reference: Tensor, moving: Tensor, iterations: int, sigma_px: float,
              zoomed: bool) -> Tensor:
    check_shape("reference", reference, ["B", "C", "H", "W"])
    check_shape("moving", moving, ["B", "C", "H", "W"])
    if reference.shape[0] != moving.shape[0] or reference.shape[-2:] != moving.shape[-2:]:
        raise ValueError(f"reference {tuple(reference.shape)} and moving {tuple(moving.shape)} "
                         "must have one batch size and one image size")
    if iterations < 1 or not sigma_px > 0:
        raise ValueError(f"need iterations >= 1 and sigma_px > 0, got {iterations!r}, "
                         f"{sigma_px!r}")
    motions = []
    with torch.no_grad():
        for ref, mov in zip(reference, moving, strict=True):
            levels = max(0, min(4, int(math.log2(max(1, min(ref.shape[-2:]) // 16)))))
            motion = torch.tensor([0.0, 0.0, 1.0, 0.0] if zoomed else [0.0, 0.0],
                                  dtype=ref.dtype, device=ref.device)
            for level in range(levels, -1, -1):
                factor = 2**level
                r = F.avg_pool2d(ref[None], factor) if factor > 1 else ref[None]
                m = F.avg_pool2d(mov[None], factor) if factor > 1 else mov[None]
                margin = min(math.ceil(3 * sigma_px) + 4, (min(r.shape[-2:]) - 1) // 3)
                if margin < 1:
                    continue
                per_level = motion.clone()
                per_level[:2] /= factor
                per_level = _lucas_kanade(_smoothed_grey(r, sigma_px), _smoothed_grey(m, sigma_px),
                                          per_level, iterations, margin)
                motion = per_level.clone()
                motion[:2] *= factor
            motions.append(motion)
    return torch.stack(motions)


def estimate_shift(reference: Tensor, moving: Tensor, iterations: int = 10,
                   sigma_px: float = 1.5) -> Tensor:
    """The translation `(B,2)` pixels `(dy, dx)` of `moving` relative to `reference`, both
    `(B,C,H,W)`: `moving(p) ~ reference(p - shift)` up to a symmetric blur, exposure and noise.

    Lucas-Kanade on Gaussian-smoothed grey images (`sigma_px`), coarse to fine over a small
    pyramid (shifts of several pixels converge), each level iterated until the update is under a
    thousandth of a pixel. A textureless pair gives a zero shift.

    Example:
        >>> image = torch.rand(1, 3, 64, 64)
        >>> moved = translate(image, torch.tensor([[0.4, -0.7]]))
        >>> estimate_shift(image, moved).round(decimals=2)
        tensor([[ 0.4000, -0.7000]])
    """
    return _estimate(reference, moving, iterations, sigma_px, zoomed=False)


def estimate_motion(reference: Tensor, moving: Tensor, iterations: int = 20,
                    sigma_px: float = 1.5) -> Tensor:
    """The translation, magnification and rotation `(B,4)` `(dy, dx, zoom, angle)` (pixels,
    ratio, radians) of `moving` relative to `reference`:
    `moving ~ warp(reference, (dy, dx), zoom, angle)` up to a symmetric blur, exposure and noise.
    A lens whose image scale changes with focus ("focus breathing") magnifies each focused photo
    a little (about 0.1-2 %), and a hand-held camera turns a little between shots;
    `estimate_shift` ignores both.

    Example:
        >>> image = kornia.filters.gaussian_blur2d(torch.rand(1, 1, 96, 96), (9, 9), (2.0, 2.0))
        >>> moved = warp(image, torch.tensor([[0.5, -0.3]]), torch.tensor([1.01]),
        ...              torch.tensor([0.01]))
        >>> estimate_motion(image, moved).round(decimals=2)
        tensor([[ 0.5000, -0.3000,  1.0100,  0.0100]])
    """
    return _estimate(reference, moving, iterations, sigma_px, zoomed=True)


#: Largest displacement (pixels, at the image corners) a zoom and a rotation together may
#: cause and still be ignored: under it they are noise, and undoing them would resample (blur)
#: the photo.
ZOOM_TOLERANCE_PX = 0.25


def align_shots(image: Tensor, focused: Tensor) -> tuple[Tensor, Tensor]:
    """Focused photos `(B,F,C,H,W)` moved (and, where the lens breathes or the camera turned,
    scaled and rotated) onto the all-in-focus `image` `(B,C,H,W)`.

    Each photo's `estimate_motion` is undone by `warp`. A zoom and rotation that move the
    corners by less than `ZOOM_TOLERANCE_PX` are taken for noise: the photo is then only moved,
    by its `estimate_shift`, with `translate` (no resampling blur).

    Returns:
        `(aligned (B,F,C,H,W), motions (B,F,4))`, the `(dy, dx, zoom, angle)` of each focused
        photo relative to `image` (zoom 1 and angle 0 where they were ignored).

    Example:
        >>> image = kornia.filters.gaussian_blur2d(torch.rand(1, 3, 48, 48), (7, 7), (1.0, 1.0))
        >>> focused = translate(image, torch.tensor([[1.0, 0.5]]))[:, None]
        >>> aligned, motions = align_shots(image, focused)
        >>> torch.allclose(aligned[0, 0, :, 8:-8, 8:-8], image[0, :, 8:-8, 8:-8], atol=1e-2)
        True
    """
    check_shape("focused", focused, ["B", "F", "C", "H", "W"])
    b, n = focused.shape[:2]
    half_diagonal = math.hypot(*focused.shape[-2:]) / 2
    aligned, motions = [], []
    for i in range(n):
        motion = estimate_motion(image, focused[:, i])
        corner = ((motion[:, 2] - 1).abs() + motion[:, 3].abs()) * half_diagonal
        small = corner < ZOOM_TOLERANCE_PX
        if bool(small.any()):  # nothing to undo but the translation, estimated as such
            motion[small, :2] = estimate_shift(image[small], focused[small, i])
            motion[small, 2:] = torch.tensor([1.0, 0.0], dtype=motion.dtype,
                                             device=motion.device)
        aligned.append(torch.cat([undo_motion(focused[j:j + 1, i], motion[j])
                                  for j in range(b)]))
        motions.append(motion)
    return torch.stack(aligned, 1), torch.stack(motions, 1)
