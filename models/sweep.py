"""Depth from defocus by a sweep over depth: no network, no training, any camera.

For a candidate depth, the thin lens gives each shot's blur `|c_i| = |A_i (1 - D_f,i / D)|`
pixels, and the all-in-focus photo blurred by the camera's PSF at that blur should reproduce the
focused photo. `sweep_cost` measures how well at every pixel: for every candidate and shot it
blurs the all-in-focus photo (a whole-image product in the Fourier domain, the photo transformed
once per shot), keeps the local squared error against the focused photo and sums over the shots.
`models.blur.select_depth` then picks the cheapest candidate after aggregating the costs of
neighbouring pixels (semi-globally along scan lines, `models.semi_global`, by default), and a
median filter removes isolated wrong picks. The errors carry their own weighting: where the
all-in-focus photo has no texture every candidate costs the same, and the textured neighbours
decide.

Two imperfections of real photos bias such a sweep toward more blur, and both are removed:

- misalignment between shots looks like blur; `models.blur.predict_depth` aligns the shots first
  (`optics.align_shots`);
- noise: blurring the all-in-focus photo also averages its noise away, which lowers the error of
  every large blur by the noise it removed. `noise_model` measures the photo's noise level (a
  variance affine in intensity, shot plus read noise) from the photo itself, and the expected
  share of that noise at each blur is subtracted from the errors.

Both the photos and the camera are all it needs, so it works for any lens and focus distances
within the range where the blur is readable (about 0.5 to 20 pixels at the working resolution).
"""

from __future__ import annotations

import functools
import math

import kornia
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from optics import Aperture, CameraSettings
from optics.checks import check_finite, check_shape

from .blur import (
    WINDOWS,
    _box,
    aggregate_cost,
    candidate_inverse_depths,
    match_exposure,
    select_depth,
    texture_weight,
    thin_lens_blur,
)
from .semi_global import SCALE_STRIDE, cost_scale, semi_global_cost
from .smoothing import edge_aware_smooth
from .tiling import apply_in_tiles, check_tiling

#: Gaussian (sigma, pixels) applied to both sides of every comparison: errors of a fraction of a
#: pixel (quantisation, resampling) weigh less than the blur being read.
FLOOR_SIGMA_PX = 0.5
#: Side (pixels) of the window the squared errors are first summed over.
ERROR_WINDOW_PX = 5
#: Side (pixels) of the median filter the depth map goes through: it removes isolated wrong
#: picks (dark or textureless pixels whose costs are nearly flat) and keeps depth edges.
MEDIAN_PX = 9
#: `models.smoothing.edge_aware_smooth` of the inverse depth afterwards: its strength, guide
#: sigma, and the confidence every pixel keeps (where the photo has no texture at all).
SMOOTHING_STRENGTH = 10.0
SMOOTHING_SIGMA = 0.1
CONFIDENCE_FLOOR = 0.01
#: The returned confidence halves every `BLUR_SPAN_PX * ln 2` pixels by which the blur read
#: varies within an error window (`depth_edge_confidence`).
BLUR_SPAN_PX = 0.5
#: Context (pixels) a tile sees beyond its centre under semi-global aggregation, whose scan lines
#: cross the whole tile: past this distance a pixel's costs rarely change another's pick.
SEMI_GLOBAL_CONTEXT_PX = 128
#: How `SweepDepth` aggregates the costs of neighbouring pixels.
AGGREGATIONS = ("semi-global", "windows")

# Immerkaer's noise operator: zero on any plane, on white noise of variance s^2 its response has
# variance 36 s^2.
_NOISE_OPERATOR = ((1.0, -2.0, 1.0), (-2.0, 4.0, -2.0), (1.0, -2.0, 1.0))


def _local_noise(image: Tensor, window: int = 7) -> tuple[Tensor, Tensor]:
    """Per-pixel noise-variance estimates and local mean intensities of `(N,1,H,W)`."""
    operator = torch.tensor(_NOISE_OPERATOR, dtype=image.dtype, device=image.device)
    response = F.conv2d(image, operator[None, None])
    return _box(response**2, window) / 36, _box(image[..., 1:-1, 1:-1], window)


_QUANTILE = 0.1


@functools.cache
def _quantile_of_pure_noise() -> float:
    """`_QUANTILE` of `_local_noise`'s estimates on white noise of unit variance (measured once)."""
    g = torch.Generator().manual_seed(0)
    white, _ = _local_noise(torch.randn(1, 1, 256, 256, generator=g, dtype=torch.float64))
    return float(torch.quantile(white.flatten(), _QUANTILE))


def noise_model(image: Tensor, bins: int = 12) -> Tensor:
    """The noise of a photo `(B,C,H,W)` (linear intensity): `(B,2)` coefficients `(a, b)` of the
    per-pixel variance `a + b * intensity` (read noise plus shot noise). Photos of one sensor
    stacked along the channels are pooled: the defocused ones, with less texture to mistake for
    noise, then set the estimate.

    Per intensity band, the low tail (10th percentile) of the local variance of Immerkaer's
    operator responses is texture-free enough to be noise; its ratio to the noise variance is
    that percentile for pure white noise, measured once. A least-squares line through the bands,
    kept non-negative, gives `a` and `b`.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> flat = torch.linspace(0.1, 0.9, 128).expand(1, 3, 128, 128)
        >>> noisy = flat + torch.randn(1, 3, 128, 128, generator=g) * (1e-4 + 1e-3 * flat).sqrt()
        >>> a, b = noise_model(noisy)[0].tolist()
        >>> 0.5e-3 < b < 2e-3 and a < 5e-4
        True
    """
    check_shape("image", image, ["B", "C", "H", "W"])
    if min(image.shape[-2:]) < 16:
        return torch.zeros(image.shape[0], 2, dtype=image.dtype, device=image.device)
    out = []
    for photo in image.detach().double():
        variance, level = (t.flatten() for t in _local_noise(photo[:, None]))
        # torch.quantile takes at most 2^24 values: a regular subsample of a larger stack
        stride = math.ceil(level.numel() / 2**24)
        variance, level = variance[::stride], level[::stride]
        edges = torch.quantile(level, torch.linspace(0, 1, bins + 1, dtype=level.dtype,
                                                     device=level.device))
        xs, ys = [], []
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            band = (level >= lo) & (level <= hi)
            if int(band.sum()) < 50:
                continue
            xs.append(float(level[band].median()))
            ys.append(float(torch.quantile(variance[band], _QUANTILE)) / _quantile_of_pure_noise())
        x, y = torch.tensor(xs, dtype=torch.float64), torch.tensor(ys, dtype=torch.float64)
        design = torch.stack([torch.ones_like(x), x], 1)
        a, b = torch.linalg.lstsq(design, y[:, None]).solution.flatten().tolist()
        if b < 0:
            a, b = float(y.mean()), 0.0
        if a < 0:
            a, b = 0.0, float((x * y).sum() / (x * x).sum().clamp_min(1e-30))
        out.append([a, b])
    return torch.tensor(out, dtype=image.dtype, device=image.device)


def _smooth_size(n: int) -> int:
    """The smallest integer >= `n` with no prime factor above 5."""
    while True:
        m = n
        for p in (2, 3, 5):
            while m % p == 0:
                m //= p
        if m == 1:
            return n
        n += 1


class _FourierBlur:
    """Whole-image convolutions of one `(B,C,H,W)` image with many kernels: the image is mirrored
    at its borders by `pad` (and its edge repeated beyond what a small image can mirror) and
    transformed once."""

    def __init__(self, image: Tensor, pad: int):
        self.h, self.w = image.shape[-2:]
        self.pad_y, self.pad_x = pad, pad
        my, mx = min(pad, self.h - 1), min(pad, self.w - 1)
        padded = F.pad(image, (mx, mx, my, my), mode="reflect")
        # then the edge repeated: beyond what a small image can mirror, and on to a size whose
        # only prime factors are 2, 3 and 5 (several times faster transforms)
        extra_y = _smooth_size(self.h + 2 * pad) - self.h - 2 * pad
        extra_x = _smooth_size(self.w + 2 * pad) - self.w - 2 * pad
        padded = F.pad(padded, (pad - mx, pad - mx + extra_x, pad - my, pad - my + extra_y),
                       mode="replicate")
        self.size = padded.shape[-2:]
        self.spectrum = torch.fft.rfft2(padded)

    def transfer(self, kernel: Tensor) -> Tensor:
        """Transfer function of `kernel` `(K,K)` (centred) on the padded grid."""
        k = kernel.shape[-1]
        if k > min(self.size):
            raise ValueError(f"a {k}-pixel kernel does not fit the padded {tuple(self.size)}")
        grid = torch.zeros(self.size, dtype=kernel.dtype, device=kernel.device)
        grid[:k, :k] = kernel
        return torch.fft.rfft2(torch.roll(grid, (-(k // 2), -(k // 2)), (0, 1)))

    def apply(self, transfer: Tensor) -> Tensor:
        out = torch.fft.irfft2(self.spectrum * transfer, s=self.size)
        return out[..., self.pad_y:self.pad_y + self.h, self.pad_x:self.pad_x + self.w]


def _with_floor(kernel: Tensor) -> Tensor:
    """`kernel` `(K,K)` convolved with the sampled Gaussian of `FLOOR_SIGMA_PX` (spatially, so
    that the result does not depend on the size of the image it is applied to)."""
    half = math.ceil(4 * FLOOR_SIGMA_PX)
    offsets = torch.arange(-half, half + 1, dtype=kernel.dtype, device=kernel.device)
    line = torch.exp(-(offsets**2) / (2 * FLOOR_SIGMA_PX**2))
    gaussian = torch.outer(line, line) / line.sum() ** 2
    padded = F.pad(kernel[None, None], (2 * half,) * 4)
    return F.conv2d(padded, gaussian[None, None])[0, 0]


def _blur_kernel(aperture: Aperture, blur_px: float, like: Tensor) -> Tensor:
    if blur_px < 0.05:  # a PSF under a twentieth of a pixel is a delta
        return torch.ones(1, 1, dtype=like.dtype, device=like.device)
    return aperture.kernel(torch.tensor(blur_px, dtype=like.dtype, device=like.device))[0]


def blur_errors(image: Tensor, focused: Tensor, aperture: Aperture, blurs: Tensor,
                noise: Tensor | None = None) -> Tensor:
    """Local squared error `(B,G,H,W)` between the all-in-focus `image` `(B,3,H,W)` blurred by
    `aperture` at each CoC diameter of `blurs` `(G,)` pixels and one `focused` photo `(B,3,H,W)`
    (exposure-matched to `image`: `models.blur.match_exposure`), less the noise the blur removes from `image` (`noise`, the
    `(B,2)` coefficients of `noise_model`; by default measured on both photos); both sides
    through a Gaussian of `FLOOR_SIGMA_PX`, summed over channels and averaged over
    `ERROR_WINDOW_PX` windows.

    Example:
        >>> from optics import Disk
        >>> image = torch.rand(1, 3, 32, 32)
        >>> errors = blur_errors(image, image, Disk(), torch.tensor([0.0, 2.0, 4.0]))
        >>> errors.shape, bool(errors[0, 0].mean() < errors[0, 2].mean())
        (torch.Size([1, 3, 32, 32]), True)
    """
    check_shape("image", image, ["B", "3", "H", "W"])
    check_shape("focused", focused, ["B", "3", "H", "W"])
    largest = float(blurs.max()) if blurs.numel() else 0.0
    half = aperture.kernel_size(largest) // 2
    source = _FourierBlur(image, half + math.ceil(4 * FLOOR_SIGMA_PX) + 2)
    target = _FourierBlur(focused, source.pad_y)
    floor = _with_floor(torch.ones(1, 1, dtype=image.dtype, device=image.device))
    reference = target.apply(target.transfer(floor))
    if noise is None:
        noise = noise_model(torch.cat([image, focused], 1))
    variance = (noise[:, :1, None, None] + noise[:, 1:, None, None]
                * _box(image, 5).clamp_min(0)).sum(1, keepdim=True)
    errors = []
    for blur_px in blurs.tolist():
        kernel = _with_floor(_blur_kernel(aperture, blur_px, image))
        squared = ((source.apply(source.transfer(kernel)) - reference) ** 2).sum(1, keepdim=True)
        # the noise variance `image` loses under this kernel: variance * sum of its squares
        errors.append(squared - variance * float((kernel**2).sum()))
    if not errors:
        return image.new_zeros(image.shape[0], 0, *image.shape[-2:])
    stacked = torch.cat(errors, 1)
    del errors  # one copy of the candidates' errors at a time
    return _box(stacked, ERROR_WINDOW_PX)


def texture_confidence(image: Tensor) -> Tensor:
    """How much texture the sweep can read around each pixel, in [0, 1] `(B,1,H,W)`: the
    photo's `models.blur.texture_weight` averaged over 5x5 pixels. It weighs the smoothing and
    is one factor of `SweepDepth`'s confidence."""
    return _box(texture_weight(image), 5).clamp(0, 1)


def depth_edge_confidence(blur: Tensor, window: int = ERROR_WINDOW_PX,
                          span_px: float = BLUR_SPAN_PX) -> Tensor:
    """How well the sweep's model holds at each pixel, in (0, 1] `(B,1,H,W)`: the sweep compares
    each error window with one blur, which fails across a depth edge (the window sees two
    blurs). From the blur maps `(B,F,H,W)` (pixels) of the depth found: `exp(-r / span_px)`, `r`
    the largest range (max - min) of any shot's blur over a `window x window` neighbourhood.

    Example:
        >>> blur = torch.zeros(1, 2, 1, 10)
        >>> blur[..., 5:] = 1.0  # a depth edge: the blur jumps by one pixel
        >>> tuple(round(v, 2) for v in depth_edge_confidence(blur)[0, 0, 0].tolist())
        (1.0, 1.0, 1.0, 0.14, 0.14, 0.14, 0.14, 1.0, 1.0, 1.0)
    """
    check_shape("blur", blur, ["B", "F", "H", "W"])
    if isinstance(window, bool) or not (isinstance(window, int) and window >= 1
                                         and window % 2 == 1):
        raise ValueError(f"window must be an odd number of pixels >= 1, got {window!r}")
    if not span_px > 0:
        raise ValueError(f"span_px must be > 0 pixels, got {span_px!r}")
    pad = window // 2
    padded = F.pad(blur, (pad, pad, pad, pad), mode="replicate")
    spread = F.max_pool2d(padded, window, 1) + F.max_pool2d(-padded, window, 1)
    return torch.exp(-spread.amax(1, keepdim=True) / span_px)


def sweep_cost(image: Tensor, focused: Tensor, settings: CameraSettings, near: float,
               far: float, n_candidates: int = 96, noise: Tensor | None = None,
               every: int = 1) -> Tensor:
    """Cost `(B,K,H,W)` of the `K = n_candidates` depths of `candidate_inverse_depths`: summed
    over shots, the `blur_errors` of each shot at the blur the thin lens gives that shot at that
    depth. (Each candidate's blur is rendered: interpolating between a coarser grid of blurs
    would misplace minima, most where a disk starts to spread past its pixel near 1 px.)

    Args:
        image: all-in-focus photos `(B,3,H,W)`, linear.
        focused: focused photos `(B,F,3,H,W)`, linear, aligned with `image` and
            exposure-matched to it (`models.blur.match_exposure`).
        settings: `(B,F)` or `(F,)` settings of the shots at this resolution; their aperture is
            the PSF rendered.
        near: nearest depth, metres.
        far: farthest depth, metres.
        n_candidates: candidate depths.
        noise: `(B,2)` `noise_model` coefficients of the photos; by default measured on all of
            them.
        every: cost only every this many candidates (`K = ceil(n_candidates / every)`; the
            same values as `sweep_cost(...)[:, ::every]`).
    """
    check_shape("focused", focused, ["B", "F", "3", "H", "W"])
    b, n, _, h, w = focused.shape
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ValueError(f"every must be a positive integer, got {every!r}")
    x = candidate_inverse_depths(near, far, n_candidates, image)[::every]
    settings = settings.batched(b).to(device=image.device, dtype=image.dtype)
    if settings.n_shots != n:
        raise ValueError(f"focused holds {n} shots but settings {settings.n_shots}")
    predicted = thin_lens_blur(settings, x[None, None])  # (B,F,K)
    aperture = settings.aperture_module()
    if noise is None:  # every photo: one sensor
        noise = noise_model(torch.cat([image, focused.flatten(1, 2)], 1))
    cost = torch.zeros(b, x.numel(), h, w, dtype=image.dtype, device=image.device)
    for j in range(b):
        for i in range(n):
            cost[j] += blur_errors(image[j:j + 1], focused[j:j + 1, i], aperture, predicted[j, i],
                                   noise[j:j + 1])[0]
    return cost


class SweepDepth(nn.Module):
    """Metric depth from an all-in-focus photo and `F >= 2` focused photos of any camera, by a
    sweep over depth (`sweep_cost`, then `models.blur.select_depth`). No weights: it is the
    default model of `defocus predict`. Same call as `models.blur.DepthFromDefocus`.

    Photos larger in pixels than one tile with its context are swept in tiles (the cost volume
    of a whole 1.5-megapixel photo would take gigabytes), each with context around it: exactly
    the untiled result with `aggregation="windows"`; with the semi-global aggregation every tile
    uses the whole photo's cost scale and at 741x500 (tile 200) 0.5 % of the pixels differ
    from the untiled depth by more than 1 % (at most 2.2 %).

    Args:
        n_candidates: candidate depths, evenly spaced in inverse depth.
        tile: largest tile side in pixels.
        progress: show a progress bar over the tiles of a large photo.
        aggregation: how the costs of neighbouring pixels are combined before each pixel picks
            its depth: `"semi-global"` (`models.semi_global.semi_global_cost`: along scan
            lines, depth edges kept where the photo has edges) or `"windows"` (sums over
            square windows, `models.blur.aggregate_cost`; tiles then give exactly the untiled
            result, while semi-global tiles see `SEMI_GLOBAL_CONTEXT_PX` of context and agree
            with the untiled result at nearly every pixel).
        smoothing: strength of the edge-aware smoothing of the inverse depth by the texture
            confidence (`models.smoothing.edge_aware_smooth`, whole image, after the tiles):
            depth read on textured pixels spreads to their untextured neighbours of similar
            colour. Zero turns it off.

    Example:
        >>> from optics import CameraSettings
        >>> settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
        >>> out = SweepDepth()(torch.rand(1, 3, 24, 24), torch.rand(1, 2, 3, 24, 24), settings,
        ...                    1.0, 10.0)
        >>> out["depth"].shape, out["confidence"].shape, out["blur"].shape
        (torch.Size([1, 1, 24, 24]), torch.Size([1, 1, 24, 24]), torch.Size([1, 2, 24, 24]))
    """

    #: Largest blur (pixels) at the working resolution that `predict_depth` lets it read: the
    #: upper end the thin-lens design covers (larger blurs cost time and gain little).
    max_coc_px = 20.0

    def __init__(self, n_candidates: int = 96, tile: int = 384, progress: bool = False,
                 smoothing: float = SMOOTHING_STRENGTH, aggregation: str = "semi-global"):
        super().__init__()
        if n_candidates < 3:
            raise ValueError(f"n_candidates must be >= 3, got {n_candidates!r}")
        if aggregation not in AGGREGATIONS:
            raise ValueError(f"aggregation must be one of {AGGREGATIONS}, got {aggregation!r}")
        self.aggregation = aggregation
        if not smoothing >= 0:
            raise ValueError(f"smoothing must be >= 0, got {smoothing!r}")
        check_tiling(tile, 0)
        self.n_candidates, self.tile, self.progress = int(n_candidates), int(tile), progress
        self.smoothing = float(smoothing)

    def forward(self, image: Tensor, focused: Tensor, settings: CameraSettings, near: float,
                far: float) -> dict[str, Tensor]:
        """Depth `(B,1,H,W)` metres, confidence `(B,1,H,W)` in [0, 1] and the blur `(B,F,H,W)`
        pixels the thin lens gives each shot at that depth. The confidence is low where there is
        no texture to read (or the photo is saturated) and across depth edges
        (`depth_edge_confidence`)."""
        check_shape("image", image, ["B", "3", "H", "W"])
        check_shape("focused", focused, ["B", "F", "3", "H", "W"])
        check_finite("image", image)
        check_finite("focused", focused)
        settings = settings.batched(image.shape[0]).to(device=image.device, dtype=image.dtype)
        focused = torch.stack([match_exposure(image, focused[:, i])
                               for i in range(focused.shape[1])], 1)
        noise = noise_model(torch.cat([image, focused.flatten(1, 2)], 1))

        def depth_of(image: Tensor, focused: Tensor, scale: Tensor | None = None) -> Tensor:
            cost = sweep_cost(image, focused, settings, near, far, self.n_candidates, noise)
            if self.aggregation == "semi-global":
                cost = semi_global_cost(cost, image, scale=scale)
            else:
                cost = aggregate_cost(cost)
            return kornia.filters.median_blur(select_depth(cost, near, far), MEDIAN_PX)

        # context around a tile: the largest PSF, the error window, the aggregation (exact for
        # windows) and the median filter
        largest = settings.largest_coc_px(near, far)
        spread = (SEMI_GLOBAL_CONTEXT_PX if self.aggregation == "semi-global"
                  else max(WINDOWS) // 2)
        reach = settings.aperture_module().kernel_size(largest) // 2 + math.ceil(
            4 * FLOOR_SIGMA_PX) + ERROR_WINDOW_PX // 2 + spread + MEDIAN_PX // 2 + 2
        # a photo no larger than one tile with its context is swept whole
        if image.shape[-2] * image.shape[-1] <= (self.tile + 2 * reach) ** 2:
            depth = depth_of(image, focused)
        else:
            from tqdm.auto import tqdm

            h, w = image.shape[-2:]
            scale = None
            if self.aggregation == "semi-global":  # the whole photo's, from a few candidates
                scale = cost_scale(sweep_cost(image, focused, settings, near, far,
                                              self.n_candidates, noise, every=SCALE_STRIDE),
                                   stride=1)
            tiles = math.ceil(h / self.tile) * math.ceil(w / self.tile)
            with tqdm(total=tiles, desc="depth sweep (tiles)", disable=not self.progress) as bar:
                def tile_depth(image: Tensor, focused: Tensor) -> Tensor:
                    out = depth_of(image, focused, scale)
                    bar.update()
                    return out

                depth = apply_in_tiles(tile_depth, [image, focused], self.tile, reach)
        texture = texture_confidence(image)
        if self.smoothing > 0:
            weight = kornia.filters.median_blur(texture, MEDIAN_PX) + CONFIDENCE_FLOOR
            inverse = edge_aware_smooth(1 / depth, weight, image, self.smoothing, SMOOTHING_SIGMA)
            depth = 1 / inverse.clamp(1 / far, 1 / near)
        blur = thin_lens_blur(settings, 1 / depth)
        return {"depth": depth, "confidence": texture * depth_edge_confidence(blur),
                "blur": blur}
