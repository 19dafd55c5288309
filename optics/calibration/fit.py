r"""Calibrating a camera from pairs of photos: a sharp reference and a defocused shot.

Each `CalibrationPair` holds a sharp reference image, the defocused photo of the same view and
the depth of what it shows (a planar target at a known distance, or a depth map), in metres. All
defocused photos share one camera setting, the one being calibrated. `calibrate` fits the
parameters of that camera by gradient descent through the renderer, so that rendering each
reference with the camera gives its defocused photo:

$$\min_\theta \sum_i \| B_i - g_i \, \mathrm{render}(S_i, \mathrm{CoC}_\theta(D_i)) \|^2$$

over the interior of the images (a margin as wide as the largest PSF is left out, since a real
photo's border blurs in content from outside the frame), with `g_i` the least-squares exposure
gain of pair `i` (solved in closed form at every step). Parameters are fitted in log space
(`focus_distance - focal_length` too, so it stays beyond the focal length): a coarse start from
per-pair blur estimates and a thin-lens curve fit, then Adam, then L-BFGS.

Identifiability: the blur in pixels of a thin lens is
`scale * f^2 |D - D_f| / (N D (D_f - f) p)`: the PSF scale (Gaussian `sigma` per CoC), the
f-number `N` and the pixel pitch `p` (and nearly the focal length `f`) enter as one product.
At most one of `f_number`, `pixel_pitch` and `psf_scale` can be fitted; `calibrate` refuses
more. The focal length is always given (e.g. from the raw file's metadata).

Uncertainties are one standard deviation from the Gauss-Newton approximation of the Hessian
(`sigma^2 (J^T J)^-1`, with `J` the Jacobian of the residuals by central differences and
`sigma^2` the residual variance). Neighbouring pixels of demosaiced photos are correlated, so
treat them as a lower bound.

Photos with depth maps (a folder of reference / defocused pairs with registered depth) are
calibrated by `calibrate_from_depth` instead: the blur measured in depth bins over all pairs and
the thin lens with a floor fitted to it (`optics.calibration.blur_curve`).

The steps live in the other modules of `optics.calibration` (one job each); the figure is
`optics.plotting.plot_calibration`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import torch

from ..aperture_spec import LENS_APERTURE
from .model import ResidualModel
from .optimise import Fit, gauss_newton, optimise
from .pair import CalibrationPair
from .problem import Problem
from .result import CalibrationResult, fitted_settings
from .start import Start, initial_guess, margin_and_pad

__all__ = ["CalibrationError", "calibrate"]


class CalibrationError(ValueError):
    """The photos do not determine the fitted parameters (an unidentifiable fit).

    Attributes:
        result: the `CalibrationResult` reached anyway, to inspect (never to save: its
            uncertainty is infinite or NaN).
    """

    def __init__(self, message: str, result: CalibrationResult):
        super().__init__(message)
        self.result = result


def calibrate(
    pairs: Sequence[CalibrationPair], focal_length: float, aperture: str = LENS_APERTURE,
    f_number: float | None = None, focus_distance: float | None = None,
    pixel_pitch: float | None = None, psf_scale: float | None = None,
    initial: Mapping[str, float] | None = None, fit_gain: bool = True,
    margin_px: int | None = None, max_coc_px: float = 24.0, adam_steps: int = 60,
    lbfgs_steps: int = 40, render_kwargs: Mapping[str, Any] | None = None,
    use_renderer: bool = False, progress: bool = False,
) -> CalibrationResult:
    """Fit the camera that turns each pair's sharp reference into its defocused photo.

    A parameter given a value is fixed to it (and stays exactly that); a parameter left `None`
    is fitted. Lengths are in metres; `pixel_pitch` is the *effective* pitch of the images
    (sensor pitch x binning).

    Args:
        pairs: one or more `CalibrationPair`; at least two distinct depths when the focus
            distance is fitted together with another parameter (three or more recommended).
        focal_length: focal length in metres (known, e.g. from the metadata).
        aperture: PSF shape as an aperture spec (`optics.aperture_spec`): `"disk"`, `"gaussian"`
            (its scale fitted unless `psf_scale` is given), `"gaussian:S"` (scale fixed to `S`)
            or `"polygon:N"` / `"polygon:N:R"` (`N` blades rotated by `R` radians).
        f_number: f-number, or `None` to fit it.
        focus_distance: focus distance in metres, or `None` to fit it.
        pixel_pitch: effective pixel pitch in metres, or `None` to fit it.
        psf_scale: Gaussian `sigma` per CoC diameter, or `None` to fit it (Gaussian only: the
            disk and polygons have no scale, their size is the CoC).
        initial: starting values of fitted parameters (by default from per-pair blur estimates).
        fit_gain: solve an exposure gain per pair (else the gain is 1).
        margin_px: border left out of the loss, in pixels (by default the half width of the PSF
            of the largest measured blur, plus 2).
        max_coc_px: largest CoC diameter (pixels) searched by the per-pair estimates.
        adam_steps: Adam iterations (learning rate 0.05 in log space).
        lbfgs_steps: L-BFGS iterations after Adam.
        render_kwargs: passed to `optics.Camera.render` (`mode`, ...).
        use_renderer: render planar targets with `optics.Camera.render` too. By default a
            pair whose depth is one distance is rendered as the spatially invariant blur the
            renderer reduces to for a constant CoC (exact in the interior, much faster);
            pairs with depth maps always go through the renderer.
        progress: show a tqdm progress bar.

    Returns:
        the `CalibrationResult`; its `settings` are the fitted camera.

    Raises:
        ValueError: for no pairs, a PSF spec calibration cannot fit, nothing to fit, more than
            one of `f_number`, `pixel_pitch`, `psf_scale` to fit (only their product shows in
            the blur), `psf_scale` for a disk or polygon, a non-positive value, fewer distinct
            depths than `optics.calibration.problem.needed_distances` (one per fitted
            parameter, two at least with the focus distance), no measurable blur in any pair,
            constant, NaN or infinite images, or a margin that leaves no pixels. Each message
            says what to shoot or give instead.
        CalibrationError: (a `ValueError`) if the fit leaves a fitted parameter undetermined
            (singular Hessian: infinite or NaN uncertainty); its `result` holds the fit.

    Example:
        >>> torch.manual_seed(0)  # doctest: +ELLIPSIS
        <torch._C.Generator object at ...>
        >>> truth = Camera(ThinLens(0.025, 4.0, 2.0), Sensor(1e-5), Disk())
        >>> sharp = torch.rand(1, 3, 40, 40, dtype=torch.float64)
        >>> pairs = [CalibrationPair(sharp, truth.render(sharp, torch.full((1, 1, 40, 40), d,
        ...          dtype=torch.float64)), d) for d in (1.2, 1.5, 4.0)]
        >>> fit = calibrate(pairs, focal_length=0.025, pixel_pitch=1e-5, adam_steps=20)
        >>> round(fit.values["focus_distance"], 2), round(fit.values["f_number"], 2)
        (2.0, 4.0)
        >>> fit.settings.aperture, tuple(fit.settings.shape)
        ('disk', (1,))
    """
    problem = Problem.build(
        pairs, aperture, fit_gain, focal_length=focal_length, f_number=f_number,
        focus_distance=focus_distance, pixel_pitch=pixel_pitch, psf_scale=psf_scale,
    )
    start = initial_guess(problem, initial, max_coc_px)
    margin, pad = margin_and_pad(problem, start, margin_px)
    model = ResidualModel(problem, start.values, margin, pad, render_kwargs, use_renderer)
    theta = optimise(model.loss, model.theta0(), adam_steps, lbfgs_steps, progress)
    fit = gauss_newton(model, theta)
    result = _result(problem, start, model, theta, fit)
    _refuse_undetermined(problem, fit, result)
    return result


def _refuse_undetermined(problem: Problem, fit: Fit, result: CalibrationResult) -> None:
    """Raise `CalibrationError` if the fit leaves a fitted parameter undetermined."""
    bad = [name for name, sd in result.uncertainty.items() if not math.isfinite(sd)]
    bad += [name for name in problem.fitted
            if not math.isfinite(result.values[name]) and name not in bad]
    if fit.singular or bad:
        raise CalibrationError(
            f"the photos do not determine {bad or list(problem.fitted)} (singular Hessian: "
            f"uncertainty {', '.join(f'{k} {v:.3g}' for k, v in result.uncertainty.items())}); "
            f"no calibration is returned. Shoot targets at more distinct distances, nearer and "
            "farther than the focus plane, with clearly visible blur, or fix more parameters",
            result,
        )


def _result(problem: Problem, start: Start, model: ResidualModel, theta: torch.Tensor,
            fit: Fit) -> CalibrationResult:
    """Gather the fitted values, their standard deviations and the per-pair details."""
    values = model.fitted_values(theta)
    uncertainty = {}
    for i, name in enumerate(problem.fitted):
        sd_log = float(fit.covariance[i, i].clamp_min(0).sqrt())
        uncertainty[name] = model.space.spread(name, values[name]) * sd_log
    camera = model.camera(theta)
    with torch.no_grad():
        coc_fit = [float(camera.coc_px(torch.tensor([d], dtype=torch.float64))[0])
                   for d in problem.depths]
    return CalibrationResult(
        settings=fitted_settings(values, problem.psf),
        psf_scale=values["psf_scale"],
        uncertainty=uncertainty,
        fitted=problem.fitted,
        gains=[float(g) for g in fit.gains],
        coc_px=coc_fit,
        measured_coc_px=[m * start.scale0 / values["psf_scale"] for m in start.measured],
        depths=problem.depths,
        residuals=[r.detach() for r in fit.residuals],
        rmse=fit.rmse,
        margin_px=int(model.margin),
        covariance=fit.covariance,
        names=[p.name or f"pair {i}" for i, p in enumerate(problem.pairs)],
    )
