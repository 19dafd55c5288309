"""What a photo's file states: one record (`PhotoMetadata`) and one reader (`read_metadata`).

One reader serves raw files (DNG, CR2, NEF, ARW, ...: `RAW_SUFFIXES`) and JPEG, TIFF, PNG and
WebP photos alike. EXIF tags are read by `exifread` for every format, with one unit table
(`METRES_PER_RESOLUTION_UNIT`). Raw files are also opened by LibRaw (through `rawpy`), which
gives the focal length, f-number, exposure and ISO first (EXIF where LibRaw has none; LibRaw
keeps single precision, so these values keep 6 significant digits), the black and white
levels, the CFA pattern, the white balances and the colour matrices.

The record holds what the file states, not a camera: its camera values (focal length, f-number,
focus distance, pixel pitch) carry the names and units of `CameraSettings`, the one camera value
type, and `datasets.photos.settings` turns records and options into `CameraSettings`.

The pixel pitch comes from the focal-plane resolution tags; for JPEG, TIFF and PNG photos it is
scaled to the stored image size (a downscaled JPEG has a larger effective pitch than the sensor)
and, where a camera leaves those tags out (most phones do), comes from the 35 mm equivalent focal
length: the stored image's diagonal spans the full-frame diagonal (`FULL_FRAME_DIAGONAL`)
divided by the crop factor, `f_35mm / f`.
"""

from __future__ import annotations

import io
import logging
import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from optics.camera import SETTING_FIELDS

from ..io import DataFormatError, require_file

#: File name endings read as raw photos (LibRaw), not as images.
RAW_SUFFIXES = (".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".rw2",
                ".raw", ".rwl", ".orf", ".raf", ".pef", ".srw", ".x3f", ".mrw", ".3fr", ".iiq",
                ".erf", ".kdc", ".dcr", ".mos", ".mef")
#: Diagonal of a 36 x 24 mm frame, metres: what a 35 mm equivalent focal length is defined on.
FULL_FRAME_DIAGONAL = float(np.hypot(0.036, 0.024))
#: Metres per unit of the EXIF FocalPlaneResolutionUnit (2: inch, the default; 3: cm; 4: mm;
#: 5: um).
METRES_PER_RESOLUTION_UNIT = {2: 0.0254, 3: 0.01, 4: 0.001, 5: 1e-6}
#: The EXIF "infinity" of SubjectDistance.
_INFINITE_DISTANCE = 0xFFFFFFFF
#: LibRaw's `flip` (0, 3: 180 degrees, 5: 90 counter-clockwise, 6: 90 clockwise) as the EXIF
#: orientation that turns the image upright.
_LIBRAW_FLIP_TO_EXIF = {0: 1, 3: 3, 5: 8, 6: 6}


class RawReadError(DataFormatError):
    """A raw file that LibRaw cannot decode, or that decodes to no image data."""


@dataclass(frozen=True)
class PhotoMetadata:
    """What a photo's file states about how it was taken (`None` where it says nothing).

    Lengths in metres, times in seconds. The camera values the file states are held in
    `stated`, by `CameraSettings` field name and in its units (`datasets.photos.settings` makes
    settings of them), and read as `focal_length`, `f_number`, `focus_distance` and
    `pixel_pitch` (`None` where the file does not state them).

    Attributes:
        path: the file read.
        stated: the camera values the file states: `"focal_length"` (metres, e.g. `0.065`),
            `"f_number"` (e.g. `5.6`), `"focus_distance"` (metres, from the SubjectDistance
            tag of JPEG, TIFF and PNG photos, which the cameras that write it fill from their
            focus: an estimate, check it against the lens's focus scale) and `"pixel_pitch"`
            (metres: of the sensor for a raw file, of the stored image for other photos; a file
            resized by a converter may state the original sensor's).
        pixel_pitch_source: which tags gave `pixel_pitch`: `"focal-plane resolution"` or
            `"35 mm equivalent"` (files round that focal length to whole millimetres: up to
            2 % off at 26 mm).
        orientation: how to turn the stored image upright, as an EXIF orientation (1: as is,
            3: half a turn, 6: a quarter turn clockwise, 8: counter-clockwise).
        compressed: the file is a JPEG (lossy: see `datasets.photos.settings.compression_warning`).
        camera_make: e.g. `"Canon"`.
        camera_model: e.g. `"Canon EOS 6D"`.
        lens_model: e.g. `"EF24-105mm f/4L IS USM"`.
        exposure_time: exposure time in seconds.
        iso: ISO sensitivity.
        cfa_pattern: raw files: the 2x2 Bayer pattern, e.g. `"RGGB"`; `None` for non-Bayer
            data (linear DNG, X-Trans, Foveon).
        black_level: raw files: black level per CFA channel (raw units).
        white_level: raw files: white (saturation) level (raw units).
        camera_white_balance: raw files: as-shot multipliers `(R, G, B)` normalised to `G = 1`.
        daylight_white_balance: raw files: daylight multipliers `(R, G, B)`, `G = 1`.
        white_balance: the multipliers applied to the decoded image (`datasets.photos.read_raw`).
        colour_matrix: raw files: 3x3 matrix from white-balanced camera RGB to linear sRGB
            (rows sum to 1).
        xyz_to_camera: raw files: 3x3 matrix from CIE XYZ to camera RGB (the DNG `ColorMatrix`).
        colour_space: colour space of the decoded image (`"camera"`, `"srgb"`, `"xyz"`).
        binning: factor by which the decoded image is smaller than the sensor grid.
        raw_size: raw files: `(height, width)` of the sensor area LibRaw reports as visible.

    Example:
        >>> meta = PhotoMetadata("a.jpg", {"focal_length": 0.05, "f_number": 2.8})
        >>> meta.path.name, meta.focal_length, meta.pixel_pitch
        ('a.jpg', 0.05, None)
    """

    path: Path
    stated: dict[str, float] = field(default_factory=dict)
    pixel_pitch_source: str | None = None
    orientation: int = 1
    compressed: bool = False
    camera_make: str | None = None
    camera_model: str | None = None
    lens_model: str | None = None
    exposure_time: float | None = None
    iso: float | None = None
    cfa_pattern: str | None = None
    black_level: list[float] = field(default_factory=list)
    white_level: float | None = None
    camera_white_balance: tuple[float, float, float] | None = None
    daylight_white_balance: tuple[float, float, float] | None = None
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    colour_matrix: list[list[float]] | None = None
    xyz_to_camera: list[list[float]] | None = None
    colour_space: str = "camera"
    binning: int = 1
    raw_size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))
        unknown = sorted(set(self.stated) - set(SETTING_FIELDS))
        if unknown:
            raise ValueError(f"stated must hold camera values among {list(SETTING_FIELDS)}, "
                             f"got {unknown}")

    @property
    def focal_length(self) -> float | None:
        """The focal length the file states, metres."""
        return self.stated.get("focal_length")

    @property
    def f_number(self) -> float | None:
        """The f-number the file states."""
        return self.stated.get("f_number")

    @property
    def focus_distance(self) -> float | None:
        """The focus distance the file states, metres."""
        return self.stated.get("focus_distance")

    @property
    def pixel_pitch(self) -> float | None:
        """The pixel pitch the file states, metres."""
        return self.stated.get("pixel_pitch")


def _known(**values: float | None) -> dict[str, float]:
    """The `values` that are not `None`."""
    return {name: value for name, value in values.items() if value is not None}


def _number(tag: Any) -> float | None:
    """The first value of an EXIF tag (rationals included) as a float, where finite and > 0."""
    try:
        value = tag.values[0] if isinstance(tag.values, list) else tag.values
        if isinstance(value, tuple):  # exifread keeps each IEEE float in a 1-tuple
            value = value[0]
        number = float(value)
    except (AttributeError, IndexError, TypeError, ValueError, ZeroDivisionError):
        return None
    return number if math.isfinite(number) and number > 0 else None


def _six_digits(value: Any) -> float | None:
    """`value` as a float to 6 significant digits (LibRaw's single precision: 5.6, not
    5.5999), where finite and > 0."""
    try:
        number = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return float(f"{number:.6g}") if math.isfinite(number) and number > 0 else None


def _webp_exif(handle: BinaryIO) -> bytes | None:
    """The EXIF chunk of a WebP file (TIFF-structured; None for other files or without one).

    The WebP container keeps EXIF as bare TIFF data, which exifread (expecting JPEG's
    `Exif\\0\\0` header first) misreads, so the chunk is handed to it as a TIFF.
    """
    head = handle.read(12)
    if head[:4] != b"RIFF" or head[8:12] != b"WEBP":
        return None
    while len(chunk := handle.read(8)) == 8:
        size = int.from_bytes(chunk[4:], "little")
        if chunk[:4] == b"EXIF":
            data = handle.read(size)
            return data[6:] if data.startswith(b"Exif\x00\x00") else data
        handle.seek(size + size % 2, 1)  # chunks are padded to an even size
    return b""


def _exif_tags(path: Path) -> dict[str, Any]:
    """EXIF tags of `path` (an empty dict where exifread cannot parse the file)."""
    import exifread

    logger = logging.getLogger("exifread")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with open(path, "rb") as handle:
            webp = _webp_exif(handle)
            handle.seek(0)
            return dict(exifread.process_file(handle if webp is None else io.BytesIO(webp),
                                              details=False))
    except Exception:  # exifread raises many kinds on damaged files; metadata is optional
        return {}
    finally:
        logger.setLevel(level)


def _tag(tags: dict[str, Any], *names: str, groups: Sequence[str] = ("EXIF",)) -> Any:
    """The first of `names` found in the `groups` (IFDs: "EXIF", "Image", "MakerNote")."""
    for name in names:
        for group in groups:
            if f"{group} {name}" in tags:
                return tags[f"{group} {name}"]
    return None


def _text(tag: Any) -> str | None:
    if tag is None:
        return None
    text = str(tag.printable if hasattr(tag, "printable") else tag).strip().strip("\x00")
    return text or None


def _integer(tag: Any, default: int) -> int:
    try:
        return int(tag.values[0]) if tag is not None else default
    except (AttributeError, IndexError, TypeError, ValueError):
        return default


def _focal_plane_pitch(tags: dict[str, Any], resolution: float | None,
                       groups: Sequence[str]) -> float | None:
    """Metres per pixel of the focal-plane resolution `resolution` (pixels per unit), in the
    unit that the `groups`' FocalPlaneResolutionUnit names (inches by default); None where
    that unit is none EXIF defines (1, "no absolute unit", or an invalid value)."""
    if resolution is None:
        return None
    unit = _integer(_tag(tags, "FocalPlaneResolutionUnit", groups=groups), 2)
    if unit not in METRES_PER_RESOLUTION_UNIT:
        return None
    return METRES_PER_RESOLUTION_UNIT[unit] / resolution


def _wb_rgb(multipliers: Sequence[float]) -> tuple[float, float, float] | None:
    values = [float(v) for v in multipliers][:3]
    if len(values) < 3 or not all(math.isfinite(v) and v > 0 for v in values):
        return None
    return (values[0] / values[1], 1.0, values[2] / values[1])


def _read_error(path: Path, error: Exception) -> RawReadError:
    detail = error.args[0] if error.args else ""
    detail = detail.decode(errors="replace") if isinstance(detail, bytes) else str(detail)
    return RawReadError(
        f"{path}: LibRaw cannot read this file ({type(error).__name__}: {detail}); "
        "it is damaged, truncated or not a raw photo"
    )


@contextmanager
def open_raw(path: str | PathLike) -> Iterator[Any]:
    """Open a raw file with LibRaw (`rawpy`); LibRaw's errors, on opening or inside the block,
    become `RawReadError` naming the file.

    Args:
        path: raw file (DNG, CR2, NEF, ARW, RW2, ...).

    Yields:
        the open `rawpy.RawPy`, closed when the block ends.

    Raises:
        RawReadError: if LibRaw cannot read the file.

    Example:
        >>> with open_raw("IMG_0001.dng") as raw:  # doctest: +SKIP
        ...     meta = metadata_from_libraw("IMG_0001.dng", raw)
    """
    import rawpy

    path = Path(path)
    try:
        with rawpy.imread(str(path)) as raw:
            yield raw
    except rawpy.LibRawError as error:
        raise _read_error(path, error) from None


def metadata_from_libraw(path: str | PathLike, raw: Any) -> PhotoMetadata:
    """The `PhotoMetadata` of a raw file opened with `open_raw`: LibRaw's values, else the
    EXIF tags', with `white_balance` set to the camera's.

    Args:
        path: the raw file.
        raw: its open `rawpy.RawPy`.

    Example:
        >>> with open_raw("IMG_0001.dng") as raw:  # doctest: +SKIP
        ...     metadata_from_libraw("IMG_0001.dng", raw).cfa_pattern
        'RGGB'
    """
    path = Path(path)
    tags = _exif_tags(path)
    groups = ("EXIF", "Image", "MakerNote")
    other, lens, sizes = raw.other, raw.lens, raw.sizes
    pattern = None
    if raw.raw_pattern is not None and raw.raw_pattern.shape == (2, 2) and raw.num_colors == 3:
        desc = raw.color_desc.decode()
        pattern = "".join(desc[i] for i in raw.raw_pattern.reshape(-1))
    camera_wb = _wb_rgb(raw.camera_whitebalance)
    matrix, xyz_cam = raw.color_matrix[:, :3], raw.rgb_xyz_matrix[:3]

    def stated(libraw_value: Any, *names: str) -> float | None:
        return _six_digits(libraw_value) or _six_digits(_number(_tag(tags, *names,
                                                                     groups=groups)))

    focal_mm = stated(other.focal_length, "FocalLength")
    resolution = _six_digits(_number(_tag(tags, "FocalPlaneXResolution", groups=groups)))
    pitch = _focal_plane_pitch(tags, resolution, groups)
    return PhotoMetadata(
        path=path,
        stated=_known(focal_length=None if focal_mm is None else focal_mm * 1e-3,
                      f_number=stated(other.aperture, "FNumber"), pixel_pitch=pitch),
        pixel_pitch_source=None if pitch is None else "focal-plane resolution",
        orientation=_LIBRAW_FLIP_TO_EXIF.get(int(sizes.flip), 1),
        camera_make=_text(_tag(tags, "Make", groups=groups)),
        camera_model=_text(_tag(tags, "Model", "UniqueCameraModel", groups=groups)),
        lens_model=(lens.model.strip() or None) if lens is not None else None,
        exposure_time=stated(other.shutter_speed, "ExposureTime"),
        iso=stated(other.iso_speed, "ISOSpeedRatings"),
        cfa_pattern=pattern,
        black_level=[float(v) for v in raw.black_level_per_channel],
        white_level=float(raw.white_level),
        camera_white_balance=camera_wb,
        daylight_white_balance=_wb_rgb(raw.daylight_whitebalance),
        white_balance=camera_wb or (1.0, 1.0, 1.0),
        colour_matrix=matrix.tolist() if bool((matrix != 0).any()) else None,
        xyz_to_camera=xyz_cam.tolist() if bool((xyz_cam != 0).any()) else None,
        raw_size=(int(sizes.height), int(sizes.width)),
    )


def _stored_size(path: Path) -> tuple[int, int] | None:
    """`(height, width)` of the image stored in `path`, from its header; None if unreadable."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            return image.height, image.width
    except (UnidentifiedImageError, OSError, ValueError):
        return None


def _photo_pitch(tags: dict[str, Any], focal_mm: float | None,
                 size: tuple[int, int] | None) -> tuple[float | None, str | None]:
    """The stored image's pixel pitch and the tags it came from (`None, None` where none)."""
    height, width = size if size is not None else (0, 0)
    pitch = _focal_plane_pitch(tags, _number(_tag(tags, "FocalPlaneXResolution")), ("EXIF",))
    if pitch is not None:  # at the sensor's full width, which PixelXDimension gives
        stored_width = _number(_tag(tags, "ExifImageWidth"))
        if stored_width is not None and width:
            pitch *= stored_width / width
        return pitch, "focal-plane resolution"
    equivalent = _number(_tag(tags, "FocalLengthIn35mmFilm"))
    if focal_mm is not None and equivalent is not None and width and height:
        # the crop factor f_35mm / f shrinks the full-frame diagonal to the stored image's
        return FULL_FRAME_DIAGONAL * focal_mm / equivalent / float(np.hypot(width, height)), \
            "35 mm equivalent"
    return None, None


def _photo_metadata(path: Path, size: tuple[int, int] | None) -> PhotoMetadata:
    """The `PhotoMetadata` of a JPEG, TIFF, PNG or WebP photo, from its EXIF tags alone."""
    tags = _exif_tags(path)
    with open(path, "rb") as handle:
        compressed = handle.read(3) == b"\xff\xd8\xff"  # JPEG (and MPO, JPEG's multi-picture)
    focal = _number(_tag(tags, "FocalLength"))
    pitch, source = _photo_pitch(tags, focal, size)
    distance = _number(_tag(tags, "SubjectDistance"))
    if distance is not None and distance >= _INFINITE_DISTANCE:
        distance = None
    return PhotoMetadata(
        path=path,
        stated=_known(focal_length=None if focal is None else focal / 1000.0,
                      f_number=_number(_tag(tags, "FNumber")), focus_distance=distance,
                      pixel_pitch=pitch),
        pixel_pitch_source=source,
        orientation=_integer(_tag(tags, "Orientation", groups=("Image",)), 1),
        compressed=compressed,
        camera_make=_text(_tag(tags, "Make", groups=("Image",))),
        camera_model=_text(_tag(tags, "Model", groups=("Image",))),
        lens_model=_text(_tag(tags, "LensModel")),
        exposure_time=_number(_tag(tags, "ExposureTime")),
        iso=_number(_tag(tags, "ISOSpeedRatings")),
    )


def read_metadata(
    path: str | PathLike, image_size: tuple[int, int] | None = None
) -> PhotoMetadata:
    """Read what a photo's file states: a raw file (by its suffix, `RAW_SUFFIXES`; works on
    files whose pixel data are missing) or a JPEG, TIFF, PNG or WebP photo.

    Args:
        path: the photo.
        image_size: `(height, width)` of the stored image (before turning it upright), which
            the pixel pitch of a JPEG, TIFF or PNG is scaled to; by default read from the
            file's header. Unused for raw files.

    Returns:
        the `PhotoMetadata` (for a raw file with `white_balance` set to the camera's).

    Raises:
        FileNotFoundError: if `path` does not exist.
        RawReadError: if LibRaw cannot parse a raw file.
        ValueError: if the header of a JPEG, TIFF, PNG or WebP photo cannot be read (and no
            `image_size` is given).

    Example:
        >>> import tempfile, pathlib
        >>> from PIL import Image
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "photo.png"
        >>> Image.new("RGB", (4, 2)).save(path)
        >>> meta = read_metadata(path)
        >>> meta.focal_length, meta.orientation, meta.compressed
        (None, 1, False)
    """
    path = require_file(Path(path), "a photo")
    raw = path.suffix.lower() in RAW_SUFFIXES
    if not raw:
        size = image_size if image_size is not None else _stored_size(path)
        if size is None:
            raise ValueError(f"{path} is not a photo that can be read (JPEG, TIFF, PNG or WebP): "
                             "its header is damaged, cut short or of another format")
        return _photo_metadata(path, size)
    with open_raw(path) as opened:
        return metadata_from_libraw(path, opened)
