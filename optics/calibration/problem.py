"""Validating `calibrate`'s arguments into a `Problem`: the pairs, the PSF and the parameters."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from torch import Tensor

from ..aperture import Aperture, Gaussian
from ..aperture_spec import aperture_spec, parse_aperture
from .pair import CalibrationPair

#: PSF specs `calibrate` can fit (`optics.aperture_spec` names them). A Gaussian's scale is its
#: sigma per CoC diameter, fitted unless given (`gaussian:S` fixes it to `S`); the disk and the
#: polygon have no scale (`psf_scale` is 1).
PSF_FAMILIES = ("disk", "gaussian", "gaussian:SCALE", "polygon:N_BLADES[:ROTATION]")
#: Parameters of the fitted camera, in the order of `CalibrationResult.values`.
PARAMETERS = ("focus_distance", "f_number", "focal_length", "pixel_pitch", "psf_scale")
#: Parameters that enter the blur only through one product: at most one can be fitted.
PRODUCT = ("f_number", "pixel_pitch", "psf_scale")


def make_aperture(psf: str, scale: float | Tensor) -> Aperture:
    """The aperture of a calibration PSF (`"gaussian"`, `"disk"`, `"polygon:N"`) at `scale`
    (a Gaussian's sigma per CoC diameter; ignored by the other shapes, which have no scale)."""
    return Gaussian(scale) if psf == "gaussian" else parse_aperture(psf)


def parse_psf(psf: object, psf_scale: float | None) -> tuple[str, float | None]:
    """`calibrate`'s `psf` and `psf_scale` as `(psf, known scale)`.

    `psf` comes back without a Gaussian scale (`"gaussian"`, `"disk"`, `"polygon:6"`); the scale
    is `psf_scale`, or the one a `"gaussian:S"` spec fixes, or `None` (fitted). Shapes without a
    scale give 1.
    """
    aperture, spec, why = None, "", "not a spec string"
    if isinstance(psf, str):
        try:
            aperture = parse_aperture(psf)
            spec = aperture_spec(aperture)
        except ValueError as error:
            aperture, why = None, str(error)
    if aperture is None:
        raise ValueError(f"psf must be one of {list(PSF_FAMILIES)}, got {psf!r} ({why})")
    gaussian = isinstance(aperture, Gaussian)
    if gaussian and ":" not in psf:
        return "gaussian", psf_scale
    if psf_scale is not None:  # the spec fixes the size: a Gaussian's scale, or the CoC itself
        raise ValueError(f"give the Gaussian scale once: psf_scale applies to the Gaussian PSF "
                         f"only, as psf='gaussian' with psf_scale; got psf_scale={psf_scale!r} "
                         f"for a {spec} (psf={psf!r} fixes its size)")
    return ("gaussian", float(psf.split(":")[1])) if gaussian else (spec, 1.0)  # digits given


@dataclass
class Problem:
    """What `calibrate` fits: the pairs, the PSF, the known values and the fitted parameters.

    Attributes:
        pairs: the pairs.
        psf: `"gaussian"`, `"disk"` or `"polygon:N[:R]"` (without the Gaussian scale).
        known: every parameter's given value, `None` where fitted (`psf_scale` is 1 without one).
        fitted: the fitted parameters in the order of `PARAMETERS`.
        depths: each pair's typical depth in metres.
        fit_gain: whether each pair has an exposure gain.
    """

    pairs: list[CalibrationPair]
    psf: str
    known: dict[str, float | None]
    fitted: tuple[str, ...]
    depths: list[float]
    fit_gain: bool = True

    @property
    def focal_length(self) -> float:
        return self.known["focal_length"]  # type: ignore[return-value]

    @property
    def product(self) -> list[str]:
        """The fitted parameter among `PRODUCT` (at most one), as a list."""
        return [name for name in self.fitted if name in PRODUCT]

    def aperture(self, scale: float | Tensor) -> Aperture:
        """The PSF at `scale` (Gaussians only; the other shapes have none)."""
        return make_aperture(self.psf, scale)

    @classmethod
    def build(cls, pairs: Sequence[CalibrationPair], psf: object, fit_gain: bool = True,
              **values: float | None) -> Problem:
        """Check `calibrate`'s arguments; `values` are the five parameters of `PARAMETERS`.

        Raises:
            ValueError: as `calibrate` documents.
            TypeError: if a pair is not a `CalibrationPair`.
        """
        pairs = pair_list(pairs)
        psf, scale = parse_psf(psf, values["psf_scale"])
        known = {name: values[name] for name in
                 ("focal_length", "f_number", "focus_distance", "pixel_pitch")}
        known["psf_scale"] = scale
        fitted = _fitted(known)
        depths = [pair.typical_depth for pair in pairs]
        _check_depths(known, fitted, depths)
        return cls(pairs, psf, known, fitted, depths, fit_gain)


def pair_list(pairs: Sequence[CalibrationPair]) -> list[CalibrationPair]:
    """`pairs` as a list, refused where empty or holding anything but `CalibrationPair`s (the
    door of `calibrate`, `measure_blur_curve` and `side_cues`)."""
    pairs = list(pairs)
    if not pairs:
        raise ValueError("pairs must hold at least one CalibrationPair, got none")
    for i, pair in enumerate(pairs):
        if not isinstance(pair, CalibrationPair):
            raise TypeError(f"pairs[{i}] must be a CalibrationPair, got {type(pair).__name__}")
    return pairs


def _fitted(known: dict[str, float | None]) -> tuple[str, ...]:
    """The parameters left `None`, refusing none, and more than one of `PRODUCT`."""
    for name, value in known.items():  # the focal length must be given
        if (value is None and name == "focal_length") or value is not None and not (
                math.isfinite(float(value)) and float(value) > 0):
            given = " (metres, e.g. from the raw metadata)" if name == "focal_length" else ""
            raise ValueError(f"{name} must be finite and > 0{given}, got {value!r}")
    fitted = tuple(name for name in PARAMETERS if known[name] is None)
    product = [name for name in fitted if name in PRODUCT]
    if not fitted or len(product) > 1:  # one to fit at least, one of the product at most
        raise ValueError(
            "every parameter is fixed: leave at least one of them None to fit it" if not fitted
            else f"cannot fit {product} together: the blur depends on psf_scale * "
            "focal_length^2 / (f_number * pixel_pitch) only, so only one of f_number, "
            "pixel_pitch and psf_scale can be fitted; fix the others (e.g. the f-number from "
            "the metadata)")
    return fitted


_WORDS = {1: "one", 2: "two", 3: "three", 4: "four", 5: "five"}


def needed_distances(fitted: tuple[str, ...]) -> int:
    """Distinct target distances `calibrate` needs for `fitted`: one per fitted parameter, and
    two at least when the focus distance is fitted (the blur at one distance fits a focus plane
    in front of the target or behind it equally well)."""
    return max(len(fitted), 2 if "focus_distance" in fitted else 1)


def _check_depths(known: dict[str, float | None], fitted: tuple[str, ...],
                  depths: list[float]) -> None:
    distinct = len({round(d, 9) for d in depths})
    needed = needed_distances(fitted)
    if distinct < needed:
        why = ("the blur at one distance fits a focus plane in front of the target and one "
               "behind it equally well" if "focus_distance" in fitted and distinct == 1
               else "each distance gives one blur measurement, one per unknown at least")
        raise ValueError(
            f"fitting {list(fitted)} needs targets at {_WORDS.get(needed, needed)} or more "
            f"distinct depths (three or more recommended), got {distinct} distinct depth(s) "
            f"{sorted(set(depths))} m: {why}. Shoot the target at more distances, nearer and "
            "farther than the focus plane, or give the known values (e.g. --focus-distance)"
        )
    focus, focal = known["focus_distance"], known["focal_length"]
    if focus is not None and focus <= focal:  # type: ignore[operator]
        raise ValueError(f"focus_distance must exceed focal_length, got {focus} <= {focal} m")
