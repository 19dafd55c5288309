"""Thin-lens geometry: circle of confusion, hyperfocal distance and depth of field."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from .checks import (
    ParamLike,
    as_parameter_tensor,
    broadcast_to_batch,
    check_param_batch,
    check_parameters,
    check_tensor,
    is_tracing,
    register_physical,
)
from .checks import format_param as _fmt

_UNITS = {"focal_length": "metres", "f_number": "", "focus_distance": "metres"}


def compute_dtype(dtype: torch.dtype) -> torch.dtype:
    """The dtype the CoC is computed in: at least float32 (fp16/bf16 inputs are promoted, since
    a pixel pitch of a few micrometres and its gradient underflow or overflow in half
    precision)."""
    return torch.promote_types(dtype, torch.float32)


class ThinLens(nn.Module):
    r"""An ideal thin lens focused at a finite distance.

    All lengths are in metres. Parameters may be Python floats, 0-d tensors or `(B,)` tensors
    (one value per batch item); `nn.Parameter` values stay trainable.

    For a lens of focal length $f$, f-number $N$ (aperture diameter $A = f/N$)
    focused at $D_f$, an object at depth $D$ is imaged as a blur circle on the sensor
    of diameter

    $$
    c(D) = \frac{f^2 \, |D - D_f|}{N \, D \, (D_f - f)}
    = A \, \frac{f}{D_f - f} \, \left|1 - \frac{D_f}{D}\right|.
    $$

    Args:
        focal_length: focal length $f$ in metres, > 0.
        f_number: f-number $N$ (dimensionless), > 0.
        focus_distance: distance $D_f$ of the plane in focus, in metres, > `focal_length`.

    Raises:
        TypeError: if a parameter is a string or not a number, tensor or list of numbers.
        ValueError: if a parameter is empty, not positive and finite, or `focus_distance` is not
            beyond `focal_length`. The values are checked again at every use (an optimiser may
            move an `nn.Parameter` out of range), naming the parameter.

    Warns:
        UserWarning: for a focal length over 2 m ("did you give millimetres?").

    The CoC is computed in at least float32 (`float16`/`bfloat16` depths are promoted) so that
    every parameter gets a finite gradient from half-precision renders.

    Example:
        >>> lens = ThinLens(focal_length=0.05, f_number=2.0, focus_distance=2.0)
        >>> depth = torch.tensor([1.0, 2.0, 4.0])
        >>> lens.coc_diameter(depth) * 1e6  # micrometres on the sensor
        tensor([641.0256,   0.0000, 320.5128])
    """

    focal_length: Tensor
    f_number: Tensor
    focus_distance: Tensor

    def __init__(self, focal_length: ParamLike, f_number: ParamLike, focus_distance: ParamLike):
        super().__init__()
        register_physical(self, _UNITS, {"focal_length": focal_length, "f_number": f_number,
                                         "focus_distance": focus_distance})
        self._check_focus()

    def _check_focus(self) -> None:
        if not is_tracing(self.focus_distance) and not bool(
                torch.all(self.focus_distance.detach() > self.focal_length.detach())):
            raise ValueError(
                "focus_distance must be greater than focal_length (a real image needs the object "
                f"beyond the focal point), got focus_distance={_fmt(self.focus_distance)} m "
                f"and focal_length={_fmt(self.focal_length)} m"
            )

    def check(self) -> None:
        """Raise `ValueError` naming the parameter unless every value is finite and > 0 and the
        focus distance lies beyond the focal length (called at every use)."""
        beyond = torch.all(self.focus_distance.detach() > self.focal_length.detach())
        if not check_parameters(self, _UNITS, also=beyond):
            self._check_focus()

    def extra_repr(self) -> str:
        return (
            f"focal_length={_fmt(self.focal_length)} m, f_number={_fmt(self.f_number)}, "
            f"focus_distance={_fmt(self.focus_distance)} m"
        )

    def _params(self, like: Tensor, name: str = "depth") -> tuple[Tensor, Tensor, Tensor]:
        self.check()
        if like.ndim and like.shape[0] != 1:  # a batch-1 input broadcasts against (B,) values
            check_param_batch(self, name, like.shape)
        return (
            broadcast_to_batch(self.focal_length, like),
            broadcast_to_batch(self.f_number, like),
            broadcast_to_batch(self.focus_distance, like),
        )

    def aperture_diameter(self) -> Tensor:
        """Entrance-pupil diameter `f / N` in metres."""
        self.check()
        return self.focal_length / self.f_number

    def image_distance(self) -> Tensor:
        """Lens-to-sensor distance `f D_f / (D_f - f)` in metres when focused at `D_f`."""
        self.check()
        return self.focal_length * self.focus_distance / (self.focus_distance - self.focal_length)

    def signed_coc_diameter(self, depth: Tensor) -> Tensor:
        """Signed circle-of-confusion diameter on the sensor, in metres.

        Negative in front of the focus plane (`depth < focus_distance`), positive behind it.

        Args:
            depth: object depths in metres, any shape with the batch first when parameters are
                `(B,)`; > 0 and not NaN (`inf` is allowed).

        Returns:
            tensor of the shape of `depth` (sensor metres), in `depth`'s dtype promoted to at
            least float32.
        """
        check_tensor("depth", depth, floating=True, values="depth")
        depth = depth.to(compute_dtype(depth.dtype))
        f, n, df = self._params(depth)
        return f * f / (n * (df - f)) * (1.0 - df / depth)

    def coc_at_infinity(self) -> Tensor:
        """CoC diameter on the sensor (metres) of a point at infinity, `A = f^2 / (N (D_f - f))`.

        The signed CoC is linear in inverse depth: `c(D) = A (1 - D_f / D)`.

        Example:
            >>> round(ThinLens(0.05, 2.0, 2.0).coc_at_infinity().item() * 1e6, 2)  # micrometres
            641.03
        """
        self.check()
        f, n, df = self.focal_length, self.f_number, self.focus_distance
        return f * f / (n * (df - f))

    def coc_diameter(self, depth: Tensor) -> Tensor:
        """Circle-of-confusion diameter on the sensor (metres), `|signed_coc_diameter|`."""
        return self.signed_coc_diameter(depth).abs()

    def forward(self, depth: Tensor) -> Tensor:
        return self.coc_diameter(depth)

    def hyperfocal_distance(self, coc_limit: ParamLike) -> Tensor:
        """Hyperfocal distance `H = f^2 / (N c) + f` in metres.

        Args:
            coc_limit: largest acceptable CoC diameter on the sensor, in metres, > 0.
        """
        c = as_parameter_tensor("coc_limit", coc_limit)
        check_tensor("coc_limit", c, values="positive", unit="metres")
        c = c.to(self.focal_length)
        self.check()
        return self.focal_length**2 / (self.f_number * c) + self.focal_length

    def depth_of_field(self, coc_limit: ParamLike) -> tuple[Tensor, Tensor]:
        """Near and far limits (metres) of the depth range whose CoC stays below `coc_limit`.

        The far limit is `inf` when the lens is focused at or beyond the hyperfocal distance.

        Example:
            >>> near, far = ThinLens(0.05, 8.0, 3.0).depth_of_field(30e-6)
            >>> round(near.item(), 3), round(far.item(), 3)
            (2.338, 4.185)
        """
        h = self.hyperfocal_distance(coc_limit)
        f, df = self.focal_length, self.focus_distance
        near = df * (h - f) / (h + df - 2 * f)
        far_denominator = h - df
        far = torch.where(
            far_denominator > 0,
            df * (h - f) / far_denominator.clamp_min(torch.finfo(h.dtype).tiny),
            torch.full_like(h, float("inf")),
        )
        return near, far

    def depth_from_signed_coc(self, signed_coc: Tensor) -> Tensor:
        """Invert `signed_coc_diameter`: the unique depth (metres) of a signed CoC (metres).

        A CoC at or beyond the limit reached at infinite depth maps to `inf`; a NaN stays NaN.

        Example:
            >>> lens = ThinLens(0.05, 2.0, 2.0)
            >>> lens.depth_from_signed_coc(lens.signed_coc_diameter(torch.tensor([1.0, 4.0])))
            tensor([1., 4.])
        """
        signed_coc = signed_coc.to(compute_dtype(signed_coc.dtype))
        f, n, df = self._params(signed_coc, "signed_coc")
        denominator = f * f - signed_coc * n * (df - f)
        safe = denominator.clamp_min(torch.finfo(denominator.dtype).tiny)
        return torch.where(denominator <= 0, torch.full_like(safe, float("inf")), f * f * df / safe)

    def depth_from_coc(self, coc_diameter: Tensor) -> tuple[Tensor, Tensor]:
        """The two depths (near, far), in metres, whose CoC diameter equals `coc_diameter`.

        The near solution lies in front of the focus plane, the far one behind it (`inf` when the
        CoC is larger than any depth behind the focus plane produces).
        """
        if not bool(torch.all(coc_diameter >= 0)):  # NaN too
            bad = coc_diameter[~(coc_diameter >= 0)]
            raise ValueError(
                "coc_diameter must be >= 0 metres (use depth_from_signed_coc for signed values), "
                f"got {bad.numel()} value(s) that are not, the first {float(bad[0]):.4g}"
            )
        return self.depth_from_signed_coc(-coc_diameter), self.depth_from_signed_coc(coc_diameter)
