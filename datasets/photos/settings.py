"""Camera settings of photos: from options, a calibration and what the files state.

One resolver serves every user of real photos. `resolve_known` finds the values that are known,
each with where it came from: an option the user gave, else a calibration (a `CameraSettings`
written by `defocus calibrate`), else what every photo's metadata (`datasets.photos.PhotoMetadata`)
states. `resolve_settings` needs them all and makes the `(F,)` `CameraSettings` of the photos
(`defocus predict`); a calibration fits the ones left unknown (`defocus calibrate`).
`describe_settings` says in one line which settings were used and where each came from, and
`compression_warning` warns of JPEG photos read near their full resolution.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from typing import Any

from optics import Sensor
from optics.aperture_spec import DEFAULT_APERTURE, LENS_APERTURE
from optics.camera import SETTING_FIELDS, CameraSettings

from .metadata import PhotoMetadata

#: Above this working scale (working / photo resolution) JPEG compression costs the sweep
#: accuracy: measured on the motorcycle (`benchmarks/cameras.py --jpeg 90`), cameras swept at
#: scale 1 lost up to 3x in abs rel, those at 0.50 and 0.56 nothing.
JPEG_SCALE_LIMIT = 0.75
#: The unit of each setting in `resolve_settings`'s messages.
_UNITS = {"f_number": "dimensionless", "focal_length": "metres, e.g. 0.05 for 50 mm",
          "pixel_pitch": "metres, e.g. 4e-6"}


def _given(value: Any) -> bool:
    """Whether an option holds a value (`None` and an empty sequence do not)."""
    return value is not None and not (isinstance(value, (list, tuple)) and len(value) == 0)


def _times(value: Any, factor: int) -> Any:
    """`value` (a number or a sequence of numbers) times `factor`, unchanged where it is 1."""
    if factor == 1:
        return value
    return [v * factor for v in value] if isinstance(value, (list, tuple)) else value * factor


def _binning(metadata: Sequence[PhotoMetadata]) -> int:
    """The binning all records share (1 for none)."""
    binnings = sorted({meta.binning for meta in metadata})
    if len(binnings) > 1:
        raise ValueError(f"metadata must come from images of one binning, got binnings "
                         f"{binnings}")
    return binnings[0] if binnings else 1


def _from_calibration(name: str, calibration: CameraSettings, n_photos: int) -> Any:
    """The calibration's value of `name`: its focus distances where it has one per photo (else
    `None`); of any other setting its one value, or its values one per photo where they
    differ (never the first alone: per-shot values that do not match the photos are refused).
    """
    if name == "focus_distance":
        return calibration.focus_distance.tolist() if calibration.n_shots == n_photos else None
    values = getattr(calibration, name).reshape(-1).tolist()
    if len(set(values)) == 1:
        return values[0]
    if len(values) != n_photos:
        raise ValueError(f"the calibration has {len(values)} different {name} values "
                         f"{values}, one per shot, but {n_photos} photo(s) are given: give one "
                         "value for every photo, or one per photo")
    return values


def _from_metadata(name: str, metadata: Sequence[PhotoMetadata]) -> tuple[Any, str] | None:
    """What every record states of `name` (pixel pitch times binning) and its source; `None`
    where a record does not state it."""
    values = [getattr(meta, name) for meta in metadata]
    if not metadata or any(v is None for v in values):
        return None
    source = "EXIF"
    if name == "pixel_pitch":
        values = [v * meta.binning for v, meta in zip(values, metadata, strict=True)]
        source += " " + " and ".join(sorted({str(meta.pixel_pitch_source) for meta in metadata}))
    return (values[0] if len(values) == 1 else values), source


def resolve_known(
    metadata: Sequence[PhotoMetadata],
    options: Mapping[str, Any] | None = None,
    calibration: CameraSettings | None = None,
    ignore: Collection[str] = (),
) -> tuple[dict[str, Any], dict[str, str]]:
    """The camera values known for photos, each from an option, else the calibration, else
    what every photo's metadata states.

    Args:
        metadata: the `PhotoMetadata` of each photo (`datasets.photos.read_metadata`, `datasets.photos.read_raw`,
            `datasets.photos.read_photo`).
        options: values the user gave, by `CameraSettings` field name (`focal_length`,
            `f_number`, `focus_distance`, `pixel_pitch`): a number or one per photo; `None` or
            an empty sequence gives nothing. `pixel_pitch` is the pitch of the files' pixels
            (the sensor's for a raw file), multiplied by the records' `binning`.
        calibration: a `CameraSettings` from `defocus calibrate` (`CameraSettings.from_json`):
            its focus distances where it has one per photo; its other settings' one value, or
            one per photo (per-shot values of another count are refused).
        ignore: settings whose metadata value is not used (to be fitted instead).

    Returns:
        `(values, sources)`: the known values by name, a number or one per photo (a list; the
        metadata's pixel pitch times `binning`), and where each came from: `"given"`,
        `"calibration"`, `"EXIF"` or, for the pixel pitch, `"EXIF "` and the tags it came from.
        Settings nothing gives are in neither.

    Raises:
        ValueError: if the records differ in binning.

    Example:
        >>> stated = {"focal_length": 0.05, "f_number": 2.8, "pixel_pitch": 4e-6}
        >>> meta = PhotoMetadata("a.dng", stated, pixel_pitch_source="focal-plane resolution",
        ...                      binning=2)
        >>> values, sources = resolve_known([meta], {"f_number": 4.0})
        >>> values
        {'focal_length': 0.05, 'f_number': 4.0, 'pixel_pitch': 8e-06}
        >>> sources["f_number"], sources["pixel_pitch"]
        ('given', 'EXIF focal-plane resolution')
    """
    options = dict(options or {})
    binning = _binning(metadata)
    values: dict[str, Any] = {}
    sources: dict[str, str] = {}
    for name in SETTING_FIELDS:
        if _given(options.get(name)):
            given = options[name]
            values[name] = _times(given, binning) if name == "pixel_pitch" else given
            sources[name] = "given"
            continue
        if calibration is not None:
            value = _from_calibration(name, calibration, len(metadata))
            if value is not None:
                values[name], sources[name] = value, "calibration"
                continue
        stated = None if name in ignore else _from_metadata(name, metadata)
        if stated is not None:
            values[name], sources[name] = stated
    return values, sources


def _why_no_focus(focus: list, source: str | None, metadata: Sequence[PhotoMetadata],
                  calibration: CameraSettings | None) -> str:
    """Where each source of the focus distances fell short, for `resolve_settings`' error."""
    n = len(metadata)
    if source == "given":
        return f"--focus-distance holds {len(focus)}"
    why = []
    if calibration is not None:
        why.append(f"the calibration holds {calibration.n_shots} "
                   f"({', '.join(f'{d:g}' for d in calibration.focus_distance.reshape(-1).tolist())} m)")
    stated = sum(meta.focus_distance is not None for meta in metadata)
    why.append(f"{stated} of the {n} photos' EXIF state it" if stated
               else "no photo's EXIF states it")
    return "; ".join(why)


def resolve_settings(
    metadata: Sequence[PhotoMetadata],
    options: Mapping[str, Any] | None = None,
    calibration: CameraSettings | None = None,
    aperture: str = LENS_APERTURE,
) -> tuple[CameraSettings, dict[str, str]]:
    """The `(F,)` `CameraSettings` of `F` focused photos, every value known (`resolve_known`),
    and where each came from.

    Args:
        metadata: the `PhotoMetadata` of each focused photo.
        options: as `resolve_known`'s, from the command line: `focus_distance` one per photo
            (else the calibration's, else the photos' SubjectDistance where every photo states
            it); `f_number` once or once per photo.
        calibration: a `CameraSettings` from `defocus calibrate`.
        aperture: the PSF spec where no calibration gives one; `"disk"` for uncalibrated
            photos.

    Returns:
        `(settings, sources)`, `sources` as `resolve_known`'s.

    Raises:
        ValueError: naming the first value that is missing or miscounted and how to give it.

    Example:
        >>> stated = {"focal_length": 0.05, "f_number": 1.4}
        >>> photos = [PhotoMetadata("a.jpg", stated), PhotoMetadata("b.jpg", stated)]
        >>> options = {"focus_distance": [2.0, 6.0], "pixel_pitch": 1e-5}
        >>> settings, sources = resolve_settings(photos, options)
        >>> describe_settings(settings, sources)
        'camera: focal length 50.0 mm (EXIF), f/1.4 (EXIF), pixel pitch 10.00 um (given), focused at 2, 6 m (given)'
    """
    n = len(metadata)
    given = dict(options or {})
    f_numbers = given.get("f_number")
    if isinstance(f_numbers, (list, tuple)) and len(f_numbers) == 1:
        given["f_number"] = f_numbers[0]
    values, sources = resolve_known(metadata, given, calibration)
    focus = values.get("focus_distance", [])
    focus = list(focus) if isinstance(focus, (list, tuple)) else [focus]
    unknown = next((name for name in ("f_number", "focal_length", "pixel_pitch")
                    if name not in values), "")
    why = (f"give --focus-distance with one value per focused photo ({n}): " + _why_no_focus(
        focus, sources.get("focus_distance"), metadata, calibration) if len(focus) != n else
        f"give --f-number once or once per focused photo ({n}), got {len(f_numbers)}"
        if isinstance(f_numbers, (list, tuple)) and len(f_numbers) not in (0, 1, n) else
        f"{unknown} is unknown: "
        f"{', '.join(str(m.path) for m in metadata if getattr(m, unknown) is None)} do(es) not "
        f"state it in EXIF; give --{unknown.replace('_', '-')} ({_UNITS[unknown]}) or --camera "
        "fit.json" if unknown else None)
    if why:
        raise ValueError(why)
    spec = calibration.aperture if calibration is not None else aperture
    settings = CameraSettings(values["focal_length"], values["f_number"], focus,
                              values["pixel_pitch"], aperture=spec)
    return settings, sources


def metadata_settings(
    metadata: PhotoMetadata,
    focus_distance: float | Sequence[float],
    pixel_pitch: float | None = None,
    aperture: str = DEFAULT_APERTURE,
    *,
    focal_length: float | None = None,
    f_number: float | None = None,
) -> CameraSettings:
    """The `CameraSettings` of an image decoded from one file (`datasets.photos.read_raw`): the file's
    focal length and f-number, and its pixel pitch times the image's `binning`.

    Most cameras do not record the focus distance, so it is always given.

    Args:
        metadata: the image's `PhotoMetadata`.
        focus_distance: metres (a number, or one per shot).
        pixel_pitch: *sensor* pixel pitch in metres; by default the file's. The settings hold
            the effective pitch, this times `binning`.
        aperture: the PSF's spec (`"gaussian:0.5"`, `"disk"`, `"polygon:6"`, ...).
        focal_length: metres, replacing the file's (for files that do not state it).
        f_number: replacing the file's (for files that do not state it, e.g. manual lenses).

    Returns:
        `(F,)` settings (`F = 1` for one focus distance).

    Raises:
        ValueError: naming each value the file does not state and the argument to pass
            instead, or for settings `CameraSettings` refuses.

    Example:
        >>> stated = {"focal_length": 0.05, "f_number": 2.8, "pixel_pitch": 4e-6}
        >>> meta = PhotoMetadata("a.dng", stated, binning=2)
        >>> metadata_settings(meta, 2.0).to_dict()
        {'focal_length': 0.05, 'f_number': 2.8, 'focus_distance': 2.0, 'pixel_pitch': 8e-06, 'aperture': 'gaussian:0.5'}
    """
    options = {"focal_length": focal_length, "f_number": f_number, "pixel_pitch": pixel_pitch}
    values, _ = resolve_known([metadata], options)
    missing = {
        "focal_length": "its focal length (EXIF FocalLength): pass focal_length in metres",
        "f_number": "its f-number (EXIF FNumber): pass f_number",
        "pixel_pitch": "its pixel pitch (EXIF focal-plane resolution): pass pixel_pitch, "
        "the sensor pitch in metres",
    }
    problems = [why for name, why in missing.items() if name not in values]
    if problems:
        raise ValueError(f"{metadata.path}: the file does not state " + "; nor ".join(problems))
    return CameraSettings(values["focal_length"], values["f_number"], focus_distance,
                          values["pixel_pitch"], aperture=aperture)


def metadata_sensor(metadata: PhotoMetadata, pixel_pitch: float | None = None) -> Sensor:
    """A `Sensor` for an image decoded from one file (its `binning` sets `downsample`).

    Args:
        metadata: the image's `PhotoMetadata`.
        pixel_pitch: sensor pixel pitch in metres; by default the file's.

    Raises:
        ValueError: if neither `pixel_pitch` nor the file gives the pitch.

    Example:
        >>> meta = PhotoMetadata("a.dng", {"pixel_pitch": 4e-6}, binning=2)
        >>> round(float(metadata_sensor(meta).effective_pixel_pitch), 12)
        8e-06
    """
    pitch = metadata.pixel_pitch if pixel_pitch is None else pixel_pitch
    if pitch is None:
        raise ValueError(
            f"{metadata.path}: the file does not state its pixel pitch (EXIF focal-plane "
            "resolution); pass pixel_pitch in metres"
        )
    return Sensor(pitch, resolution=metadata.raw_size, cfa=metadata.cfa_pattern,
                  downsample=metadata.binning)


def describe_settings(settings: CameraSettings, sources: Mapping[str, str] | None = None) -> str:
    """One line for a person: the `(F,)` shots' focal length, f-number, pixel pitch and focus
    distances, each with where it came from (`resolve_settings`'s `sources`) when known.

    Example:
        >>> describe_settings(CameraSettings(0.05, 2.0, [1.0, 3.0], 4e-6), {"f_number": "EXIF"})
        'camera: focal length 50.0 mm, f/2 (EXIF), pixel pitch 4.00 um, focused at 1, 3 m'
    """
    sources = sources or {}

    def values(name: str, scale: float, fmt: str, unit: str = "") -> str:
        unique = sorted({round(float(v) * scale, 6) for v in getattr(settings, name).reshape(-1)})
        text = "/".join(format(v, fmt) for v in unique) + unit
        return f"{text} ({sources[name]})" if name in sources else text

    focus = ", ".join(format(float(d), "g") for d in settings.focus_distance.reshape(-1)) + " m"
    if "focus_distance" in sources:
        focus += f" ({sources['focus_distance']})"
    return (f"camera: focal length {values('focal_length', 1e3, '.1f', ' mm')}, "
            f"f/{values('f_number', 1.0, 'g')}, pixel pitch "
            f"{values('pixel_pitch', 1e6, '.2f', ' um')}, focused at {focus}")


def compression_warning(metadata: Sequence[PhotoMetadata], scale: float) -> str | None:
    """A warning for a person when JPEG photos are read at `scale` (working / photo resolution)
    above `JPEG_SCALE_LIMIT`, where the compression reads as blur; None otherwise.

    Example:
        >>> compression_warning([PhotoMetadata("a.jpg", compressed=True)], 0.3) is None
        True
    """
    lossy = list(dict.fromkeys(meta.path.name for meta in metadata if meta.compressed))
    if not lossy or not scale > JPEG_SCALE_LIMIT:
        return None
    return (f"{', '.join(lossy)}: JPEG photos read at {scale:.2f} of their resolution, where the "
            "compression reads as blur (up to 3x the depth error, measured at qualities 75-95); "
            "PNG or TIFF photos (from the raw files, if the camera keeps them) avoid this")
