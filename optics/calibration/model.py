"""The residuals of a camera given in log-space parameters, for every pair."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor

from ..camera import Camera
from ..lens import ThinLens
from ..sensor import Sensor
from .measure import ConstantBlur, crop, optimal_gain
from .problem import Problem


class LogSpace:
    """The fitted parameters as `theta`: their logs, and `log(focus_distance - focal_length)`
    for the focus distance (so it stays beyond the focal length)."""

    def __init__(self, fitted: tuple[str, ...], focal_length: float):
        self.fitted = fitted
        self.focal_length = focal_length

    def to_theta(self, name: str, value: float) -> float:
        return math.log(value - self.focal_length) if name == "focus_distance" else math.log(value)

    def from_theta(self, name: str, theta: Tensor) -> Tensor:
        return theta.exp() + self.focal_length if name == "focus_distance" else theta.exp()

    def spread(self, name: str, value: float) -> float:
        """`d value / d theta`: turns a standard deviation in `theta` into one of `value`."""
        return value - self.focal_length if name == "focus_distance" else value


class ResidualModel:
    """Renders each pair's reference through the camera `theta` describes and compares it with
    the defocused photo over the interior (a border of `margin` pixels left out).

    Planar targets have one CoC per pair: their render is a spatially invariant blur (exact away
    from the border, which the margin leaves out), done by FFT, unless `use_renderer`. Pairs with
    depth maps go through `Camera.render`.

    Args:
        problem: the problem.
        values: every parameter's value; those fitted are replaced by `theta`.
        margin: border left out of the residuals, pixels.
        pad: padding of the FFT blurs, pixels.
        render_kwargs: passed to `Camera.render`.
        use_renderer: render planar targets with `Camera.render` too.
    """

    def __init__(self, problem: Problem, values: Mapping[str, float], margin: int, pad: int,
                 render_kwargs: Mapping[str, Any] | None = None, use_renderer: bool = False):
        self.problem = problem
        self.values = dict(values)
        self.margin = margin
        self.space = LogSpace(problem.fitted, problem.focal_length)
        self.dtype = torch.float64
        self.device = problem.pairs[0].sharp.device
        self.kwargs = dict(render_kwargs or {})
        pairs = problem.pairs
        self.sharp = [p.sharp.to(device=self.device, dtype=self.dtype) for p in pairs]
        self.blurred = [p.blurred.to(device=self.device, dtype=self.dtype) for p in pairs]
        self.depth_maps = [p.depth_map(s) for p, s in zip(pairs, self.sharp, strict=True)]
        self.invariant = [
            None if use_renderer or isinstance(p.depth, Tensor) else ConstantBlur(s, pad)
            for p, s in zip(pairs, self.sharp, strict=True)
        ]

    def theta0(self) -> Tensor:
        """`theta` of the start values."""
        return torch.tensor([self.space.to_theta(n, self.values[n]) for n in self.problem.fitted],
                            dtype=self.dtype, device=self.device)

    def fitted_values(self, theta: Tensor) -> dict[str, float]:
        """Every parameter's value (floats) at `theta`."""
        values = dict(self.values)
        for i, name in enumerate(self.problem.fitted):
            values[name] = float(self.space.from_theta(name, theta[i]))
        return values

    def camera(self, theta: Tensor) -> Camera:
        """The camera at `theta` (differentiable in it)."""
        values: dict[str, Tensor | float] = dict(self.values)
        for i, name in enumerate(self.problem.fitted):
            values[name] = self.space.from_theta(name, theta[i])
        t = {k: torch.as_tensor(v, dtype=self.dtype, device=self.device) for k, v in values.items()}
        lens = ThinLens(t["focal_length"], t["f_number"], t["focus_distance"])
        return Camera(lens, Sensor.from_effective_pitch(t["pixel_pitch"]), self.problem.aperture(t["psf_scale"]))

    def residuals(self, theta: Tensor) -> tuple[list[Tensor], list[Tensor]]:
        """Each pair's `(1,C,h,w)` interior residual (photo minus gain x render) and its gain."""
        camera = self.camera(theta)
        res, gains = [], []
        for i, depth in enumerate(self.problem.depths):
            rendered = crop(self._render(camera, i, depth), self.margin)
            target = crop(self.blurred[i], self.margin)
            gain = (optimal_gain(rendered, target) if self.problem.fit_gain
                    else torch.ones((), dtype=self.dtype))
            res.append(target - gain * rendered)
            gains.append(gain)
        return res, gains

    def _render(self, camera: Camera, i: int, depth: float) -> Tensor:
        blur = self.invariant[i]
        if blur is None:
            return camera.render(self.sharp[i], self.depth_maps[i], **self.kwargs)
        coc = camera.coc_px(torch.tensor([depth], dtype=self.dtype, device=self.device))
        return blur(camera.aperture, coc)

    def flat(self, theta: Tensor) -> Tensor:
        """Every residual in one vector."""
        return torch.cat([r.reshape(-1) for r in self.residuals(theta)[0]])

    def loss(self, theta: Tensor) -> Tensor:
        """Mean squared residual."""
        return self.flat(theta).pow(2).mean()
