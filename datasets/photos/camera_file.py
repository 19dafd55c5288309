"""The camera file: the camera JSON that `defocus calibrate` and `defocus sample` write, read by
the loaders (`camera=` of `datasets.DSLR`, the `camera.json` of a `datasets.PhotoFolder`) and by
`defocus predict --camera`, checked once where it is read (`CameraFile.read`).

A camera JSON holds the settings (`optics.CameraSettings.to_dict`) and, optionally, the
references' f-number of a fitted camera (`reference_f_number`), the blur its focused photos have
even in focus (`focus_floor_px`), the exposure gain per colour channel (`exposure_gain`) and the
focused photos' file names in the order of its shots (`photos`).

The per-shot rule, written once (`_one_per_shot`): a setting holds one value for every shot, or
one value per shot. A list of as many values as the data has shots is kept as it is, a list of
one repeated value counts as that one value, and a list of different values of another length is
refused in one line that names the file and the key (never cut to its first value).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

from optics import CameraSettings
from optics.camera import SETTING_FIELDS
from optics.checks import is_real_number

from ..io import DataFormatError, read_text, require_file


def _finite(value: Any, low: float) -> bool:
    return is_real_number(value) and math.isfinite(value) and value >= low


#: The values of a camera file besides its settings: what each must be, and how it is checked.
_EXTRAS: dict[str, tuple[str, Callable[[Any], bool]]] = {
    "reference_f_number": ("be an f-number >= 1", lambda v: _finite(v, 1)),
    "focus_floor_px": ("be a finite number of pixels >= 0", lambda v: _finite(v, 0)),
    "exposure_gain": ("list a finite gain > 0 per colour channel (1 or 3 of them)",
                      lambda v: isinstance(v, list) and len(v) in (1, 3)
                      and all(_finite(g, 0) and g > 0 for g in v)),
    "photos": ("list the focused photos' file names, in the order of the camera's shots",
               lambda v: isinstance(v, list) and len(v) > 0
               and all(isinstance(p, str) and p for p in v)),
}


def _one_per_shot(source: str, values: Mapping[str, Any], n_shots: int, shots: str,
                  given: Collection[str] = ()) -> dict[str, Any]:
    """`values` (settings by name, a number or a list per setting) by the per-shot rule for
    data of `n_shots` shots: a list of `n_shots` values is kept, a list of one repeated value
    becomes that value; a list of different values of another length is refused naming
    `source` and the key, unless the caller replaces that setting (`given`)."""
    values = dict(values)
    for key in SETTING_FIELDS:
        listed = values.get(key)
        if key in given or not isinstance(listed, list) or len(listed) in (0, n_shots) or \
                not all(is_real_number(v) for v in listed):
            continue  # one per shot, a single number, or no numbers: CameraSettings checks
        if len(set(listed)) > 1:
            raise DataFormatError(
                f'{source}: "{key}" holds {len(listed)} different values {listed}, one per '
                f"shot, but {shots} ({n_shots} shot(s)): give one value for all shots, or one "
                "per shot")
        values[key] = listed[0]  # one value repeated: the same for every shot
    return values


def settings_for_shots(settings: CameraSettings, n_shots: int, source: str = "camera",
                       shots: str = "the data") -> CameraSettings:
    """`settings` for data of `n_shots` shots by the per-shot rule: as they are where they
    have that many; where every shot is the same, that one shot repeated; else refused naming
    the setting.

    Example:
        >>> settings_for_shots(CameraSettings(0.05, [2.8, 2.8], 1.7, 6e-5), 1).n_shots
        1
    """
    if settings.n_shots == n_shots:
        return settings
    _one_per_shot(source, {k: getattr(settings, k).reshape(-1).tolist() for k in SETTING_FIELDS},
                  n_shots, shots)
    return settings.select_shots([0] * n_shots)


@dataclass(frozen=True)
class CameraFile:
    """A camera JSON, read and checked (`read`).

    Attributes:
        path: the file.
        settings: the camera's `(F,)` settings.
        reference_f_number: the f-number of the references a fitted camera was calibrated
            with (`None`: sharp references).
        focus_floor_px: the blur, pixels, the focused photos have even in focus.
        exposure_gain: the exposure gain per colour channel, defocused / reference (`None`:
            none measured).
        photos: the focused photos' file names in the order of the shots (`None`: not given).

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "camera.json"
        >>> CameraSettings(0.05, [8.3, 2.0], [1.0, 3.0], 2e-5).to_json(
        ...     path, photos=["near.png", "far.png"], focus_floor_px=1.2)
        >>> camera = CameraFile.read(path)
        >>> camera.settings.f_number.tolist(), camera.photos, camera.focus_floor_px
        ([8.3, 2.0], ('near.png', 'far.png'), 1.2)
        >>> CameraFile.read(path, n_shots=1, shots="a DSLR scene has one focused photo")
        Traceback (most recent call last):
        ...
        datasets.io.DataFormatError: ...camera.json: "f_number" holds 2 different values [8.3, 2.0], one per shot, but a DSLR scene has one focused photo (1 shot(s)): give one value for all shots, or one per shot
    """

    path: Path
    settings: CameraSettings
    reference_f_number: float | None = None
    focus_floor_px: float = 0.0
    exposure_gain: tuple[float, ...] | None = None
    photos: tuple[str, ...] | None = None

    @classmethod
    def read(cls, path: str | PathLike, n_shots: int | None = None, shots: str | None = None,
             given: Collection[str] = (), require: Collection[str] = ()) -> CameraFile:
        """Read and check a camera JSON, for data of `n_shots` shots (by default as many as
        its `"photos"` names, else any).

        Args:
            path: the camera JSON.
            n_shots: how many shots the data has (focused photos per scene).
            shots: what has them, for the error (`"a DSLR scene has one focused photo"`).
            given: settings the caller replaces (e.g. options given on the command line): the
                per-shot rule does not apply to them.
            require: values besides the settings the file must hold (e.g. `"photos"`).

        Raises:
            FileNotFoundError: `path` does not exist (`IsADirectoryError`: it is a folder).
            DataFormatError: the file is not UTF-8 JSON text holding an object, a value
                besides the settings is not what `_EXTRAS` says, a setting holds different
                values per shot of another count than `n_shots`, or `"photos"` names another
                count of photos than the settings have shots (each naming the file and key).
            ValueError: settings `optics.CameraSettings.from_dict` refuses (naming the file).
        """
        path = require_file(Path(path), "a camera JSON")
        try:
            data = json.loads(read_text(path, "a camera JSON"))
        except json.JSONDecodeError as error:
            raise DataFormatError(f"{path}: cannot read camera settings: {error}") from None
        if not isinstance(data, dict):
            raise DataFormatError(f"{path}: expected a JSON object of camera settings, got "
                                  f"{type(data).__name__}")
        bad = next((key for key, (_, ok) in _EXTRAS.items()
                    if (key in require or data.get(key) is not None) and not ok(data.get(key))),
                   None)
        if bad is not None:
            raise DataFormatError(f'{path}: "{bad}" must {_EXTRAS[bad][0]}, got '
                                  f"{data.get(bad)!r}")
        if data.get("mask") is not None:  # a camera learned with `--learn-optics ...mask`
            raise DataFormatError(
                f'{path}: holds a learned aperture "mask"; a camera file\'s PSF is the shape its '
                f'"aperture" names ({data.get("aperture")!r}), so the mask would be left out: '
                "score such a camera with its checkpoint (defocus evaluate CHECKPOINT)")
        photos = data.get("photos")
        if n_shots is None and photos is not None:
            n_shots, shots = len(photos), shots or f'"photos" names {len(photos)} focused photos'
        if n_shots is not None:
            data = _one_per_shot(str(path), data, n_shots, shots or "the data", given)
        settings = CameraSettings.from_dict(data, source=str(path))
        if photos is not None and len(photos) != settings.n_shots:
            raise DataFormatError(f'{path}: "photos" names {len(photos)} photos but the camera '
                                  f"has {settings.n_shots} shots (one focus distance per photo)")
        gain, reference = data.get("exposure_gain"), data.get("reference_f_number")
        return cls(path, settings, None if reference is None else float(reference),
                   float(data.get("focus_floor_px") or 0.0),
                   None if gain is None else tuple(float(g) for g in gain),
                   None if photos is None else tuple(photos))
