"""Networks that read blur: the camera-general `BlurNet` and the thin-lens solve behind it.

What the photos show is blur in pixels; the camera only maps blur to metres. So this model has
two parts:

1. `BlurNet` reads, for one focused photo and the all-in-focus photo, the CoC diameter `|c|` in
   pixels at every pixel. It never sees a camera, so it does not depend on one. It is trained
   without depth labels: the all-in-focus photo rendered with the predicted blur must reproduce
   the focused photo (the paper's self-supervision through the renderer, in blur space).
2. `solve_depth` finds, per pixel, the depth in `[near, far]` whose thin-lens blurs best explain
   the `F` measured blurs (two or more shots resolve the sign ambiguity around each focus plane),
   aggregating the costs over windows weighted by how much texture there is.

`DepthFromDefocus` puts them together, with tiling for large photos. It is an experiment: on the
cameras benchmark (`benchmarks/cameras.py`) it measures worse than the label-free sweep at every
camera (docs/tutorials/own_photos.md), so no weights ship and `defocus predict` does not offer
it; `examples/blur_net.py` trains it and `estimate_depth(..., model=...)` runs it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import kornia
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from optics import CameraSettings, Gaussian, render_defocus
from optics.checks import check_shape

from ..losses import edge_aware_smoothness, photometric_loss
from .confidence import band_energy, texture_weight
from .photometry import match_exposure
from .thin_lens import (
    WINDOWS,
    aggregate_cost,
    box_filter,
    candidate_inverse_depths,
    select_depth,
    thin_lens_blur,
)
from .tiling import apply_in_tiles

#: Blur (pixels) a fresh `BlurNet` answers everywhere: inside the range it reads, where the
#: self-supervised loss is steep (softplus of ~0 would start at 0.7 px, where it is nearly flat).
INITIAL_BLUR_PX = 4.0

#: Scales (pixels) of the band-pass energies in `blur_features`.
FEATURE_SCALES = (0.0, 1.0, 2.0, 4.0)


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
        ea, eb = band_energy(a, scale), band_energy(b, scale)
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
    den = sum(s * box_filter(total_weight, k) for k, s in windows.items()) + 1e-6
    depth = select_depth(aggregate_cost(cost, windows) / den, near, far)
    return depth, box_filter(total_weight, 5).clamp(0, 1)


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

    #: Largest blur (pixels) at the working resolution that `estimate_depth` lets it read.
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
