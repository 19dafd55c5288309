"""A camera: one shot (`Camera`: a lens, a sensor and an aperture shape, composed) and the F
shots of a scene (`CameraSettings`, the one type every package passes).

A scene is photographed `F` times (e.g. focused at 2 m and at 6 m). Dataset samples, camera
presets, raw-photo metadata, calibration results, losses, networks, the direct fit and
`defocus predict` all describe those shots with one `CameraSettings`: four tensors of shape `(F,)`
for one scene or `(B, F)` for a batch, plus the aperture's spec string (see
`optics.aperture_spec`). A shot of it is a `Camera` (`CameraSettings.shot`), and a `Camera`'s
settings are a `CameraSettings` of one shot (`Camera.settings`): the two convert into each other,
so they share this module. The thin-lens maths lives in `ThinLens`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
from collections.abc import Mapping
from os import PathLike
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from .aperture import Aperture, Gaussian
from .aperture_spec import DEFAULT_APERTURE, aperture_from_json, aperture_spec, parse_aperture
from .checks import (
    check_param_batch,
    check_setting_entry,
    check_tensor,
    implausible_length,
    is_real_number,
    is_tracing,
    require,
)
from .lens import ThinLens
from .sensor import Sensor


class Camera(nn.Module):
    """Thin lens + sensor + aperture: maps depth (metres) to CoC (pixels) and renders defocus.

    Args:
        lens: the `ThinLens` (focal length, f-number, focus distance in metres).
        sensor: the `Sensor` (pixel pitch in metres, downsampling).
        aperture: PSF shape; `Gaussian` (`sigma = 0.5 * CoC`) by default.

    Example:
        >>> camera = Camera(ThinLens(0.035, 2.8, 2.0), Sensor(5.6e-6, downsample=4))
        >>> camera.coc_px(torch.tensor([1.0, 2.0, 8.0]))
        tensor([9.9396, 0.0000, 7.4547])
    """

    def __init__(self, lens: ThinLens, sensor: Sensor, aperture: Aperture | None = None):
        super().__init__()
        aperture = Gaussian() if aperture is None else aperture
        for name, value, cls in (("lens", lens, ThinLens), ("sensor", sensor, Sensor),
                                 ("aperture", aperture, Aperture)):
            if not isinstance(value, cls):
                raise TypeError(f"{name} must be a{'n' if name == 'aperture' else ''} "
                                f"{cls.__name__}, got {type(value).__name__}")
        self.lens, self.sensor, self.aperture = lens, sensor, aperture

    def settings(self) -> CameraSettings:
        """This camera's settings as `CameraSettings` of one shot per batch item.

        Raises:
            ValueError: if the aperture has no spec string (a `Mask`).

        Example:
            >>> from optics import Disk
            >>> Camera(ThinLens(0.035, 2.8, 2.0), Sensor(5.6e-6), Disk()).settings().aperture
            'disk'
        """
        return CameraSettings(
            self.lens.focal_length, self.lens.f_number, self.lens.focus_distance,
            self.sensor.effective_pixel_pitch, aperture=aperture_spec(self.aperture),
        )

    def to_json(self, path: str | PathLike, **extra: Any) -> None:
        """Write the camera's settings (metres), its PSF spec and any `extra` JSON values."""
        self.settings().to_json(path, **extra)

    @classmethod
    def from_json(cls, path: str | PathLike) -> Camera:
        """Load a camera written by `to_json` (or a calibration's JSON).

        Example:
            >>> import tempfile, pathlib
            >>> from optics import Disk
            >>> path = pathlib.Path(tempfile.mkdtemp()) / "camera.json"
            >>> Camera(ThinLens(0.035, 2.8, 2.0), Sensor(5.6e-6), Disk()).to_json(path)
            >>> Camera.from_json(path).lens.f_number
            tensor(2.8000, dtype=torch.float64)
        """
        settings = CameraSettings.from_json(path)
        if settings.n_shots != 1:
            raise ValueError(f"{path}: holds {settings.n_shots} shots; read it with "
                             "CameraSettings.from_json and pick one with .shot(i)")
        return settings.shot(0)

    def coc_px(self, depth: Tensor) -> Tensor:
        """CoC diameter in (effective) pixels for depths in metres (same shape as `depth`).

        Computed in `depth`'s dtype promoted to at least float32 (a `float16`/`bfloat16` depth
        gives a float32 map, so every camera parameter gets a finite gradient); `render` casts
        it to the image's dtype.

        Raises:
            ValueError: if a lens or sensor value is no longer finite and > 0 (e.g. after an
                optimiser step), naming it, or `depth` is not > 0 or NaN.
        """
        return self.sensor.to_pixels(self.lens.coc_diameter(depth))

    def signed_coc_px(self, depth: Tensor) -> Tensor:
        """Signed CoC diameter in pixels: negative in front of the focus plane."""
        return self.sensor.to_pixels(self.lens.signed_coc_diameter(depth))

    def forward(self, depth: Tensor) -> Tensor:
        return self.coc_px(depth)

    def render(self, image: Tensor, depth: Tensor, **kwargs: Any) -> Tensor:
        """Render `image` `(B,C,H,W)` as this camera sees a scene of `depth` `(B,1,H,W)`.

        Keyword arguments go to `optics.render_defocus` (`mode`, `max_kernel_size`, ...).

        Raises:
            ValueError: for a NaN or infinite pixel in `image` (named, with its position), an
                invalid depth, a camera value out of range or of a batch other than 1 or B (named).
        """
        from .render.renderer import IMAGE_DIMS, per_pixel_map, render_trusted

        check_tensor("image", image, IMAGE_DIMS, floating=True)
        depth_map = per_pixel_map("depth", depth, image)  # named as given, before it is a CoC map
        for part in (self.lens, self.sensor):
            check_param_batch(part, "image", image.shape)
        coc_px = self.signed_coc_px if self.aperture.oriented else self.coc_px  # a Mask: signed
        coc = coc_px(depth).to(image.dtype).expand_as(depth_map)  # checks depth's values
        return render_trusted(image, coc, self.aperture, depth=depth_map, depth_checked=True,
                              **kwargs)


#: The tensor fields of `CameraSettings`, each in metres except the f-number.
SETTING_FIELDS = ("focal_length", "f_number", "focus_distance", "pixel_pitch")
_UNITS = {"focal_length": "metres", "f_number": "", "focus_distance": "metres",
          "pixel_pitch": "metres"}


def _shortest(value: float, dtype: torch.dtype) -> float:
    """`value` as the shortest decimal that reads back as the same `dtype` number: a float32
    setting of 2.8 is written 2.8, not 2.799999952316284.

    Example:
        >>> _shortest(float(torch.tensor(2.8, dtype=torch.float32)), torch.float32)
        2.8
    """
    if dtype not in (torch.float32, torch.float16) or not math.isfinite(value):
        return value
    import numpy as np

    kind = np.float32 if dtype == torch.float32 else np.float16
    return float(np.format_float_positional(kind(value), unique=True, trim="-"))


def _as_tensor(name: str, value: Any) -> Tensor:
    tensor = value if isinstance(value, Tensor) else None
    if tensor is None and not isinstance(value, bool | str):
        with contextlib.suppress(TypeError, ValueError, RuntimeError):
            tensor = torch.as_tensor(value, dtype=torch.float64)
    if tensor is None:
        raise TypeError(f"{name} must be a number, a sequence of numbers or a tensor, "
                        f"got {type(value).__name__} {value!r}")
    if not tensor.is_floating_point():
        tensor = tensor.to(torch.get_default_dtype())
    return tensor


@dataclasses.dataclass
class CameraSettings:
    """Settings of the `F` shots of one scene (`(F,)` tensors) or of a batch (`(B, F)`).

    Numbers and sequences are accepted and broadcast against each other: one focal length for
    every shot, one focus distance per shot, and so on. Python numbers become float64 tensors;
    move the result with `.to()`.

    Args:
        focal_length: metres, > 0.
        f_number: dimensionless, > 0.
        focus_distance: metres, > `focal_length`.
        pixel_pitch: the *effective* pixel pitch of the images in metres (sensor pitch times
            the downsampling from sensor to image), > 0.
        aperture: the PSF shape as a spec string (`"gaussian"`, `"disk"`, `"polygon:6"`, see
            `optics.aperture_spec`); the same for every shot. `DEFAULT_APERTURE` (the paper's
            Gaussian) by default.

    Example:
        >>> settings = CameraSettings(0.05, 1.4, [2.0, 6.0], 180e-6)
        >>> settings.n_shots, tuple(settings.shape)
        (2, (2,))
        >>> settings.shot(1).lens.focus_distance
        tensor(6., dtype=torch.float64)
        >>> from optics import collate
        >>> batch = collate([settings, settings])
        >>> tuple(batch.focus_distance.shape)
        (2, 2)
    """

    focal_length: Tensor
    f_number: Tensor
    focus_distance: Tensor
    pixel_pitch: Tensor
    aperture: str = DEFAULT_APERTURE

    def __post_init__(self) -> None:
        numbers = not all(isinstance(getattr(self, name), Tensor) for name in SETTING_FIELDS)
        values = [_as_tensor(name, getattr(self, name)) for name in SETTING_FIELDS]
        dtype = values[0].dtype
        for v in values[1:]:
            dtype = torch.promote_types(dtype, v.dtype)
        shapes = {n: tuple(v.shape) for n, v in zip(SETTING_FIELDS, values, strict=True)}
        with contextlib.suppress(RuntimeError):
            values = [v.reshape(1) if v.ndim == 0 else v
                      for v in torch.broadcast_tensors(*(v.to(dtype) for v in values))]
        if len({tuple(v.shape) for v in values}) > 1 or values[0].ndim > 2 \
                or values[0].numel() == 0:
            raise ValueError(f"camera settings must broadcast to one shape (F,) or (B, F) with "
                             f"F >= 1, got shapes {shapes}")
        for name, value in zip(SETTING_FIELDS, values, strict=True):
            object.__setattr__(self, name, value)
        if not isinstance(self.aperture, str):
            raise TypeError(f"aperture must be a spec string such as 'gaussian' or 'disk', got "
                            f"{type(self.aperture).__name__}; pass an Aperture object to the "
                            f"renderer instead")
        tracing = torch.compiler.is_compiling() or torch.compiler.is_exporting()
        if not tracing:
            self.aperture = aperture_spec(self.aperture)
        if (numbers and not tracing) or not is_tracing(*values):  # numbers: always checked
            self.check()

    def check(self) -> None:
        """Raise `ValueError` unless every value is finite and positive and every focus
        distance lies beyond the focal length (called on construction; call it again after
        changing a tensor in place)."""
        for name in SETTING_FIELDS:
            require(name, getattr(self, name), "positive", _UNITS[name])
        if bool(torch.any(self.focus_distance <= self.focal_length)):
            largest = implausible_length("focal_length", self.focal_length)
            hint = ("" if largest is None else
                    f": did you give millimetres? {largest:.6g} mm is {largest * 1e-3:.6g} m")
            raise ValueError(
                f"focus_distance must be > focal_length (metres), got focus_distance "
                f"{self.focus_distance.tolist()} and focal_length {self.focal_length.tolist()}"
                f"{hint}"
            )

    # ---- shape -------------------------------------------------------------------------------
    @property
    def shape(self) -> torch.Size:
        """`(F,)` or `(B, F)`."""
        return self.focus_distance.shape

    @property
    def n_shots(self) -> int:
        """`F`, the number of shots (focus settings)."""
        return int(self.shape[-1])

    @property
    def is_batched(self) -> bool:
        return len(self.shape) == 2

    def tensors(self) -> dict[str, Tensor]:
        """The four tensors by field name."""
        return {name: getattr(self, name) for name in SETTING_FIELDS}

    def _map(self, fn) -> CameraSettings:
        return dataclasses.replace(self, **{k: fn(v) for k, v in self.tensors().items()})

    def to(self, *args: Any, **kwargs: Any) -> CameraSettings:
        """Move or cast every tensor, as `Tensor.to` (`non_blocking=True` too)."""
        return self._map(lambda t: t.to(*args, **kwargs))

    def pin_memory(self) -> CameraSettings:
        """The settings with their tensors in page-locked memory (what a `DataLoader` with
        `pin_memory=True` calls), so that `.to("cuda", non_blocking=True)` does not wait."""
        return self._map(lambda t: t.contiguous().pin_memory())  # broadcast fields too

    def replace(self, **changes: Any) -> CameraSettings:
        """A copy with some fields changed (checked again).

        Example:
            >>> CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-5).replace(f_number=4.0).f_number
            tensor([4., 4.], dtype=torch.float64)
        """
        return dataclasses.replace(self, **changes)

    def batched(self, batch_size: int = 1) -> CameraSettings:
        """`(F,)` settings repeated into `(batch_size, F)` (batched settings are returned as they are)."""
        if self.is_batched:
            return self
        return self._map(lambda t: t.expand(batch_size, -1))

    def __getitem__(self, index: Any) -> CameraSettings:
        """Index the batch (the first dimension of `(B, F)` settings; keeps `(B', F)` or `(F,)`)."""
        if not self.is_batched:
            raise IndexError("index unbatched (F,) settings with .shot(i); [] indexes a batch")
        return self._map(lambda t: t[index])

    def select_shots(self, index: Any) -> CameraSettings:
        """Keep some shots (the last dimension), e.g. `select_shots([0, 2])`."""
        picked = self._map(lambda t: t[..., index])
        if picked.focus_distance.ndim < len(self.shape):
            raise IndexError("select_shots needs a slice or a list of shots; use .shot(i) for one")
        return picked

    # ---- cameras -----------------------------------------------------------------------------
    def aperture_module(self) -> Aperture:
        """The `Aperture` this spec names."""
        return parse_aperture(self.aperture)

    def shot(self, index: int, aperture: Aperture | None = None) -> Camera:
        """The `Camera` of shot `index` (scalar parameters, or `(B,)` for batched settings).

        Args:
            index: shot number in `[0, F)`.
            aperture: override the settings' aperture (e.g. a measured `Mask`).
        """
        if not -self.n_shots <= index < self.n_shots:
            raise IndexError(f"shot index {index} is out of range for {self.n_shots} shots")
        values = {k: v[..., index] for k, v in self.tensors().items()}
        return self._camera(values, aperture)

    def camera(self, aperture: Aperture | None = None) -> Camera:
        """One `Camera` over every shot, flattened in row-major order: `(B * F,)` parameters
        (or `(F,)`). Render a batch expanded the same way through it."""
        values = {k: v.reshape(-1) for k, v in self.tensors().items()}
        return self._camera(values, aperture)

    def _camera(self, values: Mapping[str, Tensor], aperture: Aperture | None) -> Camera:
        lens = ThinLens(values["focal_length"], values["f_number"], values["focus_distance"])
        return Camera(lens, Sensor.from_effective_pitch(values["pixel_pitch"]),
                      aperture if aperture is not None else self.aperture_module())

    def coc_at_infinity_px(self) -> Tensor:
        """Signed CoC diameter in pixels of a point at infinity for every shot, `A` in
        `c(D) = A (1 - D_f / D)` (same shape as the settings)."""
        lens = ThinLens(self.focal_length.reshape(-1), self.f_number.reshape(-1),
                        self.focus_distance.reshape(-1))
        coc = Sensor.from_effective_pitch(self.pixel_pitch.reshape(-1)).to_pixels(lens.coc_at_infinity())
        return coc.reshape(self.shape)

    def largest_coc_px(self, near: float, far: float) -> float:
        """The largest |CoC| diameter in pixels of any shot over depths `[near, far]` metres
        (reached at one of the two ends: the CoC is linear in inverse depth).

        Example:
            >>> round(CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4).largest_coc_px(1.0, 10.0), 3)
            10.504
        """
        if not (is_real_number(near) and is_real_number(far) and 0 < near < far):
            raise ValueError(f"near and far must be depths with 0 < near < far (metres, far may "
                             f"be infinite), got {near!r} and {far!r}")
        a = self.coc_at_infinity_px().abs().reshape(-1)
        df = self.focus_distance.reshape(-1)
        edges = torch.stack([(1 - df / near).abs(), (1 - df / far).abs()])
        return float((a * edges).max())

    # ---- JSON ----------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Plain numbers and lists (metres), and the aperture spec under `aperture`; the values
        are checked again (`check`), so that no file is written that `from_dict` refuses. One
        shot's `(1,)` settings are written as numbers, batched ones as nested lists.

        Example:
            >>> data = CameraSettings(0.05, 2.0, [2.0], 1e-5).batched(1).to_dict()
            >>> torch.tensor(data["focus_distance"]).shape  # (B, F) = (1, 1) kept
            torch.Size([1, 1])
        """
        self.check()
        data: dict[str, Any] = {}
        for name, value in self.tensors().items():
            values = [_shortest(v, value.dtype) for v in value.detach().cpu().reshape(-1).tolist()]
            data[name] = values[0] if value.numel() == 1 and not self.is_batched else \
                torch.tensor(values, dtype=torch.float64).reshape(value.shape).tolist()
        data["aperture"] = self.aperture
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "camera settings") -> CameraSettings:
        """Inverse of `to_dict`; also reads the aperture of older files, under the key `psf`
        and as a `{"family": ...}` object.

        Example:
            >>> s = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-5, "disk")
            >>> CameraSettings.from_dict(s.to_dict()) == s
            True
        """
        missing = [k for k in SETTING_FIELDS if data.get(k) is None] \
            if isinstance(data, Mapping) else list(SETTING_FIELDS)
        if missing:
            what = "" if isinstance(data, Mapping) else "expected a JSON object of camera settings, "
            raise ValueError(f"{source}: {what}missing {missing}; expected the keys "
                             f"{list(SETTING_FIELDS)} (metres) and optionally 'aperture'")
        key = "aperture" if "aperture" in data or "psf" not in data else "psf"
        try:
            aperture = aperture_spec(aperture_from_json(data.get(key, DEFAULT_APERTURE)))
        except (TypeError, ValueError) as error:
            raise ValueError(f"{source}: bad {key!r} entry {data.get(key)!r}: {error}") from None
        for key in SETTING_FIELDS:
            check_setting_entry(source, key, data[key], _UNITS[key])
        try:
            return cls(*(data[k] for k in SETTING_FIELDS), aperture=aperture)
        except (TypeError, ValueError) as error:
            raise ValueError(f"{source}: {error}") from None

    def to_json(self, path: str | PathLike, **extra: Any) -> None:
        """Write `to_dict()` and any `extra` JSON values to `path`.

        Raises:
            ValueError: an `extra` key that names a setting (or `psf`), an `aperture` entry
                for another aperture than the settings' own, or an `extra` value that is not
                finite (JSON has no NaN or infinity).
        """
        data = self.to_dict()
        taken = sorted(set(extra) & {*SETTING_FIELDS, "psf"})
        if "aperture" in extra and _spec_of_entry(extra["aperture"]) != self.aperture:
            taken.append("aperture")
        bad = {k: v for k, v in extra.items() if not _json_finite(v)}
        if taken or bad:
            raise ValueError(f"to_json extra values must not replace the settings (change them "
                             f"with .replace()) and must be finite numbers (JSON has no NaN or "
                             f"infinity), got {taken or bad}")
        data.update(extra)
        text = json.dumps(data, indent=2, allow_nan=False)
        Path(path).write_text(text + "\n")

    @classmethod
    def from_json(cls, path: str | PathLike) -> CameraSettings:
        """Read settings written by `to_json` (or by `defocus calibrate`)."""
        return cls.read_json(path)[0]

    @classmethod
    def read_json(cls, path: str | PathLike) -> tuple[CameraSettings, dict[str, Any]]:
        """The settings of a camera JSON and its extra values (those `to_json` was given, e.g.
        `reference_f_number` of a fitted camera), from one reading of the file.

        Example:
            >>> import tempfile
            >>> path = Path(tempfile.mkdtemp()) / "camera.json"
            >>> CameraSettings(0.035, 2.8, [1.7], 5.6e-5).to_json(path, reference_f_number=8.5)
            >>> settings, extra = CameraSettings.read_json(path)
            >>> extra
            {'reference_f_number': 8.5}
        """
        try:
            data = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, ValueError) as error:  # a JSON or UTF-8 error is a ValueError
            why = " is a folder: expected a camera JSON file" if Path(path).is_dir() else \
                f": cannot read camera settings: {error}"
            raise ValueError(f"{path}{why}") from None
        settings = cls.from_dict(data, source=str(path))
        known = settings.to_dict()
        return settings, {k: v for k, v in data.items() if k not in known}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CameraSettings):
            return NotImplemented
        return self.aperture == other.aperture and all(
            a.shape == b.shape and bool(torch.equal(a.to(b), b))
            for a, b in zip(self.tensors().values(), other.tensors().values(), strict=True)
        )

    __hash__ = None  # type: ignore[assignment]


def _spec_of_entry(entry: Any) -> str | None:
    """The aperture spec a JSON `aperture` entry (a spec or a `{"family": ...}` object) reads
    as, or None where it reads as none."""
    try:
        return aperture_spec(aperture_from_json(entry))
    except (TypeError, ValueError):
        return None


def _json_finite(value: Any) -> bool:
    """Whether a JSON value holds no NaN or infinity, at any depth."""
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, Mapping):
        return all(_json_finite(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return all(_json_finite(v) for v in value)
    return True


torch.export.register_dataclass(CameraSettings, serialized_type_name="optics.CameraSettings")
