"""A camera whose optics are learned: the focus distances of its `F` shots, their f-numbers and
an amplitude mask in the aperture, as parameters that stay physical whatever an optimiser does.

Each value is a smooth function of free parameters that lands inside its limits by
construction, so no projection or clamping follows an optimiser step:

| value | parametrisation | kept |
|---|---|---|
| focus distances | `1/D_i = 1/far + (1/near - 1/far) * sum_{j > i} softmax(g)_j`: `F + 1` positive gaps in inverse depth that fill the range | inside `[near, far]`, in order (strictly but for rounding) |
| f-numbers | `N = N_min (N_max / N_min)^sigmoid(t)` (per shot) | inside `[N_min, N_max]` |
| mask | `m = sigmoid(l + b)` on an `h x w` grid, `b` solved so that `sum m` is the initial mask's | in `(0, 1)`, passing the light of the initial open disk (equal exposure) |

Every value starts at the fixed camera it is built from (`LearnableCamera(settings, ...)`),
and the mask at the open disk inscribed in its grid, so that a learned camera and the fixed
one start from the same point. `LearnableCamera.settings` gives the current `CameraSettings`
(differentiable), `LearnableCamera.render` the focal stack through them and the learned mask.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import torch
from torch import Tensor, nn

from .aperture import Aperture, Mask, footprint_mean, summed_area_table
from .aperture_spec import parse_aperture
from .camera import CameraSettings
from .focal_stack import render_focal_stack
from .sensor import relative_light

#: What a `LearnableCamera` may learn (the names of `TrainConfig.learn_optics` and
#: `defocus train --learn-optics`).
LEARNABLE = ("focus", "f-number", "mask")
#: The f-numbers a lens reaches, by default (a fast f/1 prime to a small aperture; open ends:
#: the f-numbers stay strictly inside, so a fixed camera at f/1.4 can start learning).
F_NUMBER_RANGE = (1.0, 22.0)
#: The side of the learned mask's grid, by default.
MASK_SIZE = 16
#: The initial mask's values inside and outside the disk are `OPEN` and `1 - OPEN`: a
#: sigmoid never reaches 0 or 1, and a value nearer them would learn slowly (its slope is small).
OPEN = 0.95


def disk_mask(size: int = MASK_SIZE, dtype: torch.dtype = torch.float64) -> Tensor:
    """The open disk inscribed in a `size x size` grid: each cell's share inside the unit
    circle (8 x 8 samples per cell), in [0, 1].

    Example:
        >>> disk_mask(4)
        tensor([[0.3281, 0.9219, 0.9219, 0.3281],
                [0.9219, 1.0000, 1.0000, 0.9219],
                [0.9219, 1.0000, 1.0000, 0.9219],
                [0.3281, 0.9219, 0.9219, 0.3281]], dtype=torch.float64)
    """
    n = 8 * size
    centres = (torch.arange(n, dtype=torch.float64) + 0.5) / n * 2 - 1
    inside = (centres[:, None] ** 2 + centres[None, :] ** 2 <= 1).to(torch.float64)
    return inside.reshape(size, 8, size, 8).mean(dim=(1, 3)).to(dtype)


def _equal_light_offset(logits: Tensor, light: Tensor) -> Tensor:
    """The offset `b` with `sum(sigmoid(logits + b)) = light`, found without gradients by
    bisection (a 0-d tensor; the sum increases with `b`)."""
    with torch.no_grad():  # at low every value is below 1e-17 of its cell, at high above
        low, high = -logits.max() - 40.0, -logits.min() + 40.0
        for _ in range(100):  # 2^-100 of the bracket: below rounding
            mid = (low + high) / 2
            above = torch.sigmoid(logits + mid).sum() > light
            low, high = torch.where(above, low, mid), torch.where(above, mid, high)
        return (low + high) / 2


class LearnableMask(Aperture):
    """An amplitude mask in the aperture, learned: values in (0, 1) on an `h x w` grid, with the
    light it passes (their sum) held at that of the initial mask (equal exposure).

    The PSF is the mask stretched over the CoC, as `Mask`'s (`optics.aperture.footprint_mean`),
    computed from the current values at every call, so the renderer's gradient reaches them.

    Args:
        initial: the starting mask `(h, w)`, values in [0, 1] (the open disk `disk_mask()` by
            default); stored as `OPEN` where it is 1 and `1 - OPEN` where it is 0 (linearly
            between), since a sigmoid reaches neither.

    Example:
        >>> mask = LearnableMask()  # the open disk on a 16 x 16 grid
        >>> mask.values().shape, round(float(mask.kernel(6.0).detach().sum()), 6)
        (torch.Size([16, 16]), 1.0)
        >>> with torch.no_grad():
        ...     _ = mask.logits.add_(10 * torch.randn(16, 16))  # any step keeps the light
        >>> bool(torch.isclose(mask.values().sum(), mask.light))
        True
    """

    oriented = True  # a learned code need not be point-symmetric: the signed CoC (`Mask`)
    light: Tensor
    initial: Tensor

    def __init__(self, initial: Tensor | None = None):
        super().__init__()
        initial = disk_mask() if initial is None else initial
        if not isinstance(initial, Tensor) or initial.ndim != 2 or min(initial.shape) < 2 \
                or not initial.is_floating_point() \
                or not bool(torch.all((initial >= 0) & (initial <= 1))) \
                or not bool(initial.sum() > 0):
            got = f"shape {tuple(initial.shape)}" if isinstance(initial, Tensor) else \
                type(initial).__name__
            raise ValueError(f"initial must be a floating-point (h, w) mask, h, w >= 2, with "
                             f"values in [0, 1], not all 0, got {got}")
        start = (1 - OPEN) + (2 * OPEN - 1) * initial
        self.logits = nn.Parameter(torch.logit(start))
        #: the starting values (the initial mask as stored)
        self.register_buffer("initial", start)
        self.register_buffer("light", start.sum())
        self._offset: tuple[tuple, Tensor] | None = None

    def extra_repr(self) -> str:
        return f"grid={tuple(self.logits.shape)}"

    def values(self) -> Tensor:
        """The mask `(h, w)`, in (0, 1), summing to `light` (differentiable).

        `sigmoid(logits + b)` with the offset `b` solved for the light (`_equal_light_offset`,
        kept until the logits change: the renderer asks for the values at every window
        offset), then one Newton step taken with gradients, which gives the implicit
        derivative `db/dl_i = -s'_i / sum_j s'_j` of the solution.
        """
        logits = self.logits
        key = (logits._version, logits.data_ptr(), logits.dtype, logits.device)
        if self._offset is None or self._offset[0] != key:
            self._offset = (key, _equal_light_offset(logits.detach(), self.light.to(logits)))
        offset = self._offset[1]
        values = torch.sigmoid(logits + offset)
        slope = (values * (1 - values)).sum().clamp_min(torch.finfo(values.dtype).tiny)
        return torch.sigmoid(logits + offset - (values.sum() - self.light) / slope)

    def profile(self, dy: Tensor, dx: Tensor, coc_px: Tensor) -> Tensor:
        return footprint_mean(summed_area_table(self.values()), dy, dx, coc_px)

    half_width = Mask.half_width

    def frozen(self) -> Mask:
        """The current mask as a fixed `Mask` (the same PSF, no parameters)."""
        return Mask(self.values().detach().clone())


def _check_learn(learn: Iterable[str]) -> tuple[str, ...]:
    learn = tuple(learn)
    unknown = [name for name in learn if name not in LEARNABLE]
    if unknown or len(set(learn)) != len(learn):
        raise ValueError(f"learn must name each of {', '.join(LEARNABLE)} at most once, got "
                         f"{list(learn)}")
    return tuple(name for name in LEARNABLE if name in learn)


class LearnableCamera(nn.Module):
    """The `F` shots of a camera with learnable focus distances, f-numbers and aperture mask.

    The focal length and the pixel pitch stay fixed; what is not in `learn` stays at the
    fixed camera's value (exactly). See the module's table for how each value is kept physical.

    Args:
        settings: the fixed camera, `(F,)` settings (or `(1, F)`): where learning starts.
        depth_range: `(near, far)` metres, the scenes' depths; the focus distances stay inside
            it. The fixed camera's focus distances must lie strictly inside, all different.
        learn: any of `LEARNABLE`: "focus", "f-number", "mask".
        f_number_range: `(N_min, N_max)`, the lens's limits; the fixed f-numbers must lie
            strictly inside.
        mask_size: side of the mask's grid (learned "mask" only), >= 2.
        aperture: the PSF when the mask is not learned (an `Aperture` or spec; the settings'
            own by default).

    Raises:
        ValueError: an unknown name in `learn`, a fixed value outside its limits, or limits
            that are not ordered (naming them).

    Example:
        >>> fixed = CameraSettings(0.05, 2.8, [2.0, 6.0], 1.8e-4)
        >>> camera = LearnableCamera(fixed, (1.0, 10.0), learn=("focus", "f-number"))
        >>> [round(d, 9) for d in camera.settings().focus_distance.tolist()]  # the fixed start
        [2.0, 6.0]
        >>> with torch.no_grad():  # a huge step: still in range and in order
        ...     for p in camera.parameters():
        ...         _ = p.add_(100.0)
        >>> focus = camera.settings().focus_distance
        >>> bool((focus > 1.0).all() and (focus < 10.0).all() and focus[0] < focus[1])
        True
        >>> sorted(camera.record())
        ['aperture', 'depth_range', 'f_number', 'f_number_range', 'focal_length', 'focus_distance', 'learned', 'mask', 'pixel_pitch']
    """

    focal_length: Tensor
    pixel_pitch: Tensor
    fixed_focus: Tensor
    fixed_f_number: Tensor
    order: Tensor

    def __init__(self, settings: CameraSettings, depth_range: tuple[float, float],
                 learn: Iterable[str] = LEARNABLE,
                 f_number_range: tuple[float, float] = F_NUMBER_RANGE,
                 mask_size: int = MASK_SIZE, aperture: Aperture | str | None = None):
        super().__init__()
        self.learn = _check_learn(learn)
        if not isinstance(settings, CameraSettings):
            raise TypeError(f"settings must be CameraSettings, got {type(settings).__name__}")
        if settings.is_batched:
            if settings.shape[0] != 1:
                raise ValueError(f"settings must be one camera, (F,) or (1, F), got shape "
                                 f"{tuple(settings.shape)}")
            settings = settings[0]
        near, far = (float(v) for v in depth_range)
        low, high = (float(v) for v in f_number_range)
        focus = settings.focus_distance.detach().double()
        numbers = settings.f_number.detach().double()
        for refused, message in (
            (not 0 < near < far < math.inf, f"depth_range must be (near, far) metres with 0 < "
             f"near < far, finite, got {tuple(depth_range)}"),
            (not 0 < low < high < math.inf, f"f_number_range must be (N_min, N_max) with 0 < "
             f"N_min < N_max, got {tuple(f_number_range)}"),
            (bool((settings.focal_length >= near).any()), f"depth_range's near end {near:g} m "
             f"must lie beyond the focal length {settings.focal_length.tolist()} m"),
            (not bool(((focus > near) & (focus < far)).all())
             or len(set(focus.tolist())) != len(focus), f"the focus distances "
             f"{focus.tolist()} m must be all different and strictly inside depth_range "
             f"({near:g}, {far:g}) m"),
            ("f-number" in self.learn and not bool(((numbers > low) & (numbers < high)).all()),
             f"the f-numbers {numbers.tolist()} must lie strictly inside f_number_range "
             f"({low:g}, {high:g})"),
            ("mask" in self.learn and (isinstance(mask_size, bool)
                                       or not isinstance(mask_size, int) or mask_size < 2),
             f"mask_size must be an integer >= 2, got {mask_size!r}")):
            if refused:
                raise ValueError(message)
        self.depth_range, self.f_number_range = (near, far), (low, high)
        self.spec = settings.aperture
        # float64 values (a few numbers): the start reproduces the fixed camera to rounding
        self.register_buffer("focal_length", settings.focal_length.detach().double().clone())
        self.register_buffer("pixel_pitch", settings.pixel_pitch.detach().double().clone())
        self.register_buffer("fixed_focus", focus.clone())
        self.register_buffer("fixed_f_number", numbers.clone())
        order = torch.argsort(focus)
        self.register_buffer("order", order)
        if "focus" in self.learn:  # F + 1 gaps in inverse depth, from 1/near down to 1/far
            inverse = torch.cat([focus.new_tensor([1 / near]), 1 / focus[order],
                                 focus.new_tensor([1 / far])])
            self.focus_logits = nn.Parameter(torch.log(-inverse.diff()))
        if "f-number" in self.learn:
            share = torch.log(numbers / low) / math.log(high / low)
            self.f_number_logits = nn.Parameter(torch.logit(share))
        #: the learned mask, or None
        self.mask: LearnableMask | None = None
        #: the PSF where the mask is not learned, or None
        self.fixed_aperture: Aperture | None = None
        if "mask" in self.learn:
            self.mask = LearnableMask(disk_mask(mask_size))
        else:
            self.fixed_aperture = parse_aperture(self.spec if aperture is None else aperture)

    @property
    def aperture(self) -> Aperture:
        """The PSF the focal stack is rendered with: the learned mask, else the fixed one."""
        return self.mask if self.mask is not None else self.fixed_aperture

    @property
    def n_shots(self) -> int:
        return int(self.fixed_focus.shape[0])

    def focus_distance(self) -> Tensor:
        """The `(F,)` focus distances, metres, in the shots' order."""
        if "focus" not in self.learn:
            return self.fixed_focus
        near, far = self.depth_range
        shares = torch.softmax(self.focus_logits, 0)  # of the inverse-depth span, one per gap
        beyond = shares.flip(0).cumsum(0).flip(0)[1:]  # the gaps beyond each focus plane
        # a sum of non-negative shares: ordered in floating point too; the clamp only rounds
        ordered = (1 / (1 / far + (1 / near - 1 / far) * beyond)).clamp(near, far)
        return ordered[torch.argsort(self.order)]

    def f_number(self) -> Tensor:
        """The `(F,)` f-numbers."""
        if "f-number" not in self.learn:
            return self.fixed_f_number
        low, high = self.f_number_range
        return (low * (high / low) ** torch.sigmoid(self.f_number_logits)).clamp(low, high)

    def light(self) -> Tensor:
        """The `(F,)` light each shot gathers, relative to the starting camera's at the same
        exposure time: `(N_start / N)**2` (a learned mask passes the open disk's light).

        Example:
            >>> camera = LearnableCamera(CameraSettings(0.05, 2.8, [2.0, 6.0], 1.8e-4), (1.0, 10.0))
            >>> [round(v, 6) for v in camera.light().tolist()]  # at the start
            [1.0, 1.0]
        """
        return relative_light(self.f_number(), self.fixed_f_number)

    def settings(self) -> CameraSettings:
        """The current `(F,)` `CameraSettings` (differentiable in the learned values); their
        aperture spec is the fixed camera's: render with `aperture` (the learned mask)."""
        return CameraSettings(self.focal_length, self.f_number(), self.focus_distance(),
                              self.pixel_pitch, aperture=self.spec)

    def render(self, image: Tensor, depth: Tensor, **render_kwargs: Any) -> Tensor:
        """The focal stack `(B, F, C, H, W)` of `image` `(B, C, H, W)` at `depth`
        `(B, 1, H, W)` metres through the current camera and aperture
        (`optics.render_focal_stack`), differentiable in every learned value.

        Example:
            >>> camera = LearnableCamera(CameraSettings(0.05, 2.8, [2.0, 6.0], 1.8e-4), (1.0, 10.0))
            >>> camera.render(torch.rand(1, 3, 8, 8), torch.full((1, 1, 8, 8), 3.0)).shape
            torch.Size([1, 2, 3, 8, 8])
        """
        settings = self.settings().to(image.dtype)
        return render_focal_stack(image, depth, settings, self.aperture, **render_kwargs)

    def forward(self, image: Tensor, depth: Tensor, **render_kwargs: Any) -> Tensor:
        return self.render(image, depth, **render_kwargs)

    def record(self) -> dict[str, Any]:
        """The current camera as JSON-able values: the settings (lists, one per shot, metres),
        the mask (nested lists, or None when it is not learned), the fixed PSF spec, what is
        learned and the limits."""
        settings = self.settings()
        record: dict[str, Any] = {
            name: [float(v) for v in getattr(settings, name).detach().reshape(-1)]
            for name in ("focal_length", "f_number", "focus_distance", "pixel_pitch")}
        record["aperture"] = self.spec
        record["mask"] = None if self.mask is None else \
            self.mask.values().detach().double().cpu().tolist()
        record["learned"] = list(self.learn)
        record["depth_range"] = list(self.depth_range)
        record["f_number_range"] = list(self.f_number_range)
        return record


__all__ = ["LEARNABLE", "LearnableCamera", "LearnableMask", "disk_mask"]
