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
from typing import Any

import torch
from torch import Tensor

from optics import Aperture, CameraSettings
from optics.checks import check_finite, check_shape

from .confidence import depth_edge_confidence, texture_confidence
from .cost_volume import CostVolumeDepth
from .fourier_blur import FLOOR_SIGMA_PX, FourierBlur, psf_kernel, with_floor
from .photometry import match_exposure, noise_model, noise_variance
from .thin_lens import WINDOWS, box_filter, candidate_blurs, thin_lens_blur, windowed_errors

#: Side (pixels) of the windows `sweep_channels` sums each candidate's cost over, the widest of
#: `WINDOWS`: on five of the DSLR set's training scenes through a random code at one focus
#: plane, the cheapest candidate of 49-pixel windows orders the depth best (rank correlation
#: 0.57, against 0.53 for 17 and 49-pixel windows together and 0.47 for 25-pixel ones).
SWEEP_WINDOW_PX = max(WINDOWS)


def blur_errors(image: Tensor, focused: Tensor, aperture: Aperture, blurs: Tensor,
                noise: Tensor | None = None, out: Tensor | None = None) -> Tensor:
    """Local squared error `(B,G,H,W)` between the all-in-focus `image` `(B,3,H,W)` blurred by
    `aperture` at each CoC diameter of `blurs` `(G,)` pixels (signed for an `oriented` aperture,
    negative nearer than the focus plane) and one `focused` photo `(B,3,H,W)`
    (exposure-matched to `image`: `match_exposure`), less the noise the blur removes from `image` (`noise`, the
    `(B,2)` coefficients of `noise_model`; by default measured on both photos); both sides
    through a Gaussian of `FLOOR_SIGMA_PX`, summed over channels and averaged over
    `ERROR_WINDOW_PX` windows. With `out` (a `(B,G,H,W)` volume) the errors are added into it
    and it is returned (no second volume in memory).

    Example:
        >>> from optics import Disk
        >>> image = torch.rand(1, 3, 32, 32)
        >>> errors = blur_errors(image, image, Disk(), torch.tensor([0.0, 2.0, 4.0]))
        >>> errors.shape, bool(errors[0, 0].mean() < errors[0, 2].mean())
        (torch.Size([1, 3, 32, 32]), True)
    """
    check_shape("image", image, ["B", "3", "H", "W"])
    check_shape("focused", focused, ["B", "3", "H", "W"])
    largest = float(blurs.abs().max()) if blurs.numel() else 0.0
    half = aperture.kernel_size(largest) // 2
    source = FourierBlur(image, half + math.ceil(4 * FLOOR_SIGMA_PX) + 2)
    target = FourierBlur(focused, source.pad_y)
    floor = with_floor(torch.ones(1, 1, dtype=image.dtype, device=image.device))
    reference = target.apply(target.transfer(floor))
    if noise is None:
        noise = noise_model(torch.cat([image, focused], 1))
    variance = noise_variance(image, noise)

    def error(g: int) -> Tensor:
        kernel = with_floor(psf_kernel(aperture, values[g], image))
        # less the noise variance `image` loses under this kernel: variance * its squares' sum
        return source.squared_error(kernel, reference).sub_(variance[:, 0],
                                                            alpha=float((kernel**2).sum()))

    values = blurs.tolist()
    return windowed_errors(error, len(values), image, out)


def sweep_cost(image: Tensor, focused: Tensor, settings: CameraSettings, near: float,
               far: float, n_candidates: int = 96, noise: Tensor | None = None,
               every: int = 1, aperture: Aperture | None = None) -> Tensor:
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
        aperture: the PSF, the settings' by default (a `Mask` has no spec: pass it here). An
            `oriented` one is rendered at the signed blur, so a code without point symmetry
            tells a depth from its mirror across a single focus plane.
    """
    check_shape("focused", focused, ["B", "F", "3", "H", "W"])
    b, n, _, h, w = focused.shape
    aperture = settings.aperture_module() if aperture is None else aperture
    predicted = candidate_blurs(settings, near, far, n_candidates, image, n, every,
                                signed=aperture.oriented)  # (B,F,K)
    if noise is None:  # every photo: one sensor
        noise = noise_model(torch.cat([image, focused.flatten(1, 2)], 1))
    cost = torch.zeros(b, predicted.shape[-1], h, w, dtype=image.dtype, device=image.device)
    for j in range(b):
        for i in range(n):
            blur_errors(image[j:j + 1], focused[j:j + 1, i], aperture, predicted[j, i],
                        noise[j:j + 1], out=cost[j:j + 1])
    return cost


def sweep_channels(image: Tensor, focused: Tensor, settings: CameraSettings, near: float,
                   far: float, n_candidates: int, aperture: Aperture | None = None) -> Tensor:
    """The sweep's evidence as a network reads it (`TrainConfig.sweep_inputs`): `sweep_cost`
    of `n_candidates` depths between `near` and `far` metres through `aperture` (the
    settings' by default; signed where it is `oriented`), summed over `SWEEP_WINDOW_PX`
    windows, standardised over the candidates at each pixel and negated, `(B,K,H,W)`: high
    where a candidate explains the focused photos around the pixel. No gradient flows
    through it. Where the photos have no texture every candidate costs about the same, and
    the channels stay near 0.

    Example:
        >>> settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
        >>> image, focused = torch.rand(2, 3, 16, 16), torch.rand(2, 2, 3, 16, 16)
        >>> sweep_channels(image, focused, settings, 1.0, 10.0, 8).shape
        torch.Size([2, 8, 16, 16])
    """
    with torch.no_grad():
        cost = box_filter(sweep_cost(image.detach(), focused.detach(), settings, near, far,
                                     n_candidates, aperture=aperture), SWEEP_WINDOW_PX)
        spread = cost.std(1, keepdim=True)
        floor = 0.1 * spread.mean((2, 3), keepdim=True) + torch.finfo(cost.dtype).tiny
        return (cost.mean(1, keepdim=True) - cost) / (spread + floor)


class SweepDepth(CostVolumeDepth):
    """Metric depth from an all-in-focus photo and `F >= 1` focused photos of any camera, by a
    sweep over depth (`sweep_cost`, then `CostVolumeDepth.depth_map`). No weights: it is what
    `estimate_depth` runs when an all-in-focus photo is given (`method="sweep"`). Called like
    every method of `estimate_depth`: `(image, focused, settings, near, far)`.

    Photos larger in pixels than one tile with its context are aggregated in tiles (the
    aggregation of a whole 1.5-megapixel photo would take gigabytes), each with context around
    it, from one cost volume of the whole photo (`CostVolumeDepth.depth_map`): exactly the
    untiled result with `aggregation="windows"`; with the semi-global aggregation every tile
    uses the whole photo's cost scale and at 741x500 (tile 200) 0.5 % of the pixels differ
    from the untiled depth by more than 1 % (at most 2.2 %).

    Args:
        aperture: the PSF of the photos, the settings' spec by default: a coded aperture
            (`optics.Mask`) has no spec. Through an `oriented` code the sweep places a depth on
            its side of a single focus plane, which no point-symmetric aperture can (a thin
            lens turns the code by 180 degrees across the plane). Give `estimate_depth`
            `align=False` for photos already registered: a code's PSF is off-centre by a shift
            that changes sign across the plane, and alignment would take it away.
        options: see `CostVolumeDepth`.

    Example:
        >>> from optics import CameraSettings
        >>> settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
        >>> out = SweepDepth()(torch.rand(1, 3, 24, 24), torch.rand(1, 2, 3, 24, 24), settings,
        ...                    1.0, 10.0)
        >>> out["depth"].shape, out["confidence"].shape, out["blur"].shape
        (torch.Size([1, 1, 24, 24]), torch.Size([1, 1, 24, 24]), torch.Size([1, 2, 24, 24]))
    """

    #: It needs an all-in-focus photo.
    needs_image = True

    def __init__(self, aperture: Aperture | None = None, **options: Any):
        super().__init__(**options)
        self.aperture = aperture

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

        aperture = settings.aperture_module() if self.aperture is None else self.aperture

        def cost(image: Tensor, focused: Tensor, every: int = 1) -> Tensor:
            return sweep_cost(image, focused, settings, near, far, self.n_candidates, noise,
                              every=every, aperture=aperture)

        largest = settings.largest_coc_px(near, far)
        reach = self.context_px(aperture.kernel_size(largest) // 2)
        depth = self.depth_map(cost, image, [focused], near, far, reach)
        blur = thin_lens_blur(settings, 1 / depth)
        return {"depth": depth, "confidence": texture_confidence(image)
                * depth_edge_confidence(blur), "blur": blur}
