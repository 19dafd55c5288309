r"""Calibrating a camera from pairs of photos: a sharp reference and a defocused shot.

Each :class:`CalibrationPair` holds a sharp reference image, the defocused photo of the same view
and the depth of what it shows (a planar target at a known distance, or a depth map), in metres.
All defocused photos share one camera setting, the one being calibrated. :func:`calibrate` fits
the parameters of that camera by gradient descent through the renderer, so that rendering each
reference with the camera gives its defocused photo:

.. math:: \min_\theta \sum_i \| B_i - g_i \, \mathrm{render}(S_i, \mathrm{CoC}_\theta(D_i)) \|^2

over the interior of the images (a margin as wide as the largest PSF is left out, since a real
photo's border blurs in content from outside the frame), with ``g_i`` the least-squares exposure
gain of pair ``i`` (solved in closed form at every step). Parameters are fitted in log space
(``focus_distance - focal_length`` too, so it stays beyond the focal length): a coarse start from
per-pair blur estimates and a thin-lens curve fit, then Adam, then L-BFGS.

Identifiability: the blur in pixels of a thin lens is
``scale * f^2 |D - D_f| / (N D (D_f - f) p)``: the PSF scale (Gaussian ``sigma`` per CoC), the
f-number ``N`` and the pixel pitch ``p`` (and nearly the focal length ``f``) enter as one product.
At most one of ``f_number``, ``pixel_pitch`` and ``psf_scale`` can be fitted; :func:`calibrate`
refuses more. The focal length is always given (e.g. from the raw file's metadata).

Uncertainties are one standard deviation from the Gauss-Newton approximation of the Hessian
(``sigma^2 (J^T J)^{-1}``, with ``J`` the Jacobian of the residuals by central differences and
``sigma^2`` the residual variance). Neighbouring pixels of demosaiced photos are correlated, so
treat them as a lower bound.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from .aperture import Aperture, Disk, Gaussian
from .camera import Camera
from .checks import check_shape
from .lens import ThinLens
from .sensor import Sensor

#: PSF families :func:`calibrate` can fit.
PSF_FAMILIES = ("disk", "gaussian")
#: Parameters of the fitted camera, in the order of :attr:`CalibrationResult.values`.
PARAMETERS = ("focus_distance", "f_number", "focal_length", "pixel_pitch", "psf_scale")
#: Parameters that enter the blur only through one product: at most one can be fitted.
_PRODUCT = ("f_number", "pixel_pitch", "psf_scale")


@dataclass
class CalibrationPair:
    """A sharp reference, the defocused photo of the same view and the depth it shows.

    Args:
        sharp: the sharp reference ``(3,H,W)`` or ``(1,3,H,W)``, linear (e.g. a stopped-down shot).
        blurred: the defocused photo, same shape, linear.
        depth: distance of the planar target in metres (a float), or a depth map ``(1,H,W)`` or
            ``(1,1,H,W)`` in metres.
        name: a label for tables and figures.

    Raises:
        ValueError: if the images differ in shape or the depth is not positive and finite.
    """

    sharp: Tensor
    blurred: Tensor
    depth: float | Tensor
    name: str = ""

    def __post_init__(self) -> None:
        label = f"pair {self.name!r}" if self.name else "pair"
        for attr in ("sharp", "blurred"):
            value = getattr(self, attr)
            if not isinstance(value, Tensor):
                raise TypeError(f"{label}: {attr} must be a torch.Tensor, got {type(value)}")
            if value.ndim == 3:
                value = value.unsqueeze(0)
            check_shape(f"{label}: {attr}", value, ["1", "C", "H", "W"])
            setattr(self, attr, value)
        if self.sharp.shape != self.blurred.shape:
            raise ValueError(
                f"{label}: sharp and blurred images must have the same shape, got "
                f"{tuple(self.sharp.shape)} and {tuple(self.blurred.shape)}"
            )
        if isinstance(self.depth, Tensor):
            depth = self.depth if self.depth.ndim == 4 else self.depth.reshape(1, *self.depth.shape)
            check_shape(f"{label}: depth", depth, ["1", "1", "H", "W"])
            if depth.shape[-2:] != self.sharp.shape[-2:]:
                raise ValueError(
                    f"{label}: depth map must be {tuple(self.sharp.shape[-2:])} pixels like the "
                    f"images, got {tuple(depth.shape[-2:])}"
                )
            if not bool(torch.all(torch.isfinite(depth) & (depth > 0))):
                raise ValueError(f"{label}: depth must be finite and > 0 metres everywhere")
            self.depth = depth
        else:
            distance = float(self.depth)
            if not (math.isfinite(distance) and distance > 0):
                raise ValueError(
                    f"{label}: depth (target distance) must be finite and > 0 metres, "
                    f"got {self.depth!r}"
                )
            self.depth = distance

    def depth_map(self, like: Tensor) -> Tensor:
        """The depth as a ``(1,1,H,W)`` map in metres on ``like``'s device and dtype."""
        if isinstance(self.depth, Tensor):
            return self.depth.to(like)
        return torch.full((1, 1, *like.shape[-2:]), self.depth, dtype=like.dtype, device=like.device)

    @property
    def typical_depth(self) -> float:
        """The target distance, or the median of the depth map, in metres."""
        return self.depth if isinstance(self.depth, float) else float(self.depth.median())


@dataclass
class CalibrationResult:
    """What :func:`calibrate` found.

    Attributes:
        values: every parameter of the camera (lengths in metres); ``psf_scale`` is the Gaussian
            ``sigma`` per CoC diameter (1 for the disk, which has no scale).
        uncertainty: one standard deviation of each fitted value (same units).
        fitted: names of the fitted parameters.
        psf: PSF family, ``"disk"`` or ``"gaussian"``.
        gains: exposure gain of each pair (defocused / rendered reference).
        coc_px: the fitted camera's CoC diameter (pixels) at each pair's typical depth.
        measured_coc_px: each pair's own blur estimate (pixels, same PSF family and scale).
        depths: each pair's typical depth in metres.
        residuals: ``(1,3,h,w)`` residual (defocused minus gain x rendered) of each pair, interior.
        rmse: root-mean-square residual over all pairs.
        margin_px: border left out of the fit, in pixels.
        covariance: covariance of the fitted parameters in log space (``(k, k)``).
        names: pair names.
    """

    values: dict[str, float]
    uncertainty: dict[str, float]
    fitted: tuple[str, ...]
    psf: str
    gains: list[float]
    coc_px: list[float]
    measured_coc_px: list[float]
    depths: list[float]
    residuals: list[Tensor]
    rmse: float
    margin_px: int
    covariance: Tensor
    names: list[str] = field(default_factory=list)

    def aperture(self) -> Aperture:
        """The fitted PSF shape."""
        return _make_aperture(self.psf, self.values["psf_scale"])

    def camera(self) -> Camera:
        """The fitted :class:`~optics.Camera` (pixel pitch: the images' effective one)."""
        return Camera.from_settings(
            {k: self.values[k] for k in Camera.SETTING_KEYS}, aperture=self.aperture()
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: the camera keys, ``psf``, ``uncertainty`` and per-pair details."""
        data: dict[str, Any] = {k: self.values[k] for k in Camera.SETTING_KEYS}
        data["psf"] = _aperture_dict(self.psf, self.values["psf_scale"])
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
        """Write :meth:`to_dict` as JSON; :meth:`optics.Camera.from_json` loads it back."""
        data = self.to_dict()
        extra = {k: v for k, v in data.items() if k not in (*Camera.SETTING_KEYS, "psf")}
        self.camera().to_json(path, **extra)

    def table(self) -> str:
        """A plain-text table of the values, their uncertainty and which were fitted."""
        units = {"focus_distance": "m", "focal_length": "m", "pixel_pitch": "m"}
        lines = [f"{'parameter':<16}{'value':>14}{'+/- (1 sd)':>14}  {'':<6}"]
        for name in PARAMETERS:
            if name == "psf_scale" and self.psf != "gaussian":
                continue
            value = self.values[name]
            sd = self.uncertainty.get(name)
            text = "" if sd is None else f"{sd:.3g}"
            status = "fitted" if name in self.fitted else "fixed"
            lines.append(f"{name:<16}{value:>14.6g}{text:>14}  {status:<6} {units.get(name, '')}")
        lines.append(f"psf: {self.psf}; rmse {self.rmse:.4g}; margin {self.margin_px} px")
        lines.append(f"{'pair':<12}{'depth (m)':>10}{'CoC fit':>10}{'CoC own':>10}{'gain':>8}")
        for n, d, c, m, g in zip(
            self.names, self.depths, self.coc_px, self.measured_coc_px, self.gains, strict=True
        ):
            lines.append(f"{n[:12]:<12}{d:>10.4g}{c:>10.3f}{m:>10.3f}{g:>8.4f}")
        return "\n".join(lines)


def _make_aperture(psf: str, scale: float | Tensor) -> Aperture:
    return Gaussian(scale) if psf == "gaussian" else Disk()


def _aperture_dict(psf: str, scale: float) -> dict[str, Any]:
    return {"family": "gaussian", "scale": scale} if psf == "gaussian" else {"family": "disk"}


def _optimal_gain(rendered: Tensor, target: Tensor) -> Tensor:
    """Least-squares gain ``g`` minimising ``|target - g rendered|^2``."""
    return (rendered * target).sum() / (rendered * rendered).sum().clamp_min(1e-30)


def _crop(image: Tensor, margin: int) -> Tensor:
    return image[..., margin : image.shape[-2] - margin, margin : image.shape[-1] - margin]


class _ConstantBlur:
    """Spatially invariant blurs of one image by FFT: the renderer's result for a constant CoC away
    from the borders (an exactness anchor of :func:`optics.render_defocus`), much faster, and
    differentiable in the kernel."""

    def __init__(self, image: Tensor, pad: int):
        self.pad = pad
        padded = F.pad(image, (pad, pad, pad, pad), mode="replicate")
        self.size = padded.shape[-2:]
        self.spectrum = torch.fft.rfft2(padded)

    def __call__(self, aperture: Aperture, coc_px: float | Tensor) -> Tensor:
        coc = torch.as_tensor(coc_px, dtype=self.spectrum.real.dtype).reshape(-1)
        kernel = aperture.kernel(coc, kernel_size=2 * self.pad + 1)[0]
        placed = F.pad(kernel, (0, self.size[1] - kernel.shape[1], 0, self.size[0] - kernel.shape[0]))
        placed = torch.roll(placed, (-self.pad, -self.pad), dims=(0, 1))
        out = torch.fft.irfft2(self.spectrum * torch.fft.rfft2(placed), s=self.size)
        return out[..., self.pad : -self.pad, self.pad : -self.pad]


def measure_blur(
    pair: CalibrationPair,
    aperture: Aperture,
    max_coc_px: float = 24.0,
    margin_px: int | None = None,
) -> float:
    """One pair's CoC diameter in pixels, as a spatially invariant blur of the reference.

    A grid search over ``[0, max_coc_px]`` followed by a golden-section refinement, with the
    exposure gain solved in closed form. For a planar target this is the pair's true blur; for a
    depth map it is a typical value (used to start :func:`calibrate`).

    Args:
        pair: the pair.
        aperture: PSF shape (its scale, for a Gaussian, defines what "CoC" means).
        max_coc_px: largest CoC diameter searched, pixels.
        margin_px: border left out, pixels (by default the largest PSF's half width, at most a
            quarter of the image).

    Returns:
        the CoC diameter in pixels.

    Example:
        >>> sharp = torch.rand(1, 3, 48, 48, dtype=torch.float64)
        >>> blurred = Camera(ThinLens(0.05, 2.0, 2.0), Sensor(2e-5), Disk()).render(
        ...     sharp, torch.full((1, 1, 48, 48), 3.0, dtype=torch.float64))
        >>> round(measure_blur(CalibrationPair(sharp, blurred, 3.0), Disk()), 1)
        10.7
    """
    sharp = pair.sharp.to(torch.float64)
    blurred = pair.blurred.to(torch.float64)
    if margin_px is None:
        margin_px = min(aperture.half_width(max_coc_px) + 1, min(sharp.shape[-2:]) // 4)
    blur = _ConstantBlur(sharp, aperture.half_width(max_coc_px) + 1)

    def loss(coc: float) -> float:
        rendered = _crop(blur(aperture, coc), margin_px)
        target = _crop(blurred, margin_px)
        gain = _optimal_gain(rendered, target)
        return float(((target - gain * rendered) ** 2).mean())

    grid = [0.0] + torch.logspace(math.log10(0.5), math.log10(max_coc_px), 24).tolist()
    losses = [loss(c) for c in grid]
    best = min(range(len(grid)), key=losses.__getitem__)
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    ratio = (math.sqrt(5) - 1) / 2
    a, b = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    fa, fb = loss(a), loss(b)
    for _ in range(20):
        if fa < fb:
            hi, b, fb = b, a, fa
            a = hi - ratio * (hi - lo)
            fa = loss(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + ratio * (hi - lo)
            fb = loss(b)
    return (a + b) / 2


def fit_thin_lens_curve(
    depths: Sequence[float], coc_px: Sequence[float], focus_distance: float | None = None
) -> tuple[float, float]:
    """Fit ``coc(D) = A |1 - D_f / D|`` to measured blur (pixels) at depths ``D`` (metres).

    Args:
        depths: depths in metres.
        coc_px: CoC diameters in pixels.
        focus_distance: ``D_f`` if known (metres); else searched on a fine logarithmic grid.

    Returns:
        ``(A, D_f)``: the CoC in pixels at infinite depth, and the focus distance in metres.

    Example:
        >>> d = [1.0, 1.5, 4.0]
        >>> a, df = fit_thin_lens_curve(d, [8 * abs(1 - 2 / x) for x in d])
        >>> round(a, 3), round(df, 2)
        (8.0, 2.0)
    """
    depth = torch.tensor(list(depths), dtype=torch.float64)
    coc = torch.tensor(list(coc_px), dtype=torch.float64)
    if focus_distance is None:
        candidates = torch.logspace(
            math.log10(float(depth.min()) / 4), math.log10(float(depth.max()) * 4), 4001,
            dtype=torch.float64,
        )
    else:
        candidates = torch.tensor([float(focus_distance)], dtype=torch.float64)
    u = (1 - candidates[:, None] / depth[None]).abs()
    scale = (u * coc).sum(1) / (u * u).sum(1).clamp_min(1e-30)
    error = ((coc - scale[:, None] * u) ** 2).sum(1)
    best = int(error.argmin())
    return float(scale[best]), float(candidates[best])


def calibrate(
    pairs: Sequence[CalibrationPair],
    focal_length: float,
    psf: str = "disk",
    f_number: float | None = None,
    focus_distance: float | None = None,
    pixel_pitch: float | None = None,
    psf_scale: float | None = None,
    initial: Mapping[str, float] | None = None,
    fit_gain: bool = True,
    margin_px: int | None = None,
    max_coc_px: float = 24.0,
    adam_steps: int = 60,
    lbfgs_steps: int = 40,
    render_kwargs: Mapping[str, Any] | None = None,
    use_renderer: bool = False,
    progress: bool = False,
) -> CalibrationResult:
    """Fit the camera that turns each pair's sharp reference into its defocused photo.

    A parameter given a value is fixed to it (and stays exactly that); a parameter left ``None``
    is fitted. Lengths are in metres; ``pixel_pitch`` is the *effective* pitch of the images
    (sensor pitch x binning).

    Args:
        pairs: one or more :class:`CalibrationPair`; at least two distinct depths when the focus
            distance is fitted together with another parameter (three or more recommended).
        focal_length: focal length in metres (known, e.g. from the metadata).
        psf: PSF family, ``"disk"`` or ``"gaussian"``.
        f_number: f-number, or ``None`` to fit it.
        focus_distance: focus distance in metres, or ``None`` to fit it.
        pixel_pitch: effective pixel pitch in metres, or ``None`` to fit it.
        psf_scale: Gaussian ``sigma`` per CoC diameter, or ``None`` to fit it (Gaussian only).
        initial: starting values of fitted parameters (by default from per-pair blur estimates).
        fit_gain: solve an exposure gain per pair (else the gain is 1).
        margin_px: border left out of the loss, in pixels (by default the half width of the PSF
            of the largest measured blur, plus 2).
        max_coc_px: largest CoC diameter (pixels) searched by the per-pair estimates.
        adam_steps: Adam iterations (learning rate 0.05 in log space).
        lbfgs_steps: L-BFGS iterations after Adam.
        render_kwargs: passed to :meth:`optics.Camera.render` (``mode``, ...).
        use_renderer: render planar targets with :meth:`optics.Camera.render` too. By default a
            pair whose depth is one distance is rendered as the spatially invariant blur the
            renderer reduces to for a constant CoC (exact in the interior, much faster);
            pairs with depth maps always go through the renderer.
        progress: show a tqdm progress bar.

    Returns:
        the :class:`CalibrationResult`.

    Raises:
        ValueError: for no pairs, an unknown PSF family, nothing to fit, more than one of
            ``f_number``, ``pixel_pitch``, ``psf_scale`` to fit (only their product shows in the
            blur), ``psf_scale`` for a disk, a non-positive value, too few depths, or a margin that
            leaves no pixels.

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
    """
    pairs = list(pairs)
    if not pairs:
        raise ValueError("pairs must hold at least one CalibrationPair, got none")
    for i, pair in enumerate(pairs):
        if not isinstance(pair, CalibrationPair):
            raise TypeError(f"pairs[{i}] must be a CalibrationPair, got {type(pair).__name__}")
    if not isinstance(psf, str) or psf.lower() not in PSF_FAMILIES:
        raise ValueError(f"psf must be one of {list(PSF_FAMILIES)}, got {psf!r}")
    psf = psf.lower()
    if psf == "disk" and psf_scale is not None:
        raise ValueError(f"psf_scale applies to the Gaussian PSF only, got {psf_scale!r} for a disk")
    known = {
        "focal_length": focal_length,
        "f_number": f_number,
        "focus_distance": focus_distance,
        "pixel_pitch": pixel_pitch,
        "psf_scale": psf_scale if psf == "gaussian" else 1.0,
    }
    for name, value in known.items():
        if value is not None and not (math.isfinite(float(value)) and float(value) > 0):
            raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    if focal_length is None:
        raise ValueError("focal_length must be given in metres (e.g. from the raw metadata)")
    fitted = tuple(name for name in PARAMETERS if known[name] is None)
    if not fitted:
        raise ValueError("every parameter is fixed: leave at least one of them None to fit it")
    product = [name for name in fitted if name in _PRODUCT]
    if len(product) > 1:
        raise ValueError(
            f"cannot fit {product} together: the blur depends on psf_scale * focal_length^2 / "
            "(f_number * pixel_pitch) only, so only one of f_number, pixel_pitch and psf_scale "
            "can be fitted; fix the others (e.g. the f-number from the metadata)"
        )
    depths = [pair.typical_depth for pair in pairs]
    distinct = len({round(d, 9) for d in depths})
    if "focus_distance" in fitted and product and distinct < 2:
        raise ValueError(
            "fitting focus_distance together with the blur scale needs targets at two or more "
            f"distinct depths (three or more recommended), got depths {depths}"
        )
    if known["focus_distance"] is not None and known["focus_distance"] <= focal_length:
        raise ValueError(
            f"focus_distance must exceed focal_length, got {focus_distance} <= {focal_length} m"
        )

    # 1. Each pair's own blur, measured with the PSF at its starting scale.
    initial = dict(initial or {})
    scale0 = float(initial.get("psf_scale", known["psf_scale"] or 0.5))
    aperture0 = _make_aperture(psf, scale0)
    measured = [measure_blur(pair, aperture0, max_coc_px) for pair in pairs]

    # 2. Start values from the thin-lens curve through the measured blur.
    start = {k: float(v) for k, v in known.items() if v is not None}
    a_px, df0 = fit_thin_lens_curve(depths, measured, known["focus_distance"])
    start.setdefault("focus_distance", float(initial.get("focus_distance", df0)))
    start["focus_distance"] = max(start["focus_distance"], 1.05 * focal_length)
    if product:
        name = product[0]
        if name in initial:
            start[name] = float(initial[name])
        else:
            # measured A (at scale0) = (scale / scale0) f^2 / (N (D_f - f) p)
            f, df = focal_length, start["focus_distance"]
            geometric = f * f / (df - f) / max(a_px, 1e-6)
            s = start.get("psf_scale", scale0)
            if name == "psf_scale":
                start[name] = scale0 * a_px * start["f_number"] * (df - f) * start["pixel_pitch"] / (
                    f * f
                )
            elif name == "f_number":
                start[name] = geometric * s / scale0 / start["pixel_pitch"]
            else:
                start[name] = geometric * s / scale0 / start["f_number"]
            if not (math.isfinite(start[name]) and start[name] > 0):
                start[name] = {"f_number": 4.0, "pixel_pitch": 5e-6, "psf_scale": 0.5}[name]

    # 3. Joint fit through the renderer.
    largest = max(max(measured), 1.0) * 1.2
    if margin_px is None:
        margin_px = _make_aperture(psf, max(scale0, start.get("psf_scale", scale0))).half_width(
            largest
        ) + 2
    smallest = min(min(p.sharp.shape[-2:]) for p in pairs)
    if margin_px < 0 or smallest - 2 * margin_px < 4:
        raise ValueError(
            f"margin_px={margin_px} leaves no pixels of the smallest image ({smallest} px); "
            "use larger images or a smaller margin"
        )
    dtype = torch.float64
    device = pairs[0].sharp.device
    sharp = [p.sharp.to(device=device, dtype=dtype) for p in pairs]
    blurred = [p.blurred.to(device=device, dtype=dtype) for p in pairs]
    depth_maps = [p.depth_map(s) for p, s in zip(pairs, sharp, strict=True)]
    kwargs = dict(render_kwargs or {})

    def to_theta(name: str, value: float) -> float:
        return math.log(value - focal_length) if name == "focus_distance" else math.log(value)

    def from_theta(name: str, theta: Tensor) -> Tensor:
        return theta.exp() + focal_length if name == "focus_distance" else theta.exp()

    theta0 = torch.tensor([to_theta(n, start[n]) for n in fitted], dtype=dtype, device=device)

    def camera_of(theta: Tensor) -> Camera:
        values: dict[str, Tensor | float] = dict(start)
        for i, name in enumerate(fitted):
            values[name] = from_theta(name, theta[i])
        as_tensor = {k: torch.as_tensor(v, dtype=dtype, device=device) for k, v in values.items()}
        lens = ThinLens(as_tensor["focal_length"], as_tensor["f_number"], as_tensor["focus_distance"])
        return Camera(lens, Sensor(as_tensor["pixel_pitch"]), _make_aperture(psf, as_tensor["psf_scale"]))

    # Planar targets have one CoC per pair: the render is then a spatially invariant blur
    # (exact away from the border, which the margin leaves out), done by FFT.
    pad = max(margin_px, _make_aperture(psf, 1.3 * max(scale0, start.get("psf_scale", scale0)))
              .half_width(largest) + 1)
    invariant = [
        None if use_renderer or isinstance(p.depth, Tensor) else _ConstantBlur(s, pad)
        for p, s in zip(pairs, sharp, strict=True)
    ]

    def residuals(theta: Tensor) -> tuple[list[Tensor], list[Tensor]]:
        camera = camera_of(theta)
        res, gains = [], []
        for s, b, d, blur, depth in zip(sharp, blurred, depth_maps, invariant, depths, strict=True):
            if blur is None:
                rendered = camera.render(s, d, **kwargs)
            else:
                coc = camera.coc_px(torch.tensor([depth], dtype=dtype, device=device))
                rendered = blur(camera.aperture, coc)
            rendered = _crop(rendered, margin_px)
            target = _crop(b, margin_px)
            gain = _optimal_gain(rendered, target) if fit_gain else torch.ones((), dtype=dtype)
            res.append(target - gain * rendered)
            gains.append(gain)
        return res, gains

    def loss_of(theta: Tensor) -> Tensor:
        res, _ = residuals(theta)
        return torch.cat([r.reshape(-1) for r in res]).pow(2).mean()

    from tqdm.auto import tqdm

    theta = theta0.clone().requires_grad_(True)
    bar = tqdm(total=adam_steps + lbfgs_steps, desc="calibrating", disable=not progress)
    adam = torch.optim.Adam([theta], lr=0.05)
    for _ in range(adam_steps):
        adam.zero_grad()
        loss = loss_of(theta)
        loss.backward()
        adam.step()
        bar.update(1)
        bar.set_postfix(loss=f"{loss.item():.3g}")
    if lbfgs_steps > 0:
        lbfgs = torch.optim.LBFGS(
            [theta], lr=1, max_iter=lbfgs_steps, line_search_fn="strong_wolfe",
            tolerance_grad=1e-12, tolerance_change=1e-15,
        )

        def closure() -> Tensor:
            lbfgs.zero_grad()
            value = loss_of(theta)
            value.backward()
            return value

        lbfgs.step(closure)
        bar.update(lbfgs_steps)
    bar.close()
    theta = theta.detach()

    # 4. Uncertainty: Gauss-Newton covariance from a central-difference Jacobian (log space).
    with torch.no_grad():
        res, gains = residuals(theta)
        flat = torch.cat([r.reshape(-1) for r in res])
        step = 1e-4
        columns = []
        for i in range(len(fitted)):
            delta = torch.zeros_like(theta)
            delta[i] = step
            plus = torch.cat([r.reshape(-1) for r in residuals(theta + delta)[0]])
            minus = torch.cat([r.reshape(-1) for r in residuals(theta - delta)[0]])
            columns.append((plus - minus) / (2 * step))
        jacobian = torch.stack(columns, 1)
        dof = max(flat.numel() - len(fitted) - (len(pairs) if fit_gain else 0), 1)
        variance = flat.pow(2).sum() / dof
        normal = jacobian.T @ jacobian
        if bool(torch.linalg.matrix_rank(normal) < len(fitted)):
            warnings.warn(
                "the fit does not determine every fitted parameter (singular Hessian); "
                "their uncertainty is reported as inf",
                stacklevel=2,
            )
            covariance = torch.full_like(normal, float("inf"))
        else:
            covariance = variance * torch.linalg.inv(normal)

    values = dict(start)
    uncertainty = {}
    for i, name in enumerate(fitted):
        values[name] = float(from_theta(name, theta[i]))
        sd_log = float(covariance[i, i].clamp_min(0).sqrt())
        spread = values[name] - focal_length if name == "focus_distance" else values[name]
        uncertainty[name] = spread * sd_log
    camera = camera_of(theta)
    with torch.no_grad():
        coc_fit = [float(camera.coc_px(torch.tensor([d], dtype=dtype))[0]) for d in depths]
    measured_final = [m * scale0 / values["psf_scale"] for m in measured]
    return CalibrationResult(
        values=values,
        uncertainty=uncertainty,
        fitted=fitted,
        psf=psf,
        gains=[float(g) for g in gains],
        coc_px=coc_fit,
        measured_coc_px=measured_final,
        depths=depths,
        residuals=[r.detach() for r in res],
        rmse=float(flat.pow(2).mean().sqrt()),
        margin_px=int(margin_px),
        covariance=covariance,
        names=[p.name or f"pair {i}" for i, p in enumerate(pairs)],
    )


def plot_calibration(result: CalibrationResult, path: str | PathLike | None = None) -> Any:
    """Figure of a calibration: blur versus distance with the fitted thin-lens curve, and the
    residual map of each pair.

    Args:
        result: from :func:`calibrate`.
        path: where to save the figure (PNG, PDF, ...); not saved when ``None``.

    Returns:
        the matplotlib ``Figure``.
    """
    import matplotlib
    import matplotlib.ticker

    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    n = len(result.residuals)
    fig, axes = plt.subplots(1, n + 1, figsize=(4.2 + 2.6 * n, 3.6), constrained_layout=True,
                             gridspec_kw={"width_ratios": [1.6] + [1] * n})
    ax = axes[0]
    camera = result.camera()
    depths = result.depths
    lo, hi = min(depths + [result.values["focus_distance"]]), max(depths)
    grid = torch.logspace(math.log10(lo / 1.5), math.log10(hi * 1.5), 200, dtype=torch.float64)
    with torch.no_grad():
        curve = camera.coc_px(grid)
    ax.plot(grid.numpy(), curve.numpy(), label="fitted thin lens")
    ax.plot(depths, result.measured_coc_px, "o", label="each pair's own blur")
    ax.axvline(result.values["focus_distance"], color="grey", ls=":", label="focus distance")
    ax.set_xscale("log")
    # Plain decimal ticks: distances span less than a decade, where 3x10^0-style labels collide.
    ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xticks(sorted(set(round(float(d), 2) for d in depths + [result.values["focus_distance"]])))
    ax.set_xlabel("target distance (m)")
    ax.set_ylabel("CoC diameter (px)")
    ax.set_title(
        f"D_f = {result.values['focus_distance']:.3g} m, f/{result.values['f_number']:.3g}"
        + (f", scale {result.values['psf_scale']:.3g}" if result.psf == "gaussian" else "")
    )
    ax.legend(fontsize="small")
    limit = max(float(r.abs().max()) for r in result.residuals)
    for ax, residual, name, depth in zip(
        axes[1:], result.residuals, result.names, depths, strict=True
    ):
        image = ax.imshow(residual[0].mean(0).cpu().numpy(), cmap="RdBu", vmin=-limit, vmax=limit)
        ax.set_title(f"{name}: {depth:.3g} m", fontsize="small")
        ax.axis("off")
    fig.colorbar(image, ax=list(axes[1:]), shrink=0.8, label="residual")
    if path is not None:
        fig.savefig(path, dpi=100)
    return fig
