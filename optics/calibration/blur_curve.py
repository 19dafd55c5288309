r"""Calibrating from photos with depth maps: the measured blur-versus-depth curve and its fit.

A folder of real photo pairs with depth (a sharp reference, e.g. an f/8 shot, and the defocused
shot of the same view, e.g. at f/2.8, with a registered depth map) holds every depth at once.
`measure_blur_curve` sorts the pixels of all pairs into depth bins and finds, per bin, the
blur of the aperture's PSF that turns the reference into the defocused photo best (a grid of
CoC diameters, each an FFT blur of the whole reference, times the pair's exposure ratio per
colour channel (the ratio of the means: a blur keeps the mean); sub-grid by a parabola through
the three lowest errors).
`fit_blur_curve` fits the thin lens with a floor to it:

$$b(D)^2 = \left(A \left|1 - \frac{D_f}{D}\right|\right)^2 + b_0^2$$

with `A` the CoC at infinity and `b_0` the *floor*: the blur the defocused photo has even in
focus relative to the reference (JPEG compression, demosaicing, a lens softer wide open, the
residual of the alignment). Without the floor a least-squares fit pushes the focus plane away
from every pixel, to blur them all. The floor adds in quadrature exactly for Gaussians and
approximately for disks.

This reads every depth of every pair in one pass, so it is fast (seconds per pair) and has no
local minima: the focus distance is searched on a grid, `A^2` and `b_0^2` solved by
non-negative least squares. `calibrate_from_depth` turns the fit into a camera.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

import torch
from torch import Tensor

from ..aperture_spec import DEFAULT_APERTURE, aperture_spec, parse_aperture
from ..camera import CameraSettings
from ..checks import require
from ..progress import progress_bar
from .measure import ConstantBlur, crop
from .pair import CalibrationPair
from .problem import pair_list

#: Depth bin edges (metres) of `measure_blur_curve` by default: 40 bins even in inverse depth
#: between 0.3 m and 30 m (the thin lens's blur is linear in inverse depth).
DEFAULT_EDGES = 1 / torch.linspace(1 / 0.3, 1 / 30.0, 41, dtype=torch.float64)


@dataclass
class BlurCurve:
    """The blur of the defocused photos by depth, as `measure_blur_curve` measured it.

    Attributes:
        edges: `(K+1,)` depth bin edges, metres, increasing.
        candidates_px: `(M,)` CoC diameters (pixels) of the aperture's PSF that were tried.
        errors: `(K, M)` mean squared residual of each bin for each candidate.
        pixels: `(K,)` pixels in each bin (over all pairs, the border left out).
        gains: `(P, C)` exposure gain of each pair per colour channel (defocused / reference).
        aperture: the PSF's spec (`optics.aperture_spec`).
        min_pixels: bins with fewer pixels are left out of `best_px` (NaN).
    """

    edges: Tensor
    candidates_px: Tensor
    errors: Tensor
    pixels: Tensor
    gains: Tensor
    aperture: str
    min_pixels: int = 2000

    @property
    def centres(self) -> Tensor:
        """`(K,)` depth of each bin, metres (the harmonic mean of its edges: its middle in
        inverse depth)."""
        return 2 / (1 / self.edges[:-1] + 1 / self.edges[1:])

    def best_px(self) -> Tensor:
        """`(K,)` the measured blur (CoC diameter, pixels) of each bin; NaN where a bin has fewer
        than `min_pixels` pixels."""
        k = self.errors.argmin(1)
        best = self.candidates_px[k].clone()
        step = float(self.candidates_px[1] - self.candidates_px[0])
        inner = (k > 0) & (k < len(self.candidates_px) - 1)
        rows = torch.arange(len(k))[inner]
        e0, e1, e2 = (self.errors[rows, k[inner] + d] for d in (-1, 0, 1))
        curvature = (e0 - 2 * e1 + e2).clamp_min(1e-30)
        best[inner] += step * (0.5 * (e0 - e2) / curvature).clamp(-0.5, 0.5)
        best[self.pixels < self.min_pixels] = float("nan")
        return best


def measure_blur_curve(
    pairs: Sequence[CalibrationPair], aperture: str = DEFAULT_APERTURE,
    edges: Tensor | None = None, max_coc_px: float = 12.0, step_px: float = 0.25,
    margin_px: int | None = None, min_pixels: int = 2000, progress: bool = False,
) -> BlurCurve:
    """Measure the blur of the defocused photos by depth over pairs with depth maps.

    Args:
        pairs: `CalibrationPair`s whose `depth` is a map (metres); their photos already aligned
            (`optics.align_shots`: a shift reads as blur). Each pair's exposure ratio per colour
            channel (the ratio of the photos' means) is taken out.
        aperture: the PSF's spec (`"gaussian:0.5"`: sigma = CoC / 2; `"disk"`, `"polygon:6"`).
        edges: depth bin edges, metres (default `DEFAULT_EDGES`).
        max_coc_px: the largest CoC diameter tried, pixels.
        step_px: the grid step of the CoC diameters, pixels.
        margin_px: border left out (default: half the largest PSF plus 2).
        min_pixels: bins with fewer pixels are reported as NaN by `BlurCurve.best_px`.
        progress: show a progress bar over the pairs.

    Returns:
        the `BlurCurve`.

    Raises:
        ValueError: a pair without a depth map, a bad grid, or a margin that leaves nothing.

    Example:
        >>> from optics import Camera, ThinLens, Sensor, Gaussian
        >>> camera = Camera(ThinLens(0.035, 2.8, 1.7), Sensor(5.6e-5), Gaussian(0.5))
        >>> torch.manual_seed(0)  # doctest: +ELLIPSIS
        <torch._C.Generator object at ...>
        >>> sharp = torch.rand(1, 3, 64, 64, dtype=torch.float64)
        >>> depth = torch.full((1, 1, 64, 64), 5.0, dtype=torch.float64)
        >>> curve = measure_blur_curve([CalibrationPair(sharp, camera.render(sharp, depth), depth)],
        ...                            min_pixels=100)
        >>> measured = curve.best_px()[~curve.best_px().isnan()]
        >>> round(float(measured[0]), 1), round(float(camera.coc_px(torch.tensor([5.0]))[0]), 1)
        (3.1, 3.1)
    """
    pairs = pair_list(pairs)
    if not (math.isfinite(max_coc_px) and max_coc_px > 0 and 0 < step_px < max_coc_px):
        raise ValueError(f"need 0 < step_px < max_coc_px (pixels), got step_px={step_px!r}, "
                         f"max_coc_px={max_coc_px!r}")
    edges = (DEFAULT_EDGES if edges is None else torch.as_tensor(edges)).to(torch.float64)
    if edges.ndim != 1 or len(edges) < 2 or not bool((edges[1:] > edges[:-1]).all()):
        raise ValueError(f"edges must be increasing depths in metres, got {edges.tolist()}")
    psf = parse_aperture(aperture)
    candidates = torch.arange(0.0, max_coc_px + 1e-9, step_px, dtype=torch.float64)
    pad = int(math.ceil(max_coc_px / 2)) + 2
    margin = pad if margin_px is None else int(margin_px)
    errors = torch.zeros(len(edges) - 1, len(candidates), dtype=torch.float64)
    pixels = torch.zeros(len(edges) - 1, dtype=torch.float64)
    gains = []
    for i, pair in enumerate(progress_bar(pairs, desc="blur by depth", disable=not progress)):
        if not isinstance(pair.depth, Tensor):
            raise ValueError(f"pairs[{i}] ({pair.name or 'unnamed'}) has one distance, not a depth "
                             "map: measure_blur_curve reads every depth of a map")
        sharp = pair.sharp.to(torch.float64)
        target = crop(pair.blurred.to(torch.float64), margin)[0]
        depth = crop(pair.depth_map(sharp), margin)[0, 0]
        if target.numel() == 0:
            raise ValueError(f"margin_px={margin} leaves no pixels of a {tuple(sharp.shape[-2:])} "
                             "image")
        label = (torch.bucketize(depth.contiguous(), edges) - 1).reshape(-1)
        inside = (label >= 0) & (label < len(edges) - 1)
        label = label.clamp(0, len(edges) - 2)
        pixels += torch.bincount(label[inside], minlength=len(edges) - 1).to(pixels)
        blur = ConstantBlur(sharp, pad)
        # the exposure ratio of the pair (a blur keeps the mean): one gain for every candidate
        gain = (target.mean((1, 2)) / crop(sharp, margin)[0].mean((1, 2)).clamp_min(1e-12))
        for j, coc in enumerate(candidates):
            rendered = crop(blur(psf, float(coc)) if coc > 0 else sharp, margin)[0]
            residual = (target - gain[:, None, None] * rendered).pow(2).sum(0).reshape(-1)
            errors[:, j] += torch.bincount(label[inside], residual[inside],
                                           minlength=len(edges) - 1)
        gains.append(gain)
    errors /= pixels.clamp_min(1)[:, None]
    return BlurCurve(edges, candidates, errors, pixels, torch.stack(gains), aperture_spec(psf),
                     min_pixels)


@dataclass
class BlurCurveFit:
    """`b(D) = sqrt((A |1 - D_f / D|)^2 + b_0^2)` fitted to a `BlurCurve`.

    Attributes:
        coc_at_infinity_px: `A`, the CoC diameter at infinite depth, pixels.
        focus_distance: `D_f`, metres.
        floor_px: `b_0`, the blur in focus, pixels (CoC diameter of the same PSF).
        rmse_px: root mean square misfit over the bins (weighted by their pixels), pixels.
    """

    coc_at_infinity_px: float
    focus_distance: float
    floor_px: float
    rmse_px: float

    def blur_px(self, depth: Tensor) -> Tensor:
        """The fitted blur (pixels) at `depth` (metres)."""
        u = (1 - self.focus_distance / depth).abs()
        return ((self.coc_at_infinity_px * u) ** 2 + self.floor_px ** 2).sqrt()


def fit_blur_curve(curve: BlurCurve, focus_distance: float | None = None) -> BlurCurveFit:
    """Fit the thin lens with a floor to a measured `BlurCurve` (bins weighted by pixels).

    Args:
        curve: the measured curve.
        focus_distance: `D_f` in metres if known; else searched (logarithmic grid over the bins'
            depths, a quarter of the nearest to four times the farthest).

    Raises:
        ValueError: fewer than three bins measured (two with `focus_distance` given).

    Example:
        >>> edges = torch.tensor([1.0, 1.5, 2.0, 3.0, 5.0, 9.0], dtype=torch.float64)
        >>> centres = 2 / (1 / edges[:-1] + 1 / edges[1:])
        >>> blur = ((4 * (1 - 2.0 / centres)) ** 2 + 0.5 ** 2).sqrt()
        >>> candidates = torch.arange(0, 8, 0.01, dtype=torch.float64)
        >>> curve = BlurCurve(edges, candidates, (candidates - blur[:, None]) ** 2,
        ...                   torch.full((5,), 1e4), torch.ones(1, 3), "disk")
        >>> fit = fit_blur_curve(curve)
        >>> round(fit.coc_at_infinity_px, 2), round(fit.focus_distance, 2), round(fit.floor_px, 2)
        (4.0, 2.0, 0.5)
    """
    best = curve.best_px()
    ok = ~best.isnan()
    needed = 2 if focus_distance is not None else 3
    if int(ok.sum()) < needed:
        raise ValueError(f"the photos measure blur in {int(ok.sum())} depth bin(s), need {needed} "
                         "or more: give pairs with more depths (or more pixels per depth)")
    depth, blur, weight = curve.centres[ok], best[ok], curve.pixels[ok]
    if focus_distance is None:
        grid = torch.logspace(math.log10(float(depth.min()) / 4),
                              math.log10(float(depth.max()) * 4), 2001, dtype=torch.float64)
    else:
        grid = torch.tensor([float(focus_distance)], dtype=torch.float64)
    best_fit = None
    for focus in grid:
        u2 = (1 - focus / depth) ** 2
        a2, floor2 = _nonnegative_two(u2, blur ** 2, weight)
        model = (a2 * u2 + floor2).sqrt()
        error = float((weight * (model - blur) ** 2).sum() / weight.sum())
        if best_fit is None or error < best_fit[0]:
            best_fit = (error, math.sqrt(a2), float(focus), math.sqrt(floor2))
    error, a, focus, floor = best_fit  # type: ignore[misc]
    return BlurCurveFit(a, focus, floor, math.sqrt(error))


def _nonnegative_two(x: Tensor, y: Tensor, w: Tensor) -> tuple[float, float]:
    """`(a, b) >= 0` minimising `sum w (a x + b - y)^2`."""
    sw, sx, sy = w.sum(), (w * x).sum(), (w * y).sum()
    sxx, sxy = (w * x * x).sum(), (w * x * y).sum()
    det = sw * sxx - sx * sx
    if det > 1e-30:
        a = float((sw * sxy - sx * sy) / det)
        b = float((sy - a * sx) / sw)
        if a >= 0 and b >= 0:
            return a, b
    options = [(max(float(sxy / sxx.clamp_min(1e-30)), 0.0), 0.0), (0.0, max(float(sy / sw), 0.0))]
    return min(options, key=lambda ab: float((w * (ab[0] * x + ab[1] - y) ** 2).sum()))


@dataclass
class DepthCalibration:
    """A camera fitted from photo pairs with depth (`calibrate_from_depth`).

    Attributes:
        settings: `(1,)` settings of the defocused shots (focal length and f-number as given,
            focus distance and effective pixel pitch fitted, the PSF's spec).
        floor_px: the blur (CoC diameter of the PSF, pixels) the defocused photos have in focus
            relative to the references: blur the reference by it before comparing.
        reference_f_number: the references' f-number (their own blur was taken out), or None
            (references taken as sharp).
        exposure_gain: `(C,)` median exposure gain per colour channel, defocused / reference.
        curve: the measured `BlurCurve`.
        fit: the `BlurCurveFit` of the relative blur (reference to defocused photo).
    """

    settings: CameraSettings
    floor_px: float
    reference_f_number: float | None
    exposure_gain: list[float]
    curve: BlurCurve = field(repr=False)
    fit: BlurCurveFit

    def extras(self) -> dict[str, Any]:
        """The values a camera JSON carries beside the settings."""
        extra: dict[str, Any] = {"focus_floor_px": round(self.floor_px, 4),
                                 "exposure_gain": [round(g, 4) for g in self.exposure_gain],
                                 "fit_rmse_px": round(self.fit.rmse_px, 4)}
        if self.reference_f_number is not None:
            extra["reference_f_number"] = self.reference_f_number
        return extra

    def to_json(self, path: str | PathLike) -> None:
        """Write the camera JSON (`CameraSettings.from_json` reads it; the extras ride along)."""
        self.settings.to_json(path, **self.extras())


def calibrate_from_depth(
    pairs: Sequence[CalibrationPair], focal_length: float, f_number: float,
    aperture: str = DEFAULT_APERTURE, reference_f_number: float | None = None,
    focus_distance: float | None = None, **measure: Any,
) -> DepthCalibration:
    """Fit the camera of the defocused shots from pairs with depth maps.

    The relative blur from each reference to its defocused photo is measured by depth
    (`measure_blur_curve`) and fitted (`fit_blur_curve`). A reference shot at
    `reference_f_number` has its own blur, `N / N_ref` of the defocused one; the relative blur
    is `sqrt(1 - (N / N_ref)^2)` of the defocused one (exact for Gaussians), which is taken out
    here, so the settings describe the real lens. The pixel pitch follows from the CoC at
    infinity: `A = f^2 / (N (D_f - f) p)`. Only the product of the pitch, the f-number and the
    PSF's scale shows in the blur: the f-number and the PSF are given, the pitch is fitted.

    Args:
        pairs: aligned pairs with depth maps (metres).
        focal_length: metres.
        f_number: the defocused shots' f-number.
        aperture: the PSF's spec; `"gaussian:0.5"` (sigma = CoC / 2) or `"disk"`, ...
        reference_f_number: the references' f-number, or None for sharp references.
        focus_distance: metres, if known; else fitted.
        **measure: keyword arguments of `measure_blur_curve`.

    Example:
        >>> from optics import Camera, ThinLens, Sensor, Gaussian
        >>> torch.manual_seed(0)  # doctest: +ELLIPSIS
        <torch._C.Generator object at ...>
        >>> camera = Camera(ThinLens(0.035, 2.8, 1.7), Sensor(5.6e-5), Gaussian(0.5))
        >>> sharp = torch.rand(1, 3, 96, 96, dtype=torch.float64)
        >>> pairs = [CalibrationPair(sharp, camera.render(sharp, torch.full((1, 1, 96, 96), d,
        ...          dtype=torch.float64)), torch.full((1, 1, 96, 96), d, dtype=torch.float64))
        ...          for d in (0.8, 1.1, 3.0, 6.0)]
        >>> fit = calibrate_from_depth(pairs, 0.035, 2.8, min_pixels=100)
        >>> fit.fit.focus_distance = round(fit.fit.focus_distance, 1)
        >>> abs(float(fit.settings.pixel_pitch[0]) / 5.6e-5 - 1) < 0.05, fit.fit.focus_distance
        (True, 1.7)
    """
    for name, value in (("focal_length", focal_length), ("f_number", f_number)):
        require(name, torch.tensor(float(value)), "positive")
    if reference_f_number is not None and not reference_f_number > f_number:
        raise ValueError(f"reference_f_number must exceed f_number ({f_number}) to be the sharper "
                         f"shot, got {reference_f_number!r}")
    curve = measure_blur_curve(pairs, aperture, **measure)
    fit = fit_blur_curve(curve, focus_distance)
    relative = 1.0 if reference_f_number is None else math.sqrt(
        1 - (f_number / reference_f_number) ** 2)
    coc_at_infinity = fit.coc_at_infinity_px / relative
    if not coc_at_infinity > 0:
        raise ValueError("the photos show no blur that grows away from a focus plane: every "
                         f"depth bin measured about {fit.floor_px:.2f} px; nothing to fit")
    if not fit.focus_distance > focal_length:
        raise ValueError(f"the fitted focus distance {fit.focus_distance:.3g} m is not beyond the "
                         f"focal length {focal_length} m: the pairs do not fit a thin lens")
    pitch = focal_length ** 2 / (f_number * (fit.focus_distance - focal_length) * coc_at_infinity)
    settings = CameraSettings(focal_length, f_number, [fit.focus_distance], pitch,
                              aperture=curve.aperture)
    gains = curve.gains.median(0).values.tolist()
    return DepthCalibration(settings, fit.floor_px, reference_f_number, gains, curve, fit)
