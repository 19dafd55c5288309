"""`CalibrationResult`: the fitted camera as `CameraSettings`, its uncertainty and residuals."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

import torch
from torch import Tensor

from ..aperture import Aperture, Polygon
from ..aperture_spec import aperture_spec
from ..camera import SETTING_FIELDS, Camera, CameraSettings
from .problem import PARAMETERS, make_aperture

_UNITS = {"focus_distance": "m", "focal_length": "m", "pixel_pitch": "m"}


def fitted_settings(values: dict[str, float], psf: str) -> CameraSettings:
    """`(1,)` settings of a calibration's values, the aperture spec holding a Gaussian's scale."""
    scale = torch.tensor(values["psf_scale"], dtype=torch.float64)  # float64: the spec's digits
    spec = aperture_spec(make_aperture(psf, scale))
    return CameraSettings(*(values[name] for name in SETTING_FIELDS), aperture=spec)


@dataclass
class CalibrationResult:
    """What `calibrate` found.

    Attributes:
        settings: the fitted camera, `(1,)` settings (lengths in metres; `pixel_pitch` is the
            images' effective pitch) with the PSF's spec, e.g. `"gaussian:0.47"` or `"disk"`.
        psf_scale: the Gaussian's `sigma` per CoC diameter at full precision (the spec in
            `settings` keeps 6 digits); 1 for the disk and polygons, which have no scale.
        uncertainty: one standard deviation of each fitted value (same units).
        fitted: names of the fitted parameters.
        gains: exposure gain of each pair (defocused / rendered reference).
        coc_px: the fitted camera's CoC diameter (pixels) at each pair's typical depth.
        measured_coc_px: each pair's own blur estimate (pixels, same PSF family and scale).
        depths: each pair's typical depth in metres.
        residuals: `(1,3,h,w)` residual (defocused minus gain x rendered) of each pair, interior.
        rmse: root-mean-square residual over all pairs.
        margin_px: border left out of the fit, in pixels.
        covariance: covariance of the fitted parameters in log space (`(k, k)`).
        names: pair names.
    """

    settings: CameraSettings
    psf_scale: float
    uncertainty: dict[str, float]
    fitted: tuple[str, ...]
    gains: list[float]
    coc_px: list[float]
    measured_coc_px: list[float]
    depths: list[float]
    residuals: list[Tensor]
    rmse: float
    margin_px: int
    covariance: Tensor
    names: list[str] = field(default_factory=list)

    @property
    def values(self) -> dict[str, float]:
        """Every parameter as a float (a new dict, read from `settings` and `psf_scale`), in the
        order focus_distance, f_number, focal_length, pixel_pitch, psf_scale."""
        values = {name: float(getattr(self.settings, name).reshape(-1)[0])
                  for name in PARAMETERS if name != "psf_scale"}
        values["psf_scale"] = float(self.psf_scale)
        return values

    @property
    def psf(self) -> str:
        """The PSF as `calibrate`'s `psf` names it: `"gaussian"`, `"disk"` or `"polygon:N"`."""
        spec = self.settings.aperture
        return "gaussian" if spec.startswith("gaussian") else spec

    def aperture(self) -> Aperture:
        """The fitted PSF shape."""
        return make_aperture(self.psf, self.psf_scale)

    def camera(self) -> Camera:
        """The fitted `optics.Camera` (`settings.shot(0)`, pixel pitch: the images' effective
        one), its Gaussian scale at full precision."""
        return self.settings.shot(0, aperture=self.aperture())

    def _psf_entry(self) -> dict[str, Any]:
        """The PSF as the `{"family": ...}` object that both `optics.Camera.from_json` and
        `optics.CameraSettings.from_json` read (the scale at full precision)."""
        aperture = self.aperture()
        if self.psf == "gaussian":
            return {"family": "gaussian", "scale": self.psf_scale}
        if isinstance(aperture, Polygon):
            return {"family": "polygon", "n_blades": aperture.n_blades,
                    "rotation": float(aperture.rotation)}
        return {"family": self.psf}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: `settings.to_dict()` (its `aperture` as a `{"family": ...}` object),
        `uncertainty`, `fitted`, `rmse`, `margin_px` and per-pair details."""
        data = self.settings.to_dict()
        data["aperture"] = self._psf_entry()
        data["uncertainty"] = dict(self.uncertainty)
        data["fitted"] = list(self.fitted)
        data["rmse"] = self.rmse
        data["margin_px"] = self.margin_px
        data["pairs"] = [
            {"name": n, "depth": d, "coc_px": c, "measured_coc_px": m, "gain": g}
            for n, d, c, m, g in zip(
                self.names, self.depths, self.coc_px, self.measured_coc_px, self.gains,
                strict=True,
            )
        ]
        return data

    def save(self, path: str | PathLike) -> None:
        """Write `to_dict` as JSON; `optics.CameraSettings.from_json` (and
        `optics.Camera.from_json`) load the camera back.

        Raises:
            ValueError: if a value or an uncertainty is infinite or NaN (an undetermined fit is
                never saved); nothing is written then.
        """
        bad = {k: v for k, v in {**self.values, **self.uncertainty}.items()
               if not math.isfinite(v)}
        if bad or not math.isfinite(self.rmse):
            raise ValueError(
                f"refusing to save a calibration with non-finite values {bad or {}} (rmse "
                f"{self.rmse}): the photos do not determine the fit; {path} was not written"
            )
        data = self.to_dict()
        self.settings.to_json(path, **{k: v for k, v in data.items() if k not in SETTING_FIELDS})

    def table(self) -> str:
        """A plain-text table of the values, their uncertainty and which were fitted."""
        values = self.values
        lines = [f"{'parameter':<16}{'value':>14}{'+/- (1 sd)':>14}  {'':<6}"]
        for name in PARAMETERS:
            if name == "psf_scale" and self.psf != "gaussian":
                continue
            sd = self.uncertainty.get(name)
            text = "" if sd is None else f"{sd:.3g}"
            status = "fitted" if name in self.fitted else "fixed"
            lines.append(
                f"{name:<16}{values[name]:>14.6g}{text:>14}  {status:<6} {_UNITS.get(name, '')}"
            )
        lines.append(f"psf: {self.psf}; rmse {self.rmse:.4g}; margin {self.margin_px} px")
        lines.append(f"{'pair':<12}{'depth (m)':>10}{'CoC fit':>10}{'CoC own':>10}{'gain':>8}")
        for n, d, c, m, g in zip(
            self.names, self.depths, self.coc_px, self.measured_coc_px, self.gains, strict=True
        ):
            lines.append(f"{n[:12]:<12}{d:>10.4g}{c:>10.3f}{m:>10.3f}{g:>8.4f}")
        return "\n".join(lines)
