"""Depth from defocus for any camera: read blur in pixels, leave the metres to the thin lens.

For a thin lens the signed CoC diameter in pixels is linear in inverse depth,
`c_i(D) = A_i (1 - D_f,i / D)`, with `A_i` the CoC of a point at infinity (see
`CameraSettings.coc_at_infinity_px`). What the photos show is blur in pixels; the camera only maps
blur to metres. So the model has two parts:

1. `BlurNet` reads, for one focused photo and the all-in-focus photo, the CoC diameter `|c|` in
   pixels at every pixel. It never sees a camera, so it does not depend on one. It is trained
   without depth labels: the all-in-focus photo rendered with the predicted blur must reproduce
   the focused photo (the paper's self-supervision through the renderer, in blur space).
2. `solve_depth` finds, per pixel, the depth in `[near, far]` whose thin-lens blurs best explain
   the `F` measured blurs (two or more shots resolve the sign ambiguity around each focus plane),
   aggregating the costs over windows weighted by how much texture there is: where a photo holds
   no texture (or is saturated) defocus says nothing; the confidence says so and larger windows
   fill in.

`DepthFromDefocus` puts them together, with tiling for large photos.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import kornia
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from optics import CameraSettings, Gaussian, align_shots, render_defocus
from optics.checks import check_finite, check_shape

from .losses import edge_aware_smoothness, photometric_loss
from .tiling import apply_in_tiles

#: Blur (pixels) a fresh `BlurNet` answers everywhere: inside the range it reads, where the
#: self-supervised loss is steep (softplus of ~0 would start at 0.7 px, where it is nearly flat).
INITIAL_BLUR_PX = 4.0

#: Scales (pixels) of the band-pass energies in `blur_features`.
FEATURE_SCALES = (0.0, 1.0, 2.0, 4.0)


def match_exposure(image: Tensor, focused: Tensor) -> Tensor:
    """`focused` `(B,3,H,W)` scaled per channel to the mean of `image` (exposure and white
    balance differences between shots removed)."""
    gain = image.mean((-2, -1), keepdim=True) / focused.mean((-2, -1), keepdim=True).clamp_min(1e-6)
    return focused * gain


def _band_energy(gray: Tensor, scale: float, window: int = 7) -> Tensor:
    if scale > 0:
        k = 2 * math.ceil(3 * scale) + 1
        gray = kornia.filters.gaussian_blur2d(gray, (k, k), (scale, scale), border_type="reflect")
    energy = kornia.filters.laplacian(gray, 3, border_type="reflect") ** 2
    return kornia.filters.box_blur(energy, (window, window), border_type="reflect")


def blur_features(image: Tensor, focused: Tensor) -> Tensor:
    """The `BlurNet` input for one shot: `(B, 3 + 2 * len(FEATURE_SCALES), H, W)`.

    Channels: the all-in-focus and the (exposure-matched) focused grey images, their difference,
    and per scale of `FEATURE_SCALES` the log ratio of the focused photo's band-pass energy to the
    all-in-focus photo's (about `-k sigma^2` for a blur of `sigma` pixels) and the all-in-focus
    log energy (how much there is to read).
    """
    a = image.mean(1, keepdim=True)
    b = match_exposure(image, focused).mean(1, keepdim=True)
    channels = [a, b, b - a]
    for scale in FEATURE_SCALES:
        ea, eb = _band_energy(a, scale), _band_energy(b, scale)
        eps = 1e-7 + 1e-3 * ea.mean((-2, -1), keepdim=True)
        channels += [torch.log(eb + eps) - torch.log(ea + eps), torch.log(ea + eps) / 10]
    return torch.cat(channels, 1)


def _block(cin: int, cout: int, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride, dilation, dilation), nn.LeakyReLU(0.1, inplace=True),
        nn.Conv2d(cout, cout, 3, 1, 1), nn.LeakyReLU(0.1, inplace=True),
    )


class BlurNet(nn.Module):
    """Per-pixel CoC diameter (pixels) of a focused photo, from it and the all-in-focus photo.

    A four-scale encoder-decoder without normalisation layers (so tiles of a large photo give the
    same result as the whole), receptive field about 90 pixels: blurs up to about 16 pixels.

    Args:
        width: channels of the first scale.

    Example:
        >>> net = BlurNet(width=8)
        >>> image = torch.rand(1, 3, 32, 32)
        >>> net(image, image).shape
        torch.Size([1, 1, 32, 32])
    """

    def __init__(self, width: int = 24):
        super().__init__()
        w = int(width)
        if w < 1:
            raise ValueError(f"width must be >= 1, got {width!r}")
        self.width = w
        cin = 3 + 2 * len(FEATURE_SCALES)
        self.enc1 = _block(cin, w)
        self.enc2 = _block(w, 2 * w, stride=2)
        self.enc3 = _block(2 * w, 2 * w, stride=2)
        self.enc4 = _block(2 * w, 4 * w, stride=2, dilation=2)
        self.dec3 = _block(4 * w + 2 * w, 2 * w)
        self.dec2 = _block(2 * w + 2 * w, 2 * w)
        self.dec1 = _block(2 * w + w, w)
        self.out = nn.Conv2d(w, 1, 3, padding=1)
        with torch.no_grad():  # start at INITIAL_BLUR_PX everywhere
            self.out.weight.mul_(0.1)
            self.out.bias.fill_(math.log(math.expm1(INITIAL_BLUR_PX)))

    def forward(self, image: Tensor, focused: Tensor) -> Tensor:
        """CoC diameter `(B,1,H,W)` in pixels (>= 0) of `focused` `(B,3,H,W)` relative to the
        all-in-focus `image` `(B,3,H,W)`, both linear intensity."""
        check_shape("image", image, ["B", "3", "H", "W"])
        check_shape("focused", focused, ["B", "3", "H", "W"])
        x = blur_features(image, focused)
        h, w = x.shape[-2:]
        x = F.pad(x, (0, (-w) % 8, 0, (-h) % 8), mode="replicate")
        e1 = self.enc1(x)
        e2 = self.enc2(e1)
        e3 = self.enc3(e2)
        e4 = self.enc4(e3)
        d3 = self.dec3(torch.cat([_up(e4, e3), e3], 1))
        d2 = self.dec2(torch.cat([_up(d3, e2), e2], 1))
        d1 = self.dec1(torch.cat([_up(d2, e1), e1], 1))
        return F.softplus(self.out(d1)[..., :h, :w])


def _up(x: Tensor, like: Tensor) -> Tensor:
    return F.interpolate(x, size=like.shape[-2:], mode="bilinear", align_corners=False)


def texture_weight(image: Tensor, window: int = 7) -> Tensor:
    """How much defocus can be read at each pixel, in [0, 1] `(B,1,H,W)`: local band-pass
    energy of the all-in-focus photo against a floor, zero where a channel is saturated."""
    energy = _band_energy(image.mean(1, keepdim=True), 0.0, window)
    floor = 1e-5 + 0.05 * energy.mean((-2, -1), keepdim=True)
    weight = energy / (energy + floor)
    saturated = (image.amax(1, keepdim=True) > 0.98).to(image.dtype)
    saturated = F.max_pool2d(saturated, 5, 1, 2)
    return weight * (1 - saturated)


def _box(x: Tensor, size: int) -> Tensor:
    # replicate: valid for windows larger than the image, unlike reflect
    return kornia.filters.box_blur(x, (size, size), border_type="replicate")


def solve_depth(
    blur: Tensor, weight: Tensor, settings: CameraSettings, near: float, far: float,
    n_candidates: int = 96, windows: Mapping[int, float] | None = None,
) -> tuple[Tensor, Tensor]:
    """Depth `(B,1,H,W)` metres from per-shot blur maps and the thin lens of each shot.

    For candidate inverse depths `x` evenly spaced in `[1/far, 1/near]`, the cost of a pixel is
    `sum_i |b_i - |A_i (1 - D_f,i x)|| / (0.3 + 0.15 b_i)` (blur errors grow with blur),
    aggregated over square windows weighted by `weight` (fine windows dominate where there is
    texture, coarse ones fill in where there is none); the best candidate is refined by a
    parabola through its neighbours.

    Args:
        blur: `(B,F,H,W)` measured CoC diameters in pixels (>= 0).
        weight: `(B,1,H,W)` or `(B,F,H,W)` texture weights in [0, 1] (`texture_weight`).
        settings: the `(B,F)` or `(F,)` camera settings of the shots (at this resolution).
        near: nearest depth, metres.
        far: farthest depth, metres.
        n_candidates: candidate depths.
        windows: window size (pixels) -> weight of its aggregated cost.

    Returns:
        `(depth, confidence)`, both `(B,1,H,W)`; confidence in [0, 1].
    """
    windows = windows or WINDOWS
    x = candidate_inverse_depths(near, far, n_candidates, blur)
    b, n, h, w = blur.shape
    settings = settings.batched(b).to(device=blur.device, dtype=blur.dtype)
    if settings.n_shots != n:
        raise ValueError(f"blur holds {n} shots but settings {settings.n_shots}")
    predicted = thin_lens_blur(settings, x[None, None])  # (B,F,K)
    weight = weight.expand(b, n, h, w)
    cost = torch.zeros(b, n_candidates, h, w, dtype=blur.dtype, device=blur.device)
    for i in range(n):
        scale = 1 / (0.3 + 0.15 * blur[:, i:i + 1])
        cost += weight[:, i:i + 1] * (blur[:, i:i + 1] - predicted[:, i, :, None, None]).abs() * scale
    total_weight = weight.mean(1, keepdim=True)
    den = sum(s * _box(total_weight, k) for k, s in windows.items()) + 1e-6
    depth = select_depth(aggregate_cost(cost, windows) / den, near, far)
    return depth, _box(total_weight, 5).clamp(0, 1)


#: Default windows (pixels) -> weights of `aggregate_cost`: fine windows dominate where there is
#: texture, coarse ones fill in where there is none.
WINDOWS = {5: 1.0, 17: 0.3, 49: 0.1}


def aggregate_cost(cost: Tensor, windows: Mapping[int, float] | None = None) -> Tensor:
    """`cost` `(B,K,H,W)` summed over square windows of each size with its weight (`WINDOWS` by
    default)."""
    return sum(s * _box(cost, k) for k, s in (windows or WINDOWS).items())


def select_depth(cost: Tensor, near: float, far: float) -> Tensor:
    """Depth `(B,1,H,W)` metres of the cheapest of the `K` candidates of `cost` `(B,K,H,W)`,
    candidate `k` at inverse depth `1/far + k (1/near - 1/far) / (K - 1)`, refined by a parabola
    through the neighbouring costs."""
    n_candidates = cost.shape[1]
    best = cost.argmin(1, keepdim=True)
    lo = cost.gather(1, (best - 1).clamp(0, n_candidates - 1))
    mid = cost.gather(1, best)
    hi = cost.gather(1, (best + 1).clamp(0, n_candidates - 1))
    curvature = (lo + hi - 2 * mid).clamp_min(torch.finfo(cost.dtype).tiny)
    offset = (0.5 * (lo - hi) / curvature).clamp(-0.5, 0.5)
    inside = (best > 0) & (best < n_candidates - 1)
    index = best.to(cost.dtype) + torch.where(inside, offset, torch.zeros_like(offset))
    inverse = 1 / far + index * (1 / near - 1 / far) / (n_candidates - 1)
    return (1 / inverse).clamp(near, far)


def thin_lens_blur(settings: CameraSettings, inverse_depth: Tensor) -> Tensor:
    """The blur `|c_i| = |A_i (1 - D_f,i x)|` pixels that the thin lens gives each shot of
    `settings` `(B,F)` at inverse depths `x` (1/metres) shaped `(B or 1, F or 1, ...)`:
    `(B,F,...)`.

    Example:
        >>> s = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4).batched(1)  # sharp at 2 m and 6 m
        >>> thin_lens_blur(s, torch.tensor([[[1 / 2.0, 1 / 6.0]]])).round(decimals=2)
        tensor([[[0.0000, 4.2700],
                 [4.2000, 0.0000]]], dtype=torch.float64)
    """
    trailing = (1,) * (inverse_depth.dim() - 2)
    a = settings.coc_at_infinity_px().reshape(*settings.shape, *trailing)
    focus = settings.focus_distance.reshape(*settings.shape, *trailing)
    return (a * (1 - focus * inverse_depth)).abs()


def candidate_inverse_depths(near: float, far: float, n_candidates: int, like: Tensor) -> Tensor:
    """The `n_candidates` inverse depths (1/metres) of `select_depth`, evenly spaced."""
    if not 0 < near < far:
        raise ValueError(f"need 0 < near < far metres, got near={near!r}, far={far!r}")
    return torch.linspace(1 / far, 1 / near, n_candidates, dtype=like.dtype, device=like.device)


class DepthFromDefocus(nn.Module):
    """Metric depth from an all-in-focus photo and `F >= 2` focused photos of any camera.

    Args:
        blur_net: the per-shot blur reader (a new `BlurNet()` by default).
        tile: largest tile side in pixels for the blur network (large photos are processed in
            overlapping tiles within a bounded memory).

    Example:
        >>> model = DepthFromDefocus(BlurNet(width=4))
        >>> settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
        >>> out = model(torch.rand(1, 3, 24, 24), torch.rand(1, 2, 3, 24, 24), settings, 1.0, 10.0)
        >>> out["depth"].shape, out["confidence"].shape, out["blur"].shape
        (torch.Size([1, 1, 24, 24]), torch.Size([1, 1, 24, 24]), torch.Size([1, 2, 24, 24]))
    """

    #: Largest blur (pixels) at the working resolution that `predict_depth` lets it read.
    max_coc_px = 12.0

    def __init__(self, blur_net: BlurNet | None = None, tile: int = 512, overlap: int = 48):
        super().__init__()
        self.blur_net = blur_net or BlurNet()
        self.tile, self.overlap = int(tile), int(overlap)

    def read_blur(self, image: Tensor, focused: Tensor) -> Tensor:
        """`(B,F,H,W)` CoC diameters in pixels of each focused photo `(B,F,3,H,W)`."""
        check_shape("focused", focused, ["B", "F", "3", "H", "W"])
        return torch.cat([self._tiled(image, focused[:, i]) for i in range(focused.shape[1])], 1)

    def _tiled(self, image: Tensor, focused: Tensor) -> Tensor:
        h, w = image.shape[-2:]
        if max(h, w) <= self.tile:
            return self.blur_net(image, focused)
        return apply_in_tiles(self.blur_net, [image, focused], self.tile - 2 * self.overlap,
                              self.overlap)

    def forward(self, image: Tensor, focused: Tensor, settings: CameraSettings, near: float,
                far: float) -> dict[str, Tensor]:
        """Depth, confidence and blur maps (see `solve_depth`) of a batch at this resolution."""
        blur = self.read_blur(image, focused)
        depth, confidence = solve_depth(blur, texture_weight(image), settings, near, far)
        return {"depth": depth, "confidence": confidence, "blur": blur}


#: PSF of the self-supervised loss's render: a Gaussian with a disk's second moment (sigma =
#: diameter / 4), so that blurs compose exactly (see `blur_loss`).
LOSS_PSF = Gaussian(0.25)
#: Blur (pixels) added in quadrature to both sides of the self-supervised comparison.
LOSS_FLOOR_PX = 2.0


def blur_loss(net: BlurNet, image: Tensor, focused: Tensor, supervision: str = "self",
              target_coc: Tensor | None = None, smoothness: float = 0.01,
              clean: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """Training loss of `BlurNet` on pairs `(B,3,H,W)`.

    `"self"`: the all-in-focus photo rendered with the predicted blur `b` must reproduce the
    focused photo (SSIM + L1), plus edge-aware smoothness of the blur; no depth and no camera
    are used. Both sides are blurred by `LOSS_FLOOR_PX` more: the render uses the Gaussian
    `LOSS_PSF` at `sqrt(b^2 + floor^2)` and the focused photo is blurred by that Gaussian at
    `floor`, which for Gaussians is the same comparison. A PSF narrower than a pixel spreads next
    to nothing, so without the floor the loss has no gradient for blurs under a pixel and a
    network that gets there never leaves (measured: it collapsed to one constant).

    `clean`: `(image, focused)` of the same views without the camera's imperfections, where the
    data has them (`datasets.capture.RandomCameraScenes`): the network still reads the
    imperfect photos, but the comparison uses the clean ones. A misaligned pair looks blurrier
    than it is, so on imperfect photos the loss rewards over-estimated blur (measured: 3.4 px
    read where the truth averaged 1.4 px).

    `"depth"` (the supervised twin): L1 to the true `|target_coc|` `(B,1,H,W)`, relative to
    `0.5 + |target|`.
    """
    blur = net(image, focused)
    if supervision == "depth":
        if target_coc is None:
            raise ValueError("supervision 'depth' needs target_coc")
        target = target_coc.abs()
        return ((blur - target).abs() / (0.5 + target)).mean()
    if supervision != "self":
        raise ValueError(f"supervision must be 'self' or 'depth', got {supervision!r}")
    source, target = clean if clean is not None else (image, match_exposure(image, focused))
    rendered = render_defocus(source, torch.sqrt(blur**2 + LOSS_FLOOR_PX**2), psf=LOSS_PSF,
                              max_kernel_size=41)
    sigma = float(LOSS_PSF.scale) * LOSS_FLOOR_PX
    size = LOSS_PSF.kernel_size(LOSS_FLOOR_PX)
    target = kornia.filters.gaussian_blur2d(target, (size, size), (sigma, sigma),
                                            border_type="replicate")
    return photometric_loss(rendered, target) + smoothness * edge_aware_smoothness(blur + 0.5, image)


def _per_shot(samples: list[Mapping[str, Any]], key: str) -> Tensor:
    """`sample[key]` `(3,H,W)` once per shot of each sample, stacked: `(sum F, 3, H, W)`."""
    return torch.cat([p[key][None].expand(len(p["focused"]), -1, -1, -1) for p in samples])


def train_blur_net(
    net: BlurNet, samples: Iterable[Mapping[str, Any]], steps: int, batch_size: int = 8,
    lr: float = 1e-3, supervision: str = "self", progress: bool = True,
    log: list[dict[str, float]] | None = None,
) -> BlurNet:
    """Train `net` on samples with `image`, `focused` `(F,3,H,W)` and, for `"depth"`
    supervision, `coc_px` `(F,1,H,W)`; every shot is one training pair. Samples that also hold
    `clean_image` and `clean_focused` give the self-supervised loss its clean targets (see
    `blur_loss`). Adam, cosine schedule, gradient clipping; stops with an error at the first
    non-finite loss."""
    from tqdm.auto import tqdm

    optimizer = torch.optim.Adam(net.parameters(), lr=lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda s: 0.5 * (1 + math.cos(math.pi * min(s, steps) / steps)))
    stream = iter(samples)
    net.train()
    bar = tqdm(range(int(steps)), desc=f"blur net ({supervision})", disable=not progress)
    for step in bar:
        pairs = [next(stream) for _ in range(batch_size)]
        image = _per_shot(pairs, "image")
        focused = torch.cat([p["focused"] for p in pairs])
        target = torch.cat([p["coc_px"] for p in pairs]) if supervision == "depth" else None
        clean = None
        if all("clean_image" in p for p in pairs):
            clean = (_per_shot(pairs, "clean_image"),
                     torch.cat([p["clean_focused"] for p in pairs]))
        loss = blur_loss(net, image, focused, supervision, target, clean=clean)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"non-finite blur-net loss at step {step}")
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        optimizer.step()
        schedule.step()
        if log is not None:
            log.append({"step": step + 1, "loss": float(loss.detach()),
                        "lr": schedule.get_last_lr()[0]})
        bar.set_postfix(loss=f"{float(loss.detach()):.4f}")
    net.eval()
    return net


def working_scale(settings: CameraSettings, near: float, far: float, shape: tuple[int, int],
                  max_coc_px: float = 12.0, max_pixels: int = 1_500_000) -> float:
    """The downscale factor (<= 1) of the photos for `DepthFromDefocus`: the largest CoC over
    `[near, far]` at most `max_coc_px` pixels (what `BlurNet` reads well) and at most
    `max_pixels` pixels (time and memory).

    Example:
        >>> s = CameraSettings(0.05, 1.4, [2.0, 6.0], 6e-6)  # 50 mm f/1.4, 6 um pixels
        >>> round(working_scale(s, 1.0, 10.0, (3000, 4000)), 3)
        0.048
    """
    largest = settings.largest_coc_px(near, far)
    return min(1.0, max_coc_px / max(largest, 1e-9), math.sqrt(max_pixels / (shape[0] * shape[1])))


def predict_depth(
    model: nn.Module, image: Tensor, focused: Tensor, settings: CameraSettings,
    near: float, far: float, max_coc_px: float | None = None, max_pixels: int = 1_500_000,
    align: bool = True, refine_range: bool = True,
) -> dict[str, Tensor | float]:
    """Depth of one scene at the photos' resolution, computed at the working resolution.

    Args:
        model: the depth-from-defocus model: `DepthFromDefocus` or `models.sweep.SweepDepth`.
        image: all-in-focus photo `(3,H,W)`, linear.
        focused: `(F,3,H,W)` focused photos, linear, `F >= 2` (1 works but stays ambiguous
            around the focus plane).
        settings: their `(F,)` settings at the photos' resolution (effective pixel pitch).
        near: nearest depth of the scene, metres.
        far: farthest depth, metres.
        max_coc_px: see `working_scale`; by default the model's `max_coc_px` (the largest blur
            it reads well).
        max_pixels: see `working_scale`.
        align: move (and, for a lens that breathes, scale) each focused photo onto the
            all-in-focus one first (`optics.align_shots`, at the working resolution): a
            misalignment would read as blur.
        refine_range: a stated range wider than the scene costs resolution: the largest blur
            over `[near, far]` sets the working resolution, and a scene much farther than
            `near` never blurs that much. With this on, a first pass finds the depths the scene
            holds (`scene_range`); if that range allows a working resolution at least
            `REFINE_GAIN` times finer, the depth is computed again there, over that range.

    Returns:
        dict with `depth` and `confidence` `(1,H,W)`, `blur` `(F,h,w)` at the working
        resolution, `scale` (working / photo resolution), `depth_range` (the `(near, far)`
        metres of the pass kept), `shifts` `(F,2)`, `zooms` `(F,)` and `rotations` `(F,)`: how
        far each focused photo had moved `(dy, dx)`, in the photos' pixels, how much it was
        magnified and how far it was turned, in degrees, clockwise on screen (zero, one and zero
        without `align`).
    """
    check_shape("image", image, ["3", "H", "W"])
    check_shape("focused", focused, ["F", "3", "H", "W"])
    check_finite("image", image)
    check_finite("focused", focused)
    if not (math.isfinite(near) and math.isfinite(far) and 0 < near < far):
        raise ValueError(f"near and far must be finite metres with 0 < near < far, got "
                         f"near={near!r}, far={far!r}")
    if max_coc_px is not None and not (math.isfinite(max_coc_px) and max_coc_px > 0):
        raise ValueError(f"max_coc_px must be a positive number of pixels, got {max_coc_px!r}")
    if not max_pixels >= 64:
        raise ValueError(f"max_pixels must be >= 64 (8x8 pixels), got {max_pixels!r}")
    if focused.shape[-2:] != image.shape[-2:]:
        raise ValueError(f"focused photos are {tuple(focused.shape[-2:])} pixels but the "
                         f"all-in-focus photo is {tuple(image.shape[-2:])}")
    h, w = image.shape[-2:]
    max_coc_px = model.max_coc_px if max_coc_px is None else max_coc_px
    scale = working_scale(settings, near, far, (h, w), max_coc_px, max_pixels)
    out = _predict_at(model, image, focused, settings, near, far, scale, align)
    if refine_range:
        inner = scene_range(out["depth"], near, far)
        finer = working_scale(settings, *inner, (h, w), max_coc_px, max_pixels)
        if finer >= REFINE_GAIN * scale:
            out = _predict_at(model, image, focused, settings, *inner, finer, align)
    return out


#: How much finer (ratio of working scales) the scene's own depth range must allow before
#: `predict_depth` computes the depth a second time.
REFINE_GAIN = 1.25


def scene_range(depth: Tensor, near: float, far: float, tail: float = 0.01,
                margin: float = 0.15) -> tuple[float, float]:
    """The depths `(near, far)` metres a depth map holds, within `[near, far]`: its `tail` and
    `1 - tail` quantiles in inverse depth, widened by `margin` times their span on each side
    (a coarse first estimate is off by some of it), and by at least 2 % of the stated range's
    inverse-depth span (a map of one depth still gets a range).

    Example:
        >>> depth = torch.linspace(2.0, 5.0, 1000).reshape(1, 1, 20, 50)
        >>> tuple(round(d, 2) for d in scene_range(depth, 1.0, 15.0, tail=0.0))
        (1.83, 6.45)
    """
    inverse = 1 / depth.detach().flatten().double()
    inverse = inverse[:: max(1, inverse.numel() // 100_000)]
    quantiles = torch.tensor([tail, 1 - tail], dtype=inverse.dtype, device=inverse.device)
    lo, hi = torch.quantile(inverse, quantiles).tolist()
    pad = max(margin * (hi - lo), 0.02 * (1 / near - 1 / far))
    return 1 / min(hi + pad, 1 / near), 1 / max(lo - pad, 1 / far)


def to_working_resolution(image: Tensor, focused: Tensor, settings: CameraSettings,
                          scale: float) -> tuple[Tensor, CameraSettings]:
    """The all-in-focus photo `(3,H,W)` and the focused ones `(F,3,H,W)` stacked `(1+F,3,h,w)`
    at `scale` (`working_scale`; area-averaged, at least 8x8 pixels), and their settings there
    (the effective pixel pitch grows by the same factor)."""
    h, w = image.shape[-2:]
    size = (max(8, round(h * scale)), max(8, round(w * scale)))
    stack = torch.cat([image[None], focused])
    small = F.interpolate(stack, size=size, mode="area") if scale < 1 else stack
    return small, settings.replace(pixel_pitch=settings.pixel_pitch * (w / size[1]))


def _predict_at(model: nn.Module, image: Tensor, focused: Tensor, settings: CameraSettings,
                near: float, far: float, scale: float, align: bool) -> dict[str, Tensor | float]:
    """`predict_depth`'s pass over `[near, far]` at the working `scale`."""
    h, w = image.shape[-2:]
    small, effective = to_working_resolution(image, focused, settings, scale)
    size = small.shape[-2:]
    identity = torch.tensor([0.0, 0.0, 1.0, 0.0], dtype=small.dtype,
                            device=small.device).expand(1, len(focused), 4)
    shots, motions = align_shots(small[:1], small[1:][None]) if align \
        else (small[1:][None], identity)
    with torch.no_grad():
        out = model(small[:1], shots, effective.to(small.dtype), near, far)
    depth = F.interpolate(out["depth"], size=(h, w), mode="bilinear", align_corners=False)
    confidence = F.interpolate(out["confidence"], size=(h, w), mode="bilinear",
                               align_corners=False)
    return {"depth": depth[0], "confidence": confidence[0], "blur": out["blur"][0],
            "scale": size[1] / w, "depth_range": (near, far),
            "shifts": motions[0, :, :2] * (w / size[1]), "zooms": motions[0, :, 2],
            "rotations": torch.rad2deg(motions[0, :, 3])}


def evaluate_on_sample(model: nn.Module, sample: Mapping[str, Any], near: float,
                       far: float) -> tuple[dict[str, float], Tensor, float]:
    """Metrics, depth `(1,H,W)` and seconds of `model` on one sample (with `image`,
    `focused`, `camera`, `depth`, `mask`), through `predict_depth`."""
    import time

    from .metrics import depth_metrics

    started = time.perf_counter()
    out = predict_depth(model, sample["image"], sample["focused"],
                        sample["camera"].to(sample["image"].dtype), near, far)
    seconds = time.perf_counter() - started
    metrics = depth_metrics(pred=out["depth"][None], target=sample["depth"][None],
                            mask=sample["mask"][None])
    return metrics, out["depth"], seconds
