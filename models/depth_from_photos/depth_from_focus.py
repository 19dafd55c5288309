"""Depth from focus: the classic baseline of focal stacks (three or more shots).

Each pixel is sharpest in the shot focused nearest to its depth. `focus_measures` gives every
shot's local sharpness (the energy of its Laplacian after a small Gaussian, over a window); per
pixel the sharpest shot is found, and a parabola through the logarithms of its measure and its
neighbours' (a Gaussian fitted to the focus curve) places the peak between shots. The peak's
position maps to metres through the focus distances, linearly in inverse depth between the shots
(the thin lens's blur is linear in inverse depth). It needs neither the aperture nor the pixel
pitch, only the focus distances, and it cannot place a depth beyond the nearest or the farthest
focus plane.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from optics import CameraSettings
from optics.checks import check_finite, check_shape

from .confidence import band_energy, depth_edge_confidence, texture_confidence
from .cost_volume import CONFIDENCE_FLOOR, MEDIAN_PX, SMOOTHING_SIGMA, SMOOTHING_STRENGTH
from .photometry import match_exposure
from .rules import refuse_broken
from .smoothing import edge_aware_smooth
from .thin_lens import median_filter, thin_lens_blur

#: Gaussian (sigma, pixels) before the Laplacian of the focus measure, and the window (pixels)
#: its energy is averaged over.
MEASURE_SIGMA_PX = 0.5
MEASURE_WINDOW_PX = 9


def focus_measures(shots: Tensor, window: int = MEASURE_WINDOW_PX) -> Tensor:
    """Local sharpness `(B,F,H,W)` of each shot of `shots` `(B,F,3,H,W)` (linear): the energy
    of the Laplacian of its grey image after a Gaussian of `MEASURE_SIGMA_PX`, averaged over
    `window x window` pixels.

    Example:
        >>> sharp = torch.rand(1, 1, 3, 32, 32)
        >>> from kornia.filters import box_blur
        >>> blurred = box_blur(sharp[:, 0], (5, 5))[:, None]
        >>> m = focus_measures(torch.cat([sharp, blurred], 1))
        >>> bool((m[:, 0] > m[:, 1]).float().mean() > 0.9)
        True
    """
    check_shape("shots", shots, ["B", "F", "3", "H", "W"])
    gray = shots.mean(2).flatten(0, 1)[:, None]
    energy = band_energy(gray, MEASURE_SIGMA_PX, window)
    return energy.reshape(shots.shape[0], shots.shape[1], *shots.shape[-2:])


def focus_peak(measures: Tensor, inverse_focus: Tensor) -> Tensor:
    """Inverse depth `(B,1,H,W)` (1/metres) at the peak of the focus curve of each pixel.

    Args:
        measures: `(B,F,H,W)` focus measures, shots in any order.
        inverse_focus: `(B,F)` inverse focus distances of the shots, 1/metres.

    The shots are put in order of inverse focus distance; the sharpest shot's log measure and its
    neighbours' give a parabola whose vertex (within half a shot either side) is interpolated
    linearly between the neighbouring inverse focus distances. At the first and the last shot the
    depth is that shot's focus distance.

    Example:
        >>> x = torch.tensor([[1 / 1.0, 1 / 2.0, 1 / 4.0]])  # focused at 1, 2 and 4 m
        >>> curve = torch.tensor([1.0, 4.0, 1.0]).reshape(1, 3, 1, 1)  # peak at the middle shot
        >>> round(1 / focus_peak(curve, x).item(), 3)
        2.0
    """
    check_shape("measures", measures, ["B", "F", "H", "W"])
    n = measures.shape[1]
    order = inverse_focus.argsort(1)
    x = inverse_focus.gather(1, order)[:, :, None, None]  # ascending inverse focus
    log = measures.gather(1, order[:, :, None, None].expand_as(measures)).clamp_min(1e-12).log()
    best = log.argmax(1, keepdim=True)
    lo_i, hi_i = (best - 1).clamp(0, n - 1), (best + 1).clamp(0, n - 1)
    lo, mid, hi = log.gather(1, lo_i), log.gather(1, best), log.gather(1, hi_i)
    curvature = (lo + hi - 2 * mid).clamp_max(-torch.finfo(log.dtype).tiny)
    offset = (0.5 * (lo - hi) / curvature).clamp(-0.5, 0.5)
    inside = (best > 0) & (best < n - 1)
    offset = torch.where(inside, offset, torch.zeros_like(offset))
    x = x.expand(-1, -1, *measures.shape[-2:])
    at = x.gather(1, best)
    step = torch.where(offset >= 0, x.gather(1, hi_i) - at, at - x.gather(1, lo_i))
    return at + offset * step


class DepthFromFocus(nn.Module):
    """Metric depth from a focal stack of `F >= 3` shots: `focus_measures`, then `focus_peak`,
    a median filter and the edge-aware smoothing of the sweep. Called like every method of
    `estimate_depth` (`method="focus"`); `image` is not read.

    Args:
        window: side (pixels) of the focus measure's window.
        smoothing: strength of the edge-aware smoothing of the inverse depth (0: none).
        progress: unused (the method is fast); accepted like every method's.

    Example:
        >>> s = CameraSettings(0.05, 2.0, [1.5, 3.0, 6.0], 1e-4)
        >>> out = DepthFromFocus()(None, torch.rand(1, 3, 3, 24, 24), s, 1.0, 10.0)
        >>> out["depth"].shape, out["blur"].shape
        (torch.Size([1, 1, 24, 24]), torch.Size([1, 3, 24, 24]))
    """

    #: It reads depth from the focused shots alone.
    needs_image = False
    #: Largest blur (pixels) at the working resolution: as the sweep's.
    max_coc_px = 20.0

    def __init__(self, window: int = MEASURE_WINDOW_PX, smoothing: float = SMOOTHING_STRENGTH,
                 progress: bool = False):
        super().__init__()
        refuse_broken([
            (isinstance(window, bool) or not isinstance(window, int) or window < 1,
             lambda: f"window must be a positive number of pixels, got {window!r}"),
            (not smoothing >= 0, lambda: f"smoothing must be >= 0, got {smoothing!r}")])
        self.window, self.smoothing, self.progress = window, float(smoothing), progress

    def forward(self, image: Tensor | None, focused: Tensor, settings: CameraSettings,
                near: float, far: float) -> dict[str, Tensor]:
        """Depth `(B,1,H,W)` metres within `[near, far]`, confidence `(B,1,H,W)` and the blur
        `(B,F,H,W)` pixels of each shot at that depth, from `focused` `(B,F,3,H,W)`."""
        check_shape("focused", focused, ["B", "F", "3", "H", "W"])
        check_finite("focused", focused)
        if focused.shape[1] < 3:
            raise ValueError(f"depth from focus needs a stack of 3 or more shots, got "
                             f"{focused.shape[1]}; two shots: use the relative blur")
        settings = settings.batched(focused.shape[0]).to(device=focused.device,
                                                         dtype=focused.dtype)
        reference = focused[:, 0]
        shots = torch.stack([reference] + [match_exposure(reference, focused[:, i])
                                           for i in range(1, focused.shape[1])], 1)
        inverse = focus_peak(focus_measures(shots, self.window), 1 / settings.focus_distance)
        inverse = median_filter(inverse.clamp(1 / far, 1 / near), MEDIAN_PX)
        guide = shots.mean(1)
        texture = texture_confidence(guide)
        if self.smoothing > 0:
            weight = median_filter(texture, MEDIAN_PX) + CONFIDENCE_FLOOR
            inverse = edge_aware_smooth(inverse, weight, guide, self.smoothing, SMOOTHING_SIGMA)
        depth = 1 / inverse.clamp(1 / far, 1 / near)
        blur = thin_lens_blur(settings, 1 / depth)
        return {"depth": depth, "confidence": texture * depth_edge_confidence(blur),
                "blur": blur}
