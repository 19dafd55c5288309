"""The camera JSON of a dataset loader (`camera=` of `datasets.DSLR`, the `camera.json` of a
`datasets.PhotoFolder`), read at the loader's door.

A camera JSON (`optics.CameraSettings.to_json`, what `defocus calibrate` writes) may hold one
value per shot (`"f_number": [8.3, 2.0]`). Such values are used one per shot of the data,
never the first one for all: a list of as many values as the data has shots is kept as it is,
a list of one repeated value counts as that one value, and a list of different values of
another length is refused in one line that names the file and the key (as `defocus predict
--camera` does, `defocus.app.predict.check_calibration_shots`).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from os import PathLike
from pathlib import Path
from typing import Any

from optics import CameraSettings
from optics.camera import SETTING_FIELDS
from optics.checks import is_real_number

from .io import DataFormatError


def load_camera_json(path: str | PathLike) -> dict[str, Any]:
    """The JSON object of a camera file; a file that cannot be read or holds no object is
    refused naming it.

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "camera.json"
        >>> _ = path.write_text('{"f_number": 2.8}')
        >>> load_camera_json(path)
        {'f_number': 2.8}
    """
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise DataFormatError(f"{path}: cannot read camera settings: {error}") from None
    if not isinstance(data, dict):
        raise DataFormatError(f"{path}: expected a JSON object of camera settings, got "
                              f"{type(data).__name__}")
    return data


def _shot_values_refused(source: str, key: str, values: list[Any], n_shots: int,
                         shots: str) -> DataFormatError:
    return DataFormatError(f'{source}: "{key}" holds {len(values)} different values {values}, '
                           f"one per shot, but {shots} ({n_shots} shot(s)): give one value "
                           "for all shots, or one per shot")


def camera_from_json(data: Mapping[str, Any], source: str, n_shots: int,
                     shots: str = "the data") -> tuple[CameraSettings, dict[str, Any]]:
    """The settings of a camera JSON object `data` for data of `n_shots` shots, and its extra
    values (those not of the settings, e.g. `reference_f_number`).

    Args:
        data: the JSON object (`load_camera_json`).
        source: the file, as named in errors.
        n_shots: how many shots the data has (focused photos per scene).
        shots: what has them, for the error (`'"photos" names 2 focused photos'`).

    Raises:
        DataFormatError: a setting holds different values per shot, as many as the data
            has no shots (naming `source` and the key); ValueError of
            `optics.CameraSettings.from_dict` for values that are no camera's.

    Example:
        >>> data = {"focal_length": 0.05, "f_number": [8.3, 2.0], "focus_distance": 1.5,
        ...         "pixel_pitch": 2e-5}
        >>> camera_from_json(data, "cam.json", 2)[0].f_number.tolist()
        [8.3, 2.0]
        >>> camera_from_json(data, "cam.json", 1, "a DSLR scene has one focused photo")
        Traceback (most recent call last):
        ...
        datasets.io.DataFormatError: cam.json: "f_number" holds 2 different values [8.3, 2.0], one per shot, but a DSLR scene has one focused photo (1 shot(s)): give one value for all shots, or one per shot
    """
    data = dict(data)
    for key in SETTING_FIELDS:
        values = data.get(key)
        if not isinstance(values, list) or len(values) in (0, n_shots) or not all(
                is_real_number(v) for v in values):
            continue  # one per shot, a single number, or no numbers: CameraSettings checks
        if len(set(values)) > 1:
            raise _shot_values_refused(source, key, values, n_shots, shots)
        data[key] = values[0]  # one value repeated: the same for every shot
    settings = CameraSettings.from_dict(data, source=source)
    known = settings.to_dict()
    return settings, {k: v for k, v in data.items() if k not in known}


def camera_for_shots(settings: CameraSettings, n_shots: int, source: str = "camera",
                     shots: str = "the data") -> CameraSettings:
    """`settings` for data of `n_shots` shots: as they are where they have that many; where
    every shot is the same, that one shot repeated; else refused naming the setting (never
    the first shot's values for all).

    Example:
        >>> camera_for_shots(CameraSettings(0.05, [2.8, 2.8], 1.7, 6e-5), 1).n_shots
        1
    """
    if settings.n_shots == n_shots:
        return settings
    for key in SETTING_FIELDS:
        values = getattr(settings, key).reshape(-1).tolist()
        if len(set(values)) > 1:
            raise _shot_values_refused(source, key, values, n_shots, shots)
    return settings.select_shots([0] * n_shots)
