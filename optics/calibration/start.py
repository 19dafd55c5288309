"""The initial guess: each pair's own blur, the thin-lens curve through it, margin and padding."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import torch

from .measure import fit_thin_lens_curve, measure_blur
from .problem import Problem

#: Start values of a product parameter where the measured blur gives none.
FALLBACK = {"f_number": 4.0, "pixel_pitch": 5e-6, "psf_scale": 0.5}
#: Smallest blur (CoC diameter, pixels) that counts as measured: below it in every pair the
#: photos say nothing about the camera (a disk of CoC <= 1 px renders as the identity).
MIN_BLUR_PX = 1.0


@dataclass
class Start:
    """Where the fit starts.

    Attributes:
        values: every parameter: the known values, and start values of the fitted ones.
        measured: each pair's own CoC diameter (pixels), measured at the PSF scale `scale0`.
        scale0: the PSF scale of the measurements (a Gaussian's sigma per CoC diameter).
    """

    values: dict[str, float]
    measured: list[float]
    scale0: float

    @property
    def largest_coc_px(self) -> float:
        """The largest measured blur with 20 % to spare (at least 1.2 pixels)."""
        return max(max(self.measured), 1.0) * 1.2

    @property
    def widest_scale(self) -> float:
        return max(self.scale0, self.values.get("psf_scale", self.scale0))


def initial_guess(problem: Problem, initial: Mapping[str, float] | None,
                  max_coc_px: float) -> Start:
    """Measure each pair's blur, fit the thin-lens curve through it and solve for the start.

    When the f-number, pixel pitch and PSF scale are all known, the blur at infinity is known
    up to the focus distance, and the start solves the measured blur for the focus distance
    with it (not a free curve fit, which one distance cannot pin down).

    Args:
        problem: the problem.
        initial: start values that replace the guesses (`psf_scale` also sets the PSF scale of
            the measurements).
        max_coc_px: largest CoC diameter (pixels) searched by `measure_blur`.

    Raises:
        ValueError: if no pair shows a measurable blur (every CoC below `MIN_BLUR_PX`).
    """
    initial = dict(initial or {})
    known = problem.known
    scale0 = float(initial.get("psf_scale", known["psf_scale"] or 0.5))
    aperture0 = problem.aperture(scale0)
    measured = [measure_blur(pair, aperture0, max_coc_px) for pair in problem.pairs]
    _check_measurable(problem, measured)
    start = {k: float(v) for k, v in known.items() if v is not None}
    a_px, df0 = fit_thin_lens_curve(problem.depths, measured, known["focus_distance"])
    if not problem.product and known["focus_distance"] is None:
        df0 = _focus_from_known_blur(problem.depths, measured, start, scale0)
    start.setdefault("focus_distance", float(initial.get("focus_distance", df0)))
    start["focus_distance"] = max(start["focus_distance"], 1.05 * problem.focal_length)
    for name in problem.product:
        start[name] = float(initial[name]) if name in initial else _product_start(
            name, start, a_px, scale0)
    return Start(start, measured, scale0)


def _check_measurable(problem: Problem, measured: Sequence[float]) -> None:
    if max(measured) >= MIN_BLUR_PX:
        return
    blur = ", ".join(f"{m:.3f}" for m in measured)
    raise ValueError(
        f"no measurable blur: every blurred photo matches its sharp reference at a CoC below "
        f"{MIN_BLUR_PX} px (measured {blur} px at {problem.depths} m), so the photos say nothing "
        f"about {list(problem.fitted)}. The targets are at the focus distance, or the blurred "
        "shots are not defocused (the same photo twice?); shoot targets clearly nearer and "
        "farther than the focus plane with the aperture open"
    )


def _focus_from_known_blur(depths: Sequence[float], measured: Sequence[float],
                           known: Mapping[str, float], scale0: float) -> float:
    """The focus distance whose thin-lens blur `k |D - D_f| / (D (D_f - f))` (pixels, at the
    measurement scale `scale0`; `k = (s / scale0) f^2 / (N p)` known) best matches `measured`."""
    f = known["focal_length"]
    k = known["psf_scale"] / scale0 * f * f / (known["f_number"] * known["pixel_pitch"])
    depth = torch.tensor(list(depths), dtype=torch.float64)
    coc = torch.tensor(list(measured), dtype=torch.float64)
    low = max(float(depth.min()) / 4, 1.05 * f)
    candidates = torch.logspace(math.log10(low), math.log10(max(float(depth.max()) * 4, 2 * low)),
                                4001, dtype=torch.float64)[:, None]
    predicted = k * (depth - candidates).abs() / (depth * (candidates - f))
    return float(candidates[int(((predicted - coc) ** 2).sum(1).argmin()), 0])


def _product_start(name: str, start: dict[str, float], a_px: float, scale0: float) -> float:
    """Solve the measured `A = (scale / scale0) f^2 / (N (D_f - f) p)` (the CoC in pixels at
    infinity, measured at scale `scale0`) for `name`, one of f_number, pixel_pitch, psf_scale."""
    f, df = start["focal_length"], start["focus_distance"]
    geometric = f * f / (df - f) / max(a_px, 1e-6)
    s = start.get("psf_scale", scale0)
    if name == "psf_scale":
        value = scale0 * a_px * start["f_number"] * (df - f) * start["pixel_pitch"] / (f * f)
    elif name == "f_number":
        value = geometric * s / scale0 / start["pixel_pitch"]
    else:
        value = geometric * s / scale0 / start["f_number"]
    return value if math.isfinite(value) and value > 0 else FALLBACK[name]


def margin_and_pad(problem: Problem, start: Start, margin_px: int | None) -> tuple[int, int]:
    """The border left out of the loss and the FFT blurs' padding, in pixels.

    By default the margin is the half width of the PSF of the largest measured blur, plus 2;
    the padding holds the PSF at 1.3 times the widest scale.

    Raises:
        ValueError: if the margin leaves fewer than 4 pixels of the smallest image.
    """
    largest = start.largest_coc_px
    if margin_px is None:
        margin_px = problem.aperture(start.widest_scale).half_width(largest) + 2
    smallest = min(min(p.sharp.shape[-2:]) for p in problem.pairs)
    if margin_px < 0 or smallest - 2 * margin_px < 4:
        raise ValueError(
            f"margin_px={margin_px} leaves no pixels of the smallest image ({smallest} px); "
            "use larger images or a smaller margin"
        )
    pad = max(margin_px, problem.aperture(1.3 * start.widest_scale).half_width(largest) + 1)
    return margin_px, pad
