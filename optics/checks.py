"""Public input checks for camera parameters, images and depth maps (used by every package).

Every check raises a `ValueError` or `TypeError` whose message names the argument, the value
received and what is allowed. Messages are only formatted on failure.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

ParamLike = float | int | Tensor | Sequence[float]


def _describe(value: object) -> str:
    if isinstance(value, Tensor):
        if value.numel() <= 6:
            return f"tensor({value.detach().cpu().tolist()})"
        bad = value.detach()
        return (
            f"tensor of shape {tuple(value.shape)} (min {bad.min().item():.4g}, "
            f"max {bad.max().item():.4g}, NaN count {int(torch.isnan(bad).sum())})"
        )
    return repr(value)


def as_parameter_tensor(name: str, value: ParamLike) -> Tensor:
    """Turn a camera parameter (float, 0-d or `(B,)` tensor, list) into a tensor.

    Tensors keep their device, dtype and `requires_grad`; Python numbers become float64 tensors so
    that no precision is lost before they are cast to the input's dtype (in `broadcast_to_batch`).
    """
    if isinstance(value, Tensor):
        tensor = value
    elif isinstance(value, bool):
        raise TypeError(f"{name} must be a number or a tensor, got bool {value!r}")
    elif isinstance(value, int | float):
        tensor = torch.tensor(float(value), dtype=torch.float64)
    elif isinstance(value, Sequence):
        try:
            tensor = torch.tensor([float(v) for v in value], dtype=torch.float64)
        except (TypeError, ValueError):
            raise TypeError(f"{name} must hold numbers, got {value!r}") from None
    else:
        raise TypeError(
            f"{name} must be a float, a 0-d or (B,) tensor or a list of floats, "
            f"got {type(value).__name__}"
        )
    if not tensor.is_floating_point():
        tensor = tensor.to(torch.get_default_dtype())
    if tensor.ndim > 1:
        raise ValueError(
            f"{name} must be a scalar or a (B,) tensor, got shape {tuple(tensor.shape)}"
        )
    return tensor


def is_tracing(*tensors: Tensor) -> bool:
    """Whether `torch.compile` or `torch.export` is tracing (or any of `tensors` is a fake
    tensor made for tracing): value checks are skipped then, since a traced graph cannot branch
    on tensor values; eager calls check them."""
    if torch.compiler.is_compiling() or torch.compiler.is_exporting():
        return True
    return any(type(t).__name__ == "FakeTensor" for t in tensors)


def check_positive(name: str, value: Tensor, unit: str = "") -> None:
    """Raise `ValueError` unless every entry of `value` is finite and > 0."""
    if is_tracing(value):
        return
    if not bool(torch.all(torch.isfinite(value) & (value > 0))):
        suffix = f" ({unit})" if unit else ""
        raise ValueError(f"{name} must be finite and > 0{suffix}, got {_describe(value)}")


def check_depth(name: str, depth: Tensor) -> None:
    """Depth maps must be tensors of positive, non-NaN metres (`inf` is allowed: far away)."""
    if not isinstance(depth, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor of depths in metres, got {type(depth)}")
    if not depth.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor, got dtype {depth.dtype}")
    if is_tracing(depth):
        return
    if bool(torch.any(torch.isnan(depth) | (depth <= 0))):
        raise ValueError(
            f"{name} must be > 0 metres and not NaN everywhere, got {_describe(depth)}; "
            "mask invalid pixels or fill them before rendering"
        )


def check_shape(name: str, tensor: Tensor, dims: Sequence[str]) -> None:
    """Check `tensor` against named dimensions, e.g. `["B", "C", "H", "W"]`.

    A dimension given as a digit string (`"1"`, `"3"`) must have exactly that size.
    """
    if not isinstance(tensor, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(tensor).__name__}")
    if tensor.ndim != len(dims) or any(
        d.isdigit() and int(d) != s for d, s in zip(dims, tensor.shape, strict=False)
    ):
        raise ValueError(f"{name} must have shape ({', '.join(dims)}), got {tuple(tensor.shape)}")


def broadcast_to_batch(param: Tensor, like: Tensor) -> Tensor:
    """Reshape a 0-d or `(B,)` parameter to broadcast against `like` (batch first).

    The result follows `like`'s device and dtype.
    """
    param = param.to(device=like.device, dtype=like.dtype)
    if param.ndim == 1 and like.ndim > 1:
        param = param.reshape(-1, *([1] * (like.ndim - 1)))
    return param


def format_param(value: Tensor) -> str:
    """Short human-readable form of a parameter for `__repr__` and messages."""
    values = value.detach().reshape(-1).tolist()
    text = ", ".join(f"{v:.6g}" for v in values)
    return text if value.ndim == 0 else f"[{text}]"


def register_physical(module: nn.Module, name: str, value: ParamLike, unit: str = "") -> None:
    """Store a physical parameter on `module`: an `nn.Parameter` stays one, anything else is a
    buffer, so `.to()`, `state_dict` and optimisers work either way."""
    tensor = as_parameter_tensor(name, value)
    check_positive(name, tensor.detach(), unit)
    if isinstance(value, nn.Parameter):
        module.register_parameter(name, value)
    else:
        module.register_buffer(name, tensor)
