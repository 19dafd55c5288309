"""Public input checks for camera parameters, images and depth maps (used by every package).

Every check raises a `ValueError` or `TypeError` whose message names the argument, the value
received and what is allowed. Messages are only formatted on failure.

Values are checked once, where they enter (a value type's constructor, a public entry such as
`render_defocus` or `Camera.render`); code behind that door trusts them. The tensor checks
(shapes, and scans of tensor values for NaN, infinity or range) can be turned off for a hot
path with `set_checks(False)` or inside `with checks_disabled():`, as Kornia's
`disable_checks`, or for the whole process with the environment variable `OPTICS_CHECKS=0`
(read once, at import). Checks of plain Python numbers and option values stay on.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import numbers
import os
import warnings
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

ParamLike = float | int | Tensor | Sequence[float]

_ENABLED = os.environ.get("OPTICS_CHECKS", "1").strip().lower() not in ("0", "false", "off", "no")


def set_checks(enabled: bool) -> bool:
    """Turn the tensor checks of the whole process on or off; returns the previous state.

    With the checks off, shapes and tensor values (NaN, infinity, ranges, a camera parameter
    moved by an optimiser) are trusted: for a hot path whose inputs were checked where they
    entered. Checks of Python numbers and options stay on. `OPTICS_CHECKS=0` in the environment
    starts the process with them off.

    Example:
        >>> previous = set_checks(False)
        >>> render_input = torch.tensor([float("nan")])
        >>> check_finite("image", render_input)  # trusted: no error
        >>> _ = set_checks(previous)
    """
    global _ENABLED
    previous, _ENABLED = _ENABLED, bool(enabled)
    return previous


@contextlib.contextmanager
def checks_disabled() -> Iterator[None]:
    """The tensor checks off inside the block (`set_checks`), restored after it.

    Example:
        >>> with checks_disabled():
        ...     check_shape("image", torch.zeros(3), ["B", "C", "H", "W"])  # trusted
        >>> check_shape("image", torch.zeros(3), ["B", "C", "H", "W"])
        Traceback (most recent call last):
        ...
        ValueError: image must have shape (B, C, H, W), got (3,)
    """
    previous = set_checks(False)
    try:
        yield
    finally:
        set_checks(previous)


def _describe(value: object) -> str:
    if isinstance(value, Tensor):
        if value.numel() <= 6:  # as the user gave them, not a tensor's repr
            values = value.detach().cpu().reshape(-1).tolist()
            return f"{values[0]:.6g}" if value.ndim == 0 else \
                "[" + ", ".join(f"{v:.6g}" for v in values) + "]"
        bad = value.detach()
        return (
            f"a tensor of shape {tuple(value.shape)} (min {bad.min().item():.4g}, "
            f"max {bad.max().item():.4g}, NaN count {int(torch.isnan(bad).sum())})"
        )
    return repr(value)


def _real_tensor(name: str, value: object) -> tuple[Tensor | None, str]:
    """`value` as a tensor (None where it is no real number, tensor or list of them), and the
    refusal to give where it is None."""
    if isinstance(value, Tensor):
        real = not (value.dtype == torch.bool or value.is_complex())
        return (value if real else None), f"{name} must hold real numbers, got a tensor of dtype {value.dtype}"
    if isinstance(value, bool | np.bool_):
        return None, f"{name} must be a number or a tensor, got bool {value!r}"
    if isinstance(value, str | bytes):
        return None, (f"{name} must be a number (metres where it is a length), a 0-d or (B,) "
                      f"tensor or a list of numbers, got the string {value!r}; convert it first, "
                      f"e.g. float({value!r})")
    if is_real_number(value):  # Python's or numpy's
        return torch.tensor(float(value), dtype=torch.float64), ""
    if isinstance(value, np.ndarray):
        ok = value.dtype.kind in "iuf"
        return (torch.from_numpy(np.asarray(value, dtype=np.float64)) if ok else None), \
            f"{name} must hold real numbers, got an array of dtype {value.dtype}"
    if not isinstance(value, Sequence):
        return None, (f"{name} must be a float, a 0-d or (B,) tensor or a list of floats, "
                      f"got {type(value).__name__}")
    strings = any(isinstance(v, str | bytes | bool) for v in value)
    problem = f"{name} must hold numbers, got {value!r}" + ("; convert strings first" if strings else "")
    try:
        return (None if strings else torch.tensor([float(v) for v in value], dtype=torch.float64)), problem
    except (TypeError, ValueError):
        return None, problem


def as_parameter_tensor(name: str, value: ParamLike) -> Tensor:
    """Turn a camera parameter (a number, Python's or numpy's; a 0-d or `(B,)` tensor or numpy
    array; a list) into a tensor.

    Tensors keep their device, dtype and `requires_grad`; Python numbers become float64 tensors so
    that no precision is lost before they are cast to the input's dtype (in `broadcast_to_batch`).

    Example:
        >>> as_parameter_tensor("f_number", [2.0, 2.8])
        tensor([2.0000, 2.8000], dtype=torch.float64)
        >>> as_parameter_tensor("f_number", [])
        Traceback (most recent call last):
        ...
        ValueError: f_number must hold at least one value (a scalar or a (B,) tensor with B >= 1), got shape (0,)
    """
    tensor, problem = _real_tensor(name, value)
    if tensor is None:
        raise TypeError(problem)
    if not tensor.is_floating_point():
        tensor = tensor.to(torch.get_default_dtype())
    if tensor.ndim > 1 or tensor.numel() == 0:
        raise ValueError(f"{name} must {'be' if tensor.numel() else 'hold at least one value'} "
                         f"(a scalar or a (B,) tensor with B >= 1), got shape {tuple(tensor.shape)}")
    return tensor


_VALUES_CHECKED = contextvars.ContextVar("optics_values_checked", default=False)


def values_checked() -> contextlib.AbstractContextManager[None]:
    """Skip the checks that read tensor values inside the block, as under tracing: for code
    whose inputs were checked where they entered (e.g. a training batch checked on the host
    when it was prepared) and whose results are checked once at the end (the training step's
    finite loss). Reading a value from a GPU waits for every queued kernel; shapes, types and
    names are still checked (`checks_disabled` skips those too).

    Example:
        >>> with values_checked():
        ...     check_tensor("f_number", torch.tensor([-1.0]), values="positive")  # not read
    """
    if torch.compiler.is_compiling():  # traced code reads no values, and a graph may not
        return contextlib.nullcontext()  # set a context variable
    return _values_checked()


@contextlib.contextmanager
def _values_checked() -> Iterator[None]:
    token = _VALUES_CHECKED.set(True)
    try:
        yield
    finally:
        _VALUES_CHECKED.reset(token)


def is_tracing(*tensors: Tensor) -> bool:
    """Whether tensor values are not to be read: `torch.compile` or `torch.export` is tracing
    (or any of `tensors` is a fake tensor made for tracing: a traced graph cannot branch on
    tensor values), the block is `values_checked`, or the checks are off (`set_checks`)."""
    if torch.compiler.is_compiling() or torch.compiler.is_exporting():
        return True  # first: a traced graph must not read the context variable
    if _VALUES_CHECKED.get() or not _ENABLED:
        return True
    return any(type(t).__name__ == "FakeTensor" for t in tensors)


def is_real_number(value: object) -> bool:
    """Whether `value` is a real number, Python's or numpy's, and not a bool.

    Example:
        >>> is_real_number(2.8), is_real_number(True), is_real_number("2.8")
        (True, False, False)
    """
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


#: `check_tensor`'s value rules: what holds everywhere, as the message says it, and a hint.
VALUE_RULES: dict[str, tuple[Callable[[Tensor], Tensor], str, str]] = {
    "positive": (lambda t: torch.isfinite(t) & (t > 0), "finite and > 0", ""),
    "depth": (lambda t: ~torch.isnan(t) & (t > 0), "> 0 metres and not NaN everywhere",
              "; mask invalid pixels or fill them before rendering"),
    "coc": (lambda t: torch.isfinite(t) & (t >= 0), "finite and >= 0", ""),
    "signed coc": (torch.isfinite, "finite (signed: negative nearer than the focus plane)", ""),
    "nonnegative": (lambda t: t >= 0, ">= 0 and not NaN", ""),  # NaN fails; inf allowed
}


def check_tensor(name: str, value: object, dims: Sequence[str] | None = None, *,
                 floating: bool = False, values: str | None = None, unit: str = "") -> None:
    """The door check of a tensor argument: a `torch.Tensor`, of named dimensions `dims` (a
    digit string such as `"1"` must be exactly that size), floating-point where `floating`,
    and whose values follow `values`: `"finite"` (`check_finite`), or a rule of `VALUE_RULES`
    (`"positive"`: finite and > 0, named with its `unit`; `"depth"`: > 0 metres and not NaN,
    `inf` allowed; `"coc"`: finite and >= 0; `"nonnegative"`: >= 0, `inf` allowed). Shapes and values are trusted while the checks are off (`set_checks`);
    values while tracing or `values_checked`.

    Raises:
        TypeError: not a tensor, or not floating-point where `floating`.
        ValueError: another shape, or values that break the rule (described).

    Example:
        >>> check_tensor("depth", torch.ones(1, 1, 4, 4), ["B", "1", "H", "W"], values="depth")
        >>> check_tensor("f_number", torch.tensor([2.0, -1.0]), values="positive")
        Traceback (most recent call last):
        ...
        ValueError: f_number must be finite and > 0, got [2, -1]
    """
    if not isinstance(value, Tensor) or (floating and not value.is_floating_point()):
        got = f"dtype {value.dtype}" if isinstance(value, Tensor) else type(value).__name__
        raise TypeError(f"{name} must be a {'floating-point ' if floating else ''}torch.Tensor, "
                        f"got {got}")
    if not _ENABLED:
        return
    if dims is not None and (value.ndim != len(dims) or any(
            d.isdigit() and int(d) != s for d, s in zip(dims, value.shape, strict=False))):
        raise ValueError(f"{name} must have shape ({', '.join(dims)}), got {tuple(value.shape)}")
    if values == "finite":
        check_finite(name, value)
    elif values is not None and not is_tracing(value):
        require(name, value, values, unit)


def require(name: str, value: Tensor, rule: str, unit: str = "") -> None:
    """Raise `ValueError` unless `value` follows `VALUE_RULES[rule]` everywhere, whether or not
    the checks are off (for values given as Python numbers, and explicit checks).

    Example:
        >>> require("scale", torch.tensor(0.0), "positive")
        Traceback (most recent call last):
        ...
        ValueError: scale must be finite and > 0, got 0
    """
    holds, text, hint = VALUE_RULES[rule]
    if not bool(torch.all(holds(value.detach()))):
        unit = f" ({unit})" if unit else ""
        raise ValueError(f"{name} must be {text}{unit}, got {_describe(value)}{hint}")


def check_shape(name: str, tensor: Tensor, dims: Sequence[str]) -> None:
    """Check `tensor` against named dimensions, e.g. `["B", "C", "H", "W"]` (`check_tensor`).

    A dimension given as a digit string (`"1"`, `"3"`) must have exactly that size.
    """
    check_tensor(name, tensor, dims)


def check_finite(name: str, tensor: Tensor) -> None:
    """Raise `ValueError` if `tensor` holds a NaN or an infinity, naming `name`, how many and
    where the first one is (one reduction when all is well; skipped while tracing, or with the
    checks off).

    Example:
        >>> check_finite("image", torch.tensor([[0.5, float("nan")]]))
        Traceback (most recent call last):
        ...
        ValueError: image has 1 NaN and 0 infinite value(s), the first at index (0, 1); ...
    """
    if not isinstance(tensor, Tensor) or not tensor.is_floating_point() or is_tracing(tensor):
        return
    values = tensor.detach()
    # a NaN or an infinity makes the sum NaN or infinite; the sum holds no temporary of the
    # tensor's size, unlike isfinite() (4 GB spared on two 100-megapixel photos). Only a sum
    # that overflows (huge finite values) needs the value-by-value check.
    if bool(torch.isfinite(values.sum(dtype=torch.promote_types(values.dtype, torch.float32)))) \
            or bool(torch.isfinite(values).all()):
        return
    nan = int(torch.isnan(values).sum())
    inf = int(torch.isinf(values).sum())
    first = tuple(int(i) for i in torch.nonzero(~torch.isfinite(values))[0].tolist())
    raise ValueError(
        f"{name} has {nan} NaN and {inf} infinite value(s), the first at index {first}; "
        f"{name} must be finite everywhere (a NaN spreads over the whole blur window); "
        "replace or mask those pixels before passing it"
    )


#: Values above which a length looks like millimetres given for metres (`warn_unit`).
UNIT_LIMITS = {"focal_length": 2.0, "pixel_pitch": 1e-3}
_UNIT_WARNINGS = contextvars.ContextVar("optics_unit_warnings", default=True)


@contextlib.contextmanager
def no_unit_warnings() -> Iterator[None]:
    """Turn `warn_unit` off inside the block (e.g. for the *effective* pitch of a heavily
    downsampled image, which may legitimately exceed 1 mm)."""
    if torch.compiler.is_compiling():  # traced code warns of nothing (`warn_unit`)
        yield
        return
    token = _UNIT_WARNINGS.set(False)
    try:
        yield
    finally:
        _UNIT_WARNINGS.reset(token)


def implausible_length(name: str, value: Tensor) -> float | None:
    """The largest of `value` (metres) where it exceeds `UNIT_LIMITS[name]`, so probably was
    given in millimetres; None where it does not, or `name` has no limit."""
    limit = UNIT_LIMITS.get(name)
    largest = float(value.detach().max())
    return largest if limit is not None and largest > limit else None


def warn_unit(name: str, value: Tensor) -> None:
    """Warn (`UserWarning`) when a length is implausibly large for metres: a focal length over
    2 m or a pixel pitch over 1 mm ("did you give millimetres?"). Other names are not checked."""
    if name not in UNIT_LIMITS or is_tracing(value) or not _UNIT_WARNINGS.get():
        return
    largest = implausible_length(name, value)
    if largest is not None:
        limit = UNIT_LIMITS[name]
        warnings.warn(
            f"{name} is {largest:.6g} m, more than {limit:g} m: did you give millimetres? "
            f"Lengths are in metres (e.g. {name}={largest * 1e-3:.6g} for {largest:.6g} mm)",
            UserWarning,
            stacklevel=4,  # the caller of ThinLens(...) or Sensor(...)
        )


def check_parameters(module: nn.Module, units: dict[str, str],
                     also: Tensor | None = None) -> bool:
    """Re-check a module's physical parameters at use (an optimiser step may have moved an
    `nn.Parameter` out of range after construction): every value finite and > 0.

    One reduction over all of them (and the 0-d boolean `also`, a further condition of the
    caller's) when all is well; the failing parameter is named otherwise. Skipped while tracing
    or with the checks off (`set_checks`).

    Returns:
        whether `also` holds too (`True` while skipped); the caller raises its own error if not.
    """
    tensors = [getattr(module, name) for name in units]
    if is_tracing(*tensors):
        return True
    if len({t.device for t in tensors}) == 1:
        values = torch.cat([t.detach().reshape(-1) for t in tensors])
        ok = (values > 0).all() & (values < float("inf")).all()  # NaN fails both
        if also is not None:
            ok = ok & also.detach()
        if bool(ok):
            return True
    for (name, unit), tensor in zip(units.items(), tensors, strict=True):
        try:
            check_tensor(f"{type(module).__name__}.{name}", tensor, values="positive", unit=unit)
        except ValueError as error:
            raise ValueError(
                f"{error} at use (it was valid when the {type(module).__name__} was built: was it "
                "changed since, e.g. by an optimiser step? Fit it in log space or clamp it)"
            ) from None
    return also is None or bool(also)


def check_depth_bounds(low: object, high: object, names: tuple[str, str] = ("min_depth", "max_depth"),
                       why: str = "", high_optional: bool = False) -> None:
    """Refuse a lower depth bound that is not a finite number >= 0 metres, and an upper bound
    not above it (infinity allowed; `None` too where `high_optional`). `why` is added to the
    lower bound's message.

    Example:
        >>> check_depth_bounds(0.0, float("inf"))
        >>> check_depth_bounds(2.0, 1.0, names=("min_depth", "depth_cap"))
        Traceback (most recent call last):
        ...
        ValueError: depth_cap must be a depth > min_depth (2.0) metres (infinity allowed), got 1.0
    """
    low_name, high_name = names
    low_ok = is_real_number(low) and np.isfinite(low) and low >= 0
    if not low_ok or not ((high is None and high_optional) or (is_real_number(high) and high > low)):
        none = "None or " if high_optional else ""
        raise ValueError(f"{low_name} must be a finite depth >= 0 metres{why}, got {low!r}"
                         if not low_ok else f"{high_name} must be {none}a depth > {low_name} "
                         f"({low!r}) metres (infinity allowed), got {high!r}")


def check_param_batch(module: nn.Module, name: str, shape: Sequence[int]) -> None:
    """Refuse a `(B,)` parameter or buffer of `module` whose `B` is neither 1 nor the batch size
    `shape[0]` of the input it must broadcast against (shapes only: nothing is read from the
    device; the message is formatted only on failure; trusted with the checks off).

    Args:
        module: the module holding the parameters (`ThinLens`, `Sensor`; named in the message).
        name: the input, as the message names it (e.g. `"depth"`).
        shape: the input's shape, batch first.

    Raises:
        ValueError: naming the parameter, its number of values, the input and what is allowed.

    Example:
        >>> from optics import ThinLens
        >>> lens = ThinLens([0.05, 0.05, 0.05], 2.0, 2.0)
        >>> check_param_batch(lens, "depth", (2, 1, 8, 8))
        Traceback (most recent call last):
        ...
        ValueError: ThinLens.focal_length has 3 values (one per batch item), which does not broadcast against depth (2, 1, 8, 8): give one value, or 2 (one per batch item)
    """
    if not _ENABLED:
        return
    batch = shape[0]
    own = (*module.named_parameters(recurse=False), *module.named_buffers(recurse=False))
    for param, value in own:
        if value.ndim == 1 and value.shape[0] not in (1, batch):
            raise ValueError(
                f"{type(module).__name__}.{param} has {value.shape[0]} values (one per batch "
                f"item), which does not broadcast against {name} {tuple(shape)}: give one value"
                + ("" if batch == 1 else f", or {batch} (one per batch item)")
            )


def broadcast_to_batch(param: Tensor, like: Tensor) -> Tensor:
    """Reshape a 0-d or `(B,)` parameter to broadcast against `like` (batch first).

    The result follows `like`'s device, and its dtype where `like` is floating-point (an
    integer `like` keeps the parameter's dtype: a pitch of 5e-6 m cast to an integer is 0).

    Example:
        >>> broadcast_to_batch(torch.tensor([1.5, 2.5]), torch.zeros(2, 1, 4, 4)).shape
        torch.Size([2, 1, 1, 1])
        >>> broadcast_to_batch(torch.tensor(5e-6), torch.tensor([3])).dtype
        torch.float32
    """
    dtype = like.dtype if like.is_floating_point() else param.dtype
    param = param.to(device=like.device, dtype=dtype)
    if param.ndim == 1 and like.ndim > 1:
        param = param.reshape(-1, *([1] * (like.ndim - 1)))
    return param


def format_param(value: Tensor) -> str:
    """Short human-readable form of a parameter for `__repr__` and messages."""
    values = value.detach().reshape(-1).tolist()
    text = ", ".join(f"{v:.6g}" for v in values)
    return text if value.ndim == 0 else f"[{text}]"


def register_physical(module: nn.Module, units: dict[str, str], values: dict[str, ParamLike]) -> None:
    """Store physical parameters on `module` (`units` by name, e.g. `{"f_number": ""}`; the
    `values` by the same names): an `nn.Parameter` stays one, anything else is a buffer, so
    `.to()`, `state_dict` and optimisers work either way. Each must be finite and > 0 (Python
    numbers always; tensors unless the checks are off), and the `(B,)` ones of one `B`.
    """
    for name, unit in units.items():
        value = values[name]
        tensor = as_parameter_tensor(name, value)
        if isinstance(value, Tensor) or torch.compiler.is_compiling():
            check_tensor(name, tensor, values="positive", unit=unit)
        else:  # numbers: always checked
            require(name, tensor, "positive", unit)
        warn_unit(name, tensor)
        if isinstance(value, nn.Parameter):
            module.register_parameter(name, value)
        else:
            module.register_buffer(name, tensor)
    sizes = {name: getattr(module, name).numel() for name in units if getattr(module, name).ndim == 1}
    if len(set(sizes.values()) - {1}) > 1:
        names = list(units)
        raise ValueError(f"{', '.join(names[:-1])} and {names[-1]} must be one value or one per "
                         f"batch item (the same B), got sizes {sizes}")


def check_setting_entry(source: str, key: str, value: Any, unit: str = "") -> None:
    """Refuse a camera file's entry `key` unless it is a finite number > 0 or a list of them
    (at most `(B, F)`), naming the file and the key as written and the value as JSON writes it.

    Example:
        >>> check_setting_entry("cam.json", "f_number", [8.3, 2.0])
        >>> check_setting_entry("cam.json", "f_number", float("nan"))
        Traceback (most recent call last):
        ...
        ValueError: cam.json: "f_number" must be a finite number > 0 or a list of them (one per shot), got NaN
    """
    try:
        ok = not isinstance(value, (bool, str)) and all(
            not isinstance(v, bool) for v in (value if isinstance(value, list) else [value]))
        tensor = torch.as_tensor(value, dtype=torch.float64)
        ok = ok and tensor.ndim <= 2 and bool(torch.all(torch.isfinite(tensor) & (tensor > 0)))
    except (TypeError, ValueError, RuntimeError):
        ok = False
    if not ok:
        try:
            shown = json.dumps(value)
        except (TypeError, ValueError):
            shown = repr(value)
        unit = f", {unit}" if unit else ""
        raise ValueError(f'{source}: "{key}" must be a finite number > 0{unit} or a list of '
                         f"them (one per shot), got {shown}")
