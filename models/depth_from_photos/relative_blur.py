"""Depth from two or more focused shots alone, by the relative blur between them.

Without an all-in-focus photo, every shot is compared with every other. At a candidate depth the
thin lens gives shot `i` a blur of `d_i` pixels (its own focus distance, f-number and pitch, so a
nearly sharp f/8 shot beside an f/2.8 one is just another shot). Of a pair, the sharper shot
(`d_s <= d_r`) blurred by the *relative* PSF must reproduce the blurrier one; `relative_blur_cost`
measures how well at every pixel, summed over every pair, and `RelativeBlurDepth` turns those
costs into depth the way the sweep does (`CostVolumeDepth`).

The relative PSF is the aperture's own PSF at the diameter `d_rel = sqrt(d_r^2 - d_s^2)`
(`relative_blur_px`):

- for a Gaussian PSF it is exact (Gaussians compose, variances add);
- for any PSF it is exact when the sharper shot is in focus (`d_s = 0`);
- for a disk or a polygon it keeps the second moment exactly (a disk of diameter `d` has variance
  `d^2 / 16` per axis, and variances add under convolution), while the shape is approximate: a
  disk of `d_s` blurred by a disk of `d_rel` is a rounded cone, not a disk of `d_r`. For
  `d_r = 8` pixels, the L1 distance between the two kernels is 0.16, 0.31 and 0.35 of the
  kernel's mass for `d_s = 2, 4` and `6` (`tests/test_relative_blur.py` computes it); the
  cost's minimum stays at the true depth for disks too (the same test, float32 and float64).

Which shot of a pair is the sharper one changes with the candidate; both sides of every
comparison go through the small floor Gaussian (`with_floor`), the expected noise of both sides
is subtracted and each window's error is divided by that expected noise variance (a chi-square
per window, zero on average at the true depth), so that costs compare across that switch and
across pairs: a comparison that keeps more noise (through a sharper relative PSF) weighs less.
On the procedural tuning scenes of `benchmarks/tune_focus_stack.py` dividing by the noise
lowered the median ratio to the best constant from 0.560 to 0.548 (mean 0.705 to 0.674).
Where the two shots blur equally (between two focus planes) the pair still says something: the
shots must then agree.
"""

from __future__ import annotations

import itertools
import math

import torch
from torch import Tensor

from optics import Aperture, CameraSettings
from optics.checks import check_finite, check_shape

from .confidence import depth_edge_confidence, texture_confidence
from .cost_volume import CostVolumeDepth
from .fourier_blur import FLOOR_SIGMA_PX, FourierBlur, psf_kernel, with_floor
from .photometry import match_exposure, noise_model, noise_variance
from .thin_lens import (
    ERROR_WINDOW_PX,
    WINDOW_CHUNK,
    box_filter,
    candidate_blurs,
    thin_lens_blur,
    windowed_errors,
)

#: Floor of the expected noise variance a comparison's error is divided by (noise-free photos).
MIN_NOISE_VARIANCE = 1e-10


def relative_blur_px(sharper_px: Tensor, blurrier_px: Tensor) -> Tensor:
    """Diameter (pixels) of the relative PSF that takes a blur of `sharper_px` to one of
    `blurrier_px` (module docstring): `sqrt(max(d_r^2 - d_s^2, 0))`.

    Example:
        >>> relative_blur_px(torch.tensor([3.0, 5.0]), torch.tensor([5.0, 5.0]))
        tensor([4., 0.])
    """
    return (blurrier_px**2 - sharper_px**2).clamp_min(0).sqrt()


def pair_errors(first: Tensor, second: Tensor, aperture: Aperture, first_px: Tensor,
                second_px: Tensor, noise: Tensor, out: Tensor | None = None) -> Tensor:
    """Local error `(1,K,H,W)` between two shots `(1,3,H,W)` (exposure-matched, aligned) for `K`
    candidate blurs `first_px`, `second_px` `(K,)` pixels: per candidate the sharper shot
    blurred by the relative PSF against the blurrier one, both through the floor Gaussian; the
    squared difference summed over channels, less the noise both sides keep (`noise`, `(1,2)`
    `noise_model` coefficients), over that expected noise, each summed over `ERROR_WINDOW_PX`
    windows (at least `MIN_NOISE_VARIANCE`, for noise-free photos). With `out` (a `(1,K,H,W)`
    volume) the errors are added into it and it is returned (no second volume in memory).

    Example:
        >>> from optics import Disk
        >>> sharp = torch.rand(1, 3, 32, 32)
        >>> errors = pair_errors(sharp, sharp, Disk(), torch.tensor([0.0, 0.0]),
        ...                      torch.tensor([0.0, 4.0]), torch.zeros(1, 2))
        >>> bool(errors[0, 0].mean() < errors[0, 1].mean())  # no relative blur: the truth
        True
    """
    largest = float(torch.maximum(first_px, second_px).max()) if first_px.numel() else 0.0
    pad = aperture.kernel_size(largest) // 2 + math.ceil(4 * FLOOR_SIGMA_PX) + 2
    shots = (FourierBlur(first, pad), FourierBlur(second, pad))
    floor = with_floor(torch.ones(1, 1, dtype=first.dtype, device=first.device))
    floor_energy = float((floor**2).sum())
    references = [shot.apply(shot.transfer(floor)) for shot in shots]
    # the noise variances summed over the error windows, once (a window sum is linear)
    variances = [box_filter(noise_variance(photo, noise), ERROR_WINDOW_PX)
                 for photo in (first, second)]
    first_sharper = (first_px <= second_px).tolist()
    relative = relative_blur_px(torch.minimum(first_px, second_px),
                                torch.maximum(first_px, second_px)).tolist()
    # the noise each side keeps, per candidate: its window sum times the energy of the kernel
    # it went through (the floor alone for the blurrier shot)
    energies = first.new_zeros(2, len(relative))

    def error(k: int) -> Tensor:
        s, r = (0, 1) if first_sharper[k] else (1, 0)
        kernel = with_floor(psf_kernel(aperture, relative[k], first))
        energies[s, k] += float((kernel**2).sum())
        energies[r, k] += floor_energy
        return shots[s].squared_error(kernel, references[r])

    # one chunk's expected noise, reused: no fresh pages per chunk (fresh ones where
    # gradients are asked for)
    reuse = not (torch.is_grad_enabled() and (first.requires_grad or second.requires_grad))
    expected = first.new_empty(1, min(WINDOW_CHUNK, len(relative)), *first.shape[-2:]) \
        if reuse else None

    def normalised(means: Tensor, start: int, stop: int) -> Tensor:
        noise = torch.mul(energies[0, start:stop, None, None], variances[0],
                          out=None if expected is None else expected[:, :stop - start])
        noise.addcmul_(energies[1, start:stop, None, None], variances[1])
        return means.sub_(noise).div_(noise.clamp_min_(MIN_NOISE_VARIANCE))

    return windowed_errors(error, len(relative), first, out, normalised)


def relative_blur_cost(focused: Tensor, settings: CameraSettings, near: float, far: float,
                       n_candidates: int = 96, noise: Tensor | None = None,
                       every: int = 1) -> Tensor:
    """Cost `(B,K,H,W)` of the `K = n_candidates` depths of `candidate_inverse_depths`: summed
    over every pair of shots, their `pair_errors` at the blurs the thin lens gives them there.

    Args:
        focused: `(B,F,3,H,W)` shots, `F >= 2`, linear, aligned and exposure-matched.
        settings: their `(B,F)` or `(F,)` settings at this resolution; the aperture is the PSF.
        near: nearest depth, metres.
        far: farthest depth, metres.
        n_candidates: candidate depths.
        noise: `(B,2)` `noise_model` coefficients; by default measured on all shots.
        every: cost only every this many candidates (as `sweep_cost`).

    Example:
        >>> s = CameraSettings(0.05, 2.0, [1.5, 4.0], 1e-4)
        >>> relative_blur_cost(torch.rand(1, 2, 3, 24, 24), s, 1.0, 10.0, 8).shape
        torch.Size([1, 8, 24, 24])
    """
    check_shape("focused", focused, ["B", "F", "3", "H", "W"])
    b, n, _, h, w = focused.shape
    if n < 2:
        raise ValueError(f"the relative blur compares shots: focused needs 2 or more, got {n}")
    predicted = candidate_blurs(settings, near, far, n_candidates, focused, n, every)  # (B,F,K)
    aperture = settings.aperture_module()
    if noise is None:
        noise = noise_model(focused.flatten(1, 2))
    cost = torch.zeros(b, predicted.shape[-1], h, w, dtype=focused.dtype, device=focused.device)
    for j in range(b):
        for p, q in itertools.combinations(range(n), 2):
            pair_errors(focused[j:j + 1, p], focused[j:j + 1, q], aperture, predicted[j, p],
                        predicted[j, q], noise[j:j + 1], out=cost[j:j + 1])
    return cost


class RelativeBlurDepth(CostVolumeDepth):
    """Metric depth from `F >= 2` shots of one view focused at different distances (or at one
    distance through different apertures), no all-in-focus photo needed: `relative_blur_cost`,
    then `CostVolumeDepth.depth_map`. What `estimate_depth` runs without an all-in-focus photo
    (`method="relative-blur"`). The mean of the exposure-matched shots guides the aggregation
    and the smoothing.

    Args: see `CostVolumeDepth`.

    Example:
        >>> s = CameraSettings(0.05, 2.0, [1.5, 4.0], 1e-4)
        >>> out = RelativeBlurDepth()(None, torch.rand(1, 2, 3, 24, 24), s, 1.0, 10.0)
        >>> out["depth"].shape, out["blur"].shape
        (torch.Size([1, 1, 24, 24]), torch.Size([1, 2, 24, 24]))
    """

    #: It reads depth from the focused shots alone.
    needs_image = False

    def forward(self, image: Tensor | None, focused: Tensor, settings: CameraSettings,
                near: float, far: float) -> dict[str, Tensor]:
        """Depth `(B,1,H,W)` metres, confidence `(B,1,H,W)` in [0, 1] and the blur `(B,F,H,W)`
        pixels of each shot at that depth, from the `focused` shots `(B,F,3,H,W)`, linear and
        aligned. `image` is not read: a nearly sharp photo is one more shot with its settings."""
        check_shape("focused", focused, ["B", "F", "3", "H", "W"])
        check_finite("focused", focused)
        settings = settings.batched(focused.shape[0]).to(device=focused.device,
                                                         dtype=focused.dtype)
        reference = focused[:, 0]
        focused = torch.stack([reference] + [match_exposure(reference, focused[:, i])
                                             for i in range(1, focused.shape[1])], 1)
        noise = noise_model(focused.flatten(1, 2))
        guide = focused.mean(1)

        def cost(guide: Tensor, focused: Tensor, every: int = 1) -> Tensor:
            return relative_blur_cost(focused, settings, near, far, self.n_candidates, noise,
                                      every=every)

        largest = settings.largest_coc_px(near, far)
        reach = self.context_px(settings.aperture_module().kernel_size(largest) // 2)
        depth = self.depth_map(cost, guide, [focused], near, far, reach, desc="relative blur")
        blur = thin_lens_blur(settings, 1 / depth)
        return {"depth": depth, "confidence": texture_confidence(guide)
                * depth_edge_confidence(blur), "blur": blur}
