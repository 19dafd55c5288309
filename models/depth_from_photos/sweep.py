"""Depth from defocus by a sweep over depth, given an all-in-focus photo: no network, any camera.

For a candidate depth, the thin lens gives each shot's blur `|c_i| = |A_i (1 - D_f,i / D)|`
pixels, and the all-in-focus photo blurred by the camera's PSF at that blur should reproduce the
focused photo. `sweep_cost` measures how well at every pixel: for every candidate and shot it
blurs the all-in-focus photo (a whole-image product in the Fourier domain, `FourierBlur`, the
photo transformed once per shot), keeps the local squared error against the focused photo and
sums over the shots. `select_depth` then picks the cheapest candidate after aggregating the costs
of neighbouring pixels (semi-globally along scan lines, `semi_global_cost`, by default), and a
median filter removes isolated wrong picks. The errors carry their own weighting: where the
all-in-focus photo has no texture every candidate costs the same, and the textured neighbours
decide.

Two imperfections of real photos bias such a sweep toward more blur, and both are removed:

- misalignment between shots looks like blur; `estimate_depth` aligns the shots first
  (`optics.align_shots`);
- noise: blurring the all-in-focus photo also averages its noise away, which lowers the error of
  every large blur by the noise it removed. `noise_model` measures the photo's noise level (a
  variance affine in intensity, shot plus read noise) from the photo itself, and the expected
  share of that noise at each blur is subtracted from the errors.

Both the photos and the camera are all it needs, so it works for any lens and focus distances
within the range where the blur is readable (about 0.5 to 20 pixels at the working resolution).
"""

from __future__ import annotations

import math

import kornia
import torch
from torch import Tensor, nn

from optics import Aperture, CameraSettings
from optics.checks import check_finite, check_shape
from optics.progress import progress_bar

from .confidence import depth_edge_confidence, texture_confidence
from .fourier_blur import FLOOR_SIGMA_PX, FourierBlur, psf_kernel, with_floor
from .photometry import match_exposure, noise_model
from .semi_global import SCALE_STRIDE, cost_scale, semi_global_cost
from .smoothing import edge_aware_smooth
from .thin_lens import (
    ERROR_WINDOW_PX,
    WINDOWS,
    aggregate_cost,
    box_filter,
    candidate_inverse_depths,
    select_depth,
    thin_lens_blur,
)
from .tiling import apply_in_tiles, check_tiling

#: Side (pixels) of the median filter the depth map goes through: it removes isolated wrong
#: picks (dark or textureless pixels whose costs are nearly flat) and keeps depth edges.
MEDIAN_PX = 9
#: `edge_aware_smooth` of the inverse depth afterwards: its strength, guide sigma, and the
#: confidence every pixel keeps (where the photo has no texture at all).
SMOOTHING_STRENGTH = 10.0
SMOOTHING_SIGMA = 0.1
CONFIDENCE_FLOOR = 0.01
#: Context (pixels) a tile sees beyond its centre under semi-global aggregation, whose scan lines
#: cross the whole tile: past this distance a pixel's costs rarely change another's pick.
SEMI_GLOBAL_CONTEXT_PX = 128
#: How `SweepDepth` aggregates the costs of neighbouring pixels.
AGGREGATIONS = ("semi-global", "windows")


def blur_errors(image: Tensor, focused: Tensor, aperture: Aperture, blurs: Tensor,
                noise: Tensor | None = None) -> Tensor:
    """Local squared error `(B,G,H,W)` between the all-in-focus `image` `(B,3,H,W)` blurred by
    `aperture` at each CoC diameter of `blurs` `(G,)` pixels and one `focused` photo `(B,3,H,W)`
    (exposure-matched to `image`: `match_exposure`), less the noise the blur removes from `image` (`noise`, the
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
    source = FourierBlur(image, half + math.ceil(4 * FLOOR_SIGMA_PX) + 2)
    target = FourierBlur(focused, source.pad_y)
    floor = with_floor(torch.ones(1, 1, dtype=image.dtype, device=image.device))
    reference = target.apply(target.transfer(floor))
    if noise is None:
        noise = noise_model(torch.cat([image, focused], 1))
    variance = (noise[:, :1, None, None] + noise[:, 1:, None, None]
                * box_filter(image, 5).clamp_min(0)).sum(1, keepdim=True)
    errors = []
    for blur_px in blurs.tolist():
        kernel = with_floor(psf_kernel(aperture, blur_px, image))
        squared = ((source.apply(source.transfer(kernel)) - reference) ** 2).sum(1, keepdim=True)
        # the noise variance `image` loses under this kernel: variance * sum of its squares
        errors.append(squared - variance * float((kernel**2).sum()))
    if not errors:
        return image.new_zeros(image.shape[0], 0, *image.shape[-2:])
    stacked = torch.cat(errors, 1)
    del errors  # one copy of the candidates' errors at a time
    return box_filter(stacked, ERROR_WINDOW_PX)


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
            exposure-matched to it (`match_exposure`).
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
    sweep over depth (`sweep_cost`, then `select_depth`). No weights: it is what
    `estimate_depth` runs when an all-in-focus photo is given (`method="sweep"`). Called like
    every method of `estimate_depth`: `(image, focused, settings, near, far)`.

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
            its depth: `"semi-global"` (`semi_global_cost`: along scan
            lines, depth edges kept where the photo has edges) or `"windows"` (sums over
            square windows, `aggregate_cost`; tiles then give exactly the untiled
            result, while semi-global tiles see `SEMI_GLOBAL_CONTEXT_PX` of context and agree
            with the untiled result at nearly every pixel).
        smoothing: strength of the edge-aware smoothing of the inverse depth by the texture
            confidence (`edge_aware_smooth`, whole image, after the tiles):
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

    #: Largest blur (pixels) at the working resolution that `estimate_depth` lets it read: the
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

    #: It needs an all-in-focus photo.
    needs_image = True

    def forward(self, image: Tensor | None, focused: Tensor, settings: CameraSettings,
                near: float, far: float) -> dict[str, Tensor]:
        """Depth `(B,1,H,W)` metres, confidence `(B,1,H,W)` in [0, 1] and the blur `(B,F,H,W)`
        pixels the thin lens gives each shot at that depth, from the all-in-focus `image`
        `(B,3,H,W)` and the `focused` photos `(B,F,3,H,W)`, linear. The confidence is low where
        there is no texture to read (or the photo is saturated) and across depth edges
        (`depth_edge_confidence`)."""
        if image is None:
            raise ValueError("the sweep compares the focused photos with an all-in-focus photo: "
                             "give image, a (B, 3, H, W) tensor")
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
            h, w = image.shape[-2:]
            scale = None
            if self.aggregation == "semi-global":  # the whole photo's, from a few candidates
                scale = cost_scale(sweep_cost(image, focused, settings, near, far,
                                              self.n_candidates, noise, every=SCALE_STRIDE),
                                   stride=1)
            tiles = math.ceil(h / self.tile) * math.ceil(w / self.tile)
            with progress_bar(total=tiles, desc="depth sweep (tiles)", disable=not self.progress) as bar:
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
