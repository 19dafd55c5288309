"""Your own photos: read a JPEG/PNG/TIFF upright, with the camera values its EXIF holds.

`read_photo` applies the EXIF orientation (a portrait shot stored sideways comes out upright) and
returns the focal length, f-number and pixel pitch where the file states them. The pixel pitch
comes from the focal-plane resolution tags, scaled to the stored image size (a downscaled JPEG
has a larger effective pitch than the sensor); where a camera leaves those out (most phones do),
from the 35 mm equivalent focal length: the stored image's diagonal spans the full-frame
diagonal (43.27 mm) divided by the crop factor, `f_35mm / f`. 16-bit colour TIFFs and PNGs
(what raw developers export) keep all 16 bits: Pillow would cut them to 8, so `tifffile` and
`pypng` read those.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from kornia.color import linear_rgb_to_rgb, rgb_to_linear_rgb
from torch import Tensor

from optics import CameraSettings

from .io import DataFormatError, require_file

#: EXIF tag numbers (the Exif IFD).
_FOCAL_LENGTH, _F_NUMBER = 37386, 33437
_FOCAL_PLANE_X_RES, _FOCAL_PLANE_UNIT = 41486, 41488
_FOCAL_LENGTH_35MM = 41989
_SUBJECT_DISTANCE = 37382
#: Diagonal of a 36 x 24 mm frame, metres: what a 35 mm equivalent focal length is defined on.
FULL_FRAME_DIAGONAL = float(np.hypot(0.036, 0.024))
_EXIF_IFD = 0x8769
_METRES_PER_UNIT = {2: 0.0254, 3: 0.01, 4: 0.001, 5: 1e-6}
#: Pillow formats whose pixels are not the camera's (MPO: the multi-picture JPEG of some cameras).
_LOSSY_FORMATS = ("JPEG", "MPO")
#: Above this working scale (working / photo resolution) JPEG compression costs the sweep
#: accuracy: measured on the motorcycle (`benchmarks/cameras.py --jpeg 90`), cameras swept at
#: scale 1 lost up to 3x in abs rel, those at 0.50 and 0.56 nothing.
JPEG_SCALE_LIMIT = 0.75


@dataclass(frozen=True)
class PhotoInfo:
    """What a photo's EXIF says (None where it says nothing). Lengths in metres.

    Args:
        path: the file.
        focal_length: metres.
        f_number: dimensionless.
        pixel_pitch: effective pixel pitch of the stored (upright) image, metres.
        orientation: the EXIF orientation that was applied (1 = none).
        pixel_pitch_source: which tags gave `pixel_pitch`: `"focal-plane resolution"` or
            `"35 mm equivalent"` (files round that focal length to whole millimetres: up to 2 %
            off at 26 mm).
        compressed: the file is a JPEG (lossy: see `compression_warning`).
        focus_distance: metres, from the SubjectDistance tag, which the cameras that write it
            fill from their focus (an estimate: check it against the lens's focus scale).
    """

    path: Path
    focal_length: float | None = None
    f_number: float | None = None
    pixel_pitch: float | None = None
    orientation: int = 1
    pixel_pitch_source: str | None = None
    compressed: bool = False
    focus_distance: float | None = None


#: How a JPEG, PNG or TIFF stores intensity (`read_photo`).
ENCODINGS = ("srgb", "linear")


def _positive(value) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return number if np.isfinite(number) and number > 0 else None


def _exif_info(path: Path, image) -> PhotoInfo:
    exif = image.getexif()
    detail = exif.get_ifd(_EXIF_IFD) if exif else {}
    orientation = int(exif.get(274, 1)) if exif else 1
    focal = _positive(detail.get(_FOCAL_LENGTH))
    pitch, source = None, None
    resolution = _positive(detail.get(_FOCAL_PLANE_X_RES))
    equivalent = _positive(detail.get(_FOCAL_LENGTH_35MM))
    if resolution is not None:
        unit = _METRES_PER_UNIT.get(int(detail.get(_FOCAL_PLANE_UNIT, 2)), 0.0254)
        pitch = unit / resolution  # at the sensor's full width...
        sensor_width = detail.get(40962)  # PixelXDimension: the stored image's width
        if _positive(sensor_width) is not None and image.width:
            pitch *= float(sensor_width) / image.width
        source = "focal-plane resolution"
    elif focal is not None and equivalent is not None and image.width and image.height:
        # the crop factor f_35mm / f shrinks the full-frame diagonal to the stored image's
        pitch = FULL_FRAME_DIAGONAL * focal / equivalent / float(np.hypot(image.width,
                                                                         image.height))
        source = "35 mm equivalent"
    distance = _positive(detail.get(_SUBJECT_DISTANCE))
    if distance is not None and distance >= 0xFFFFFFFF:  # the tag's "infinity"
        distance = None
    return PhotoInfo(path, None if focal is None else focal / 1000.0,
                     _positive(detail.get(_F_NUMBER)), pitch, orientation, source,
                     image.format in _LOSSY_FORMATS, distance)


def _is_tiff(path: Path) -> bool:
    with open(path, "rb") as file:
        return file.read(4) in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


def _deep_colour(path: Path, opened) -> np.ndarray | None:
    """The samples of a colour TIFF or PNG with more than 8 bits per sample, as stored
    (`(H,W,C)` uint16), which Pillow would cut to 8 bits; None for any other photo."""
    if _is_tiff(path) and (opened is None or (
            opened.mode not in ("L", "P", "1", "I;16")
            and max(opened.tag_v2.get(258, (8,)), default=8) > 8)):
        import tifffile

        try:
            array = tifffile.imread(path, key=0)
        except Exception as error:  # noqa: BLE001 (tifffile raises many kinds)
            if opened is None:
                raise DataFormatError(
                    f"{str(path)!r}: cannot be read as a photo ({error})") from None
            warnings.warn(f"{path}: read with 8 bits per channel only, tifffile cannot decode it "
                          f"({error}); with the imagecodecs package installed all 16 are kept",
                          UserWarning, stacklevel=3)
            return None
        if not np.issubdtype(array.dtype, np.integer):
            raise DataFormatError(
                f"{str(path)!r}: holds {array.dtype} samples; save it as an 8- or 16-bit photo "
                "(floating-point TIFFs say nothing of their encoding)")
        if array.ndim == 3 and array.shape[0] in (3, 4) and array.shape[-1] not in (3, 4):
            array = np.moveaxis(array, 0, -1)  # stored plane by plane
        return array if array.dtype.itemsize > 1 and array.ndim == 3 else None
    if opened is not None and opened.format == "PNG" and opened.mode in ("RGB", "RGBA"):
        import png

        reader = png.Reader(filename=str(path))
        width, height, rows, meta = reader.asDirect()
        if meta["bitdepth"] <= 8:
            return None
        planes = meta["planes"]
        return np.vstack([np.asarray(row, np.uint16) for row in rows]).reshape(
            height, width, planes)
    return None


#: EXIF orientation -> the turn that shows the stored `(H,W,C)` array upright.
_UPRIGHT = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],
    3: lambda a: a[::-1, ::-1],
    4: lambda a: a[::-1],
    5: lambda a: a.transpose(1, 0, 2),
    6: lambda a: np.rot90(a, -1),
    7: lambda a: a.transpose(1, 0, 2)[::-1, ::-1],
    8: lambda a: np.rot90(a, 1),
}


def _orient(array: np.ndarray, orientation: int) -> np.ndarray:
    return _UPRIGHT.get(orientation, _UPRIGHT[1])(array)


#: File name endings read as raw photos (`optics.read_raw`), not as images.
RAW_SUFFIXES = (".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".rw2",
                ".raw", ".rwl", ".orf", ".raf", ".pef", ".srw", ".x3f", ".mrw", ".3fr", ".iiq",
                ".erf", ".kdc", ".dcr", ".mos", ".mef")


def _read_raw_photo(path: Path, dtype: torch.dtype) -> tuple[Tensor, PhotoInfo]:
    """A raw photo as linear sRGB, upright, and what its metadata says."""
    from optics.raw import RawReadError, read_raw

    try:
        # daylight white balance: the same gains for every shot (as-shot ones may differ
        # between shots), divided by the largest so that only saturated photosites reach 1
        image, meta = read_raw(path, white_balance="daylight", colour_space="srgb", dtype=dtype)
    except RawReadError as error:
        raise DataFormatError(str(error)) from None
    image = (image[0] / max(meta.white_balance)).clamp(0, 1)
    upright = _orient(image.permute(1, 2, 0).numpy(), meta.orientation)
    info = PhotoInfo(path, meta.focal_length, meta.f_number, meta.pixel_pitch, meta.orientation,
                     None if meta.pixel_pitch is None else "focal-plane resolution")
    return torch.from_numpy(np.ascontiguousarray(upright)).permute(2, 0, 1), info


def read_photo(path: str | Path, dtype: torch.dtype = torch.float32,
               encoding: str = "srgb") -> tuple[Tensor, PhotoInfo]:
    """Read an RGB photo upright as linear intensity `(3,H,W)` in [0, 1].

    Args:
        path: JPEG, PNG or TIFF file (16-bit colour TIFFs and PNGs keep all 16 bits), or a raw
            photo (`RAW_SUFFIXES`: DNG, CR2, NEF, ARW, ...), decoded by LibRaw to linear sRGB
            with daylight white balance: no compression, no tone curve, the camera's own bits.
        dtype: floating dtype of the result.
        encoding: how a JPEG, PNG or TIFF stores intensity: `"srgb"` (what cameras and phones
            write) or `"linear"` (values proportional to the light, as scientific cameras and
            some 16-bit exports store them). Raw photos are always linear.

    Returns:
        `(image, info)`: the photo and its `PhotoInfo` (EXIF values, orientation applied).

    Raises:
        FileNotFoundError: `path` does not exist.
        DataFormatError: the file cannot be read as an RGB photo.

    Example:
        >>> import tempfile, pathlib
        >>> from PIL import Image
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "photo.png"
        >>> Image.new("RGB", (4, 2), (255, 0, 0)).save(path)
        >>> image, info = read_photo(path)
        >>> image.shape, info.focal_length
        (torch.Size([3, 2, 4]), None)
    """
    from PIL import Image, ImageOps, UnidentifiedImageError

    if encoding not in ENCODINGS:
        raise ValueError(f"encoding must be one of {ENCODINGS}, got {encoding!r}")
    path = Path(path)
    require_file(path, "a photo")
    if path.suffix.lower() in RAW_SUFFIXES:
        return _read_raw_photo(path, dtype)
    try:
        with Image.open(path) as opened:
            info = _exif_info(path, opened)
            deep = _deep_colour(path, opened)
            if deep is None:
                upright = ImageOps.exif_transpose(opened)
                array = np.array(upright.convert("RGB") if upright.mode not in ("RGB", "I;16")
                                 else upright)
    except (UnidentifiedImageError, OSError, ValueError) as error:
        # Pillow reads no floating-point colour TIFF: tifffile says what it holds
        deep = _deep_colour(path, None)
        if deep is None:
            raise DataFormatError(f"{str(path)!r}: cannot be read as a photo ({error})") from None
        info = PhotoInfo(path)
    if deep is not None:
        array = _orient(deep, info.orientation)
    if array.ndim == 2:
        array = np.repeat(array[..., None], 3, axis=2)
    scale = float(np.iinfo(array.dtype).max) if np.issubdtype(array.dtype, np.integer) else 1.0
    image = torch.from_numpy(np.ascontiguousarray(array[..., :3])).to(dtype).permute(2, 0, 1)
    image = image / scale
    return (rgb_to_linear_rgb(image) if encoding == "srgb" else image), info


def save_photo(path: str | Path, image: Tensor) -> Path:
    """Write a linear image `(3,H,W)` (values in [0, 1], clipped) as a 16-bit sRGB PNG, which
    `read_photo` reads back to within 1e-4.

    Example:
        >>> import tempfile, pathlib
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "aif.png"
        >>> image = torch.rand(3, 4, 6)
        >>> back, _ = read_photo(save_photo(path, image))
        >>> bool((back - image).abs().max() < 1e-4)
        True
    """
    import png

    check_image = image.detach().cpu().float()
    if check_image.dim() != 3 or check_image.shape[0] != 3:
        raise ValueError(f"image must be (3, H, W), got {tuple(image.shape)}")
    encoded = linear_rgb_to_rgb(check_image.clamp(0, 1)).clamp(0, 1)
    array = (encoded.permute(1, 2, 0).numpy() * 65535 + 0.5).astype(np.uint16)
    path = Path(path)
    with open(path, "wb") as handle:
        png.Writer(array.shape[1], array.shape[0], greyscale=False, bitdepth=16).write(
            handle, array.reshape(array.shape[0], -1))
    return path


def photo_settings(
    infos: list[PhotoInfo], focus_distances: list[float], f_numbers: list[float] | None = None,
    focal_length: float | None = None, pixel_pitch: float | None = None,
    calibration: CameraSettings | None = None, aperture: str = "disk",
    sources: dict[str, str] | None = None,
) -> CameraSettings:
    """The `(F,)` `CameraSettings` of focused photos, from what the user gave, else the
    calibration, else the photos' EXIF.

    Args:
        infos: the `PhotoInfo` of each focused photo (`read_photo`).
        focus_distances: one per photo, metres (`--focus-distance`); else the calibration's,
            else EXIF's SubjectDistance where every photo states it (few cameras do).
        f_numbers: one per photo or one for all (else the calibration, else EXIF).
        focal_length: metres (else the calibration, else EXIF).
        pixel_pitch: effective pitch of the photos as stored, metres (else the calibration, else
            EXIF: the focal-plane resolution or the 35 mm equivalent focal length).
        calibration: a `CameraSettings` from `defocus calibrate` (`CameraSettings.from_json`).
        aperture: PSF spec when no calibration gives one.
        sources: a dict that, when given, is filled with where each of `focus_distance`,
            `focal_length`, `f_number` and `pixel_pitch` came from: `"given"`, `"calibration"` or `"EXIF"`
            (for the pitch, with the tags it came from).

    Raises:
        ValueError: naming every value that is missing and how to give it.
    """
    n = len(infos)
    found = {} if sources is None else sources
    found["focus_distance"] = "given"
    if len(focus_distances) == 0 and calibration is not None and calibration.n_shots == n:
        focus_distances = calibration.focus_distance.tolist()
        found["focus_distance"] = "calibration"
    elif len(focus_distances) == 0 and all(info.focus_distance for info in infos):
        focus_distances = [info.focus_distance for info in infos]
        found["focus_distance"] = "EXIF"
    if len(focus_distances) != n:
        hint = "" if focus_distances else " (none of the photos' EXIF states it)"
        raise ValueError(f"give --focus-distance with one value per focused photo ({n}), "
                         f"got {len(focus_distances)}{hint}")

    def pick(name: str, given, unit: str):
        if given is not None:
            found[name] = "given"
            return given
        if calibration is not None:
            found[name] = "calibration"
            return getattr(calibration, name).reshape(-1)[0].item()
        values = [getattr(info, name) for info in infos]
        if all(v is not None for v in values):
            found[name] = ("EXIF " + " and ".join(sorted({str(info.pixel_pitch_source)
                                                          for info in infos}))
                           if name == "pixel_pitch" else "EXIF")
            return values
        missing = [str(info.path) for info, v in zip(infos, values, strict=True) if v is None]
        raise ValueError(f"{name} is unknown: {', '.join(missing)} do(es) not state it in EXIF; "
                         f"give --{name.replace('_', '-')} ({unit}) or --camera fit.json")

    if f_numbers is not None and len(f_numbers) not in (0, 1, n):
        raise ValueError(f"give --f-number once or once per focused photo ({n}), got "
                         f"{len(f_numbers)}")
    f_number = pick("f_number", (f_numbers[0] if len(f_numbers) == 1 else f_numbers)
                    if f_numbers else None, "dimensionless")
    focal = pick("focal_length", focal_length, "metres, e.g. 0.05 for 50 mm")
    pitch = pick("pixel_pitch", pixel_pitch, "metres, e.g. 4e-6")
    spec = calibration.aperture if calibration is not None else aperture
    return CameraSettings(focal, f_number, list(focus_distances), pitch, aperture=spec)


def describe_settings(settings: CameraSettings, sources: dict[str, str] | None = None) -> str:
    """One line for a person: the `(F,)` shots' focal length, f-number, pixel pitch and focus
    distances, each with where it came from (`photo_settings`'s `sources`) when known.

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


def compression_warning(infos: list[PhotoInfo], scale: float) -> str | None:
    """A warning for a person when JPEG photos are read at `scale` (working / photo resolution)
    above `JPEG_SCALE_LIMIT`, where the compression reads as blur; None otherwise.

    Example:
        >>> from pathlib import Path
        >>> compression_warning([PhotoInfo(Path("a.jpg"), compressed=True)], 0.3) is None
        True
    """
    lossy = [info.path.name for info in infos if info.compressed]
    if not lossy or not scale > JPEG_SCALE_LIMIT:
        return None
    return (f"{', '.join(lossy)}: JPEG photos read at {scale:.2f} of their resolution, where the "
            "compression reads as blur (up to 3x the depth error, measured at qualities 75-95); "
            "PNG or TIFF photos (from the raw files, if the camera keeps them) avoid this")
