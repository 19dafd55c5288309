"""Reading raw photos: linear camera RGB and the metadata a calibration needs.

Raw files are decoded by LibRaw (through `rawpy`) without any tone processing: the black level is
subtracted, values are divided by `white_level - black_level` (so a saturated pixel reads 1), the
Bayer mosaic is demosaiced (or binned), and there is no gamma, no auto-brightness and no clipping
by white balance (white balance is applied here, after decoding, so balanced values may exceed 1).
Colour conversion to linear sRGB or CIE XYZ uses the camera's colour matrix (from the file, as
LibRaw reads it) and colour-science's sRGB definition.

Camera and lens model, exposure, ISO and the focal-plane resolution come from the EXIF tags
(`exifread`), focal length, f-number, levels, CFA and white balance from LibRaw.
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from .camera import CameraSettings
from .sensor import Sensor

#: White-balance choices of `read_raw`.
WHITE_BALANCES = ("camera", "daylight", "none")
#: Output colour spaces of `read_raw` (all linear).
COLOUR_SPACES = ("camera", "srgb", "xyz")
#: Files smaller than this many bytes per photosite cannot hold the image they declare.
MIN_BYTES_PER_PHOTOSITE = 0.02
#: LibRaw demosaicing algorithms offered by `read_raw`.
DEMOSAIC_ALGORITHMS = ("linear", "ahd", "dcb", "vng", "ppg")


class RawReadError(ValueError):
    """A raw file that LibRaw cannot decode, or that decodes to no image data."""


@dataclass
class RawMetadata:
    """What a raw file says about how it was taken (lengths in metres, times in seconds).

    Attributes:
        path: the file read.
        camera_make: e.g. `"Canon"` (`None` where the file does not say).
        camera_model: e.g. `"Canon EOS 6D"`.
        lens_model: e.g. `"EF24-105mm f/4L IS USM"`.
        focal_length: focal length in metres, e.g. `0.065`.
        f_number: f-number, e.g. `5.6`.
        exposure_time: exposure time in seconds.
        iso: ISO sensitivity.
        pixel_pitch: sensor pixel pitch in metres from the EXIF focal-plane resolution. It refers
            to the image size the camera wrote; a file resized by a converter may state the
            original sensor's value. `None` when absent.
        cfa_pattern: the 2x2 Bayer pattern, e.g. `"RGGB"`; `None` for non-Bayer data
            (linear DNG, X-Trans, Foveon).
        black_level: black level per CFA channel (raw units).
        white_level: white (saturation) level (raw units).
        camera_white_balance: as-shot multipliers `(R, G, B)` normalised to `G = 1`.
        daylight_white_balance: daylight multipliers `(R, G, B)` normalised to `G = 1`.
        white_balance: the multipliers applied to the returned image.
        colour_matrix: 3x3 matrix from white-balanced camera RGB to linear sRGB (rows sum to 1).
        xyz_to_camera: 3x3 matrix from CIE XYZ to camera RGB (the DNG `ColorMatrix`).
        colour_space: colour space of the returned image (`"camera"`, `"srgb"`, `"xyz"`).
        binning: factor by which the returned image is smaller than the sensor grid.
        raw_size: `(height, width)` of the sensor area LibRaw reports as visible.
        orientation: how to turn the returned image upright, as an EXIF orientation (1: as
            is, 3: half a turn, 6: a quarter turn clockwise, 8: counter-clockwise); the image
            itself is returned as the sensor recorded it.
    """

    path: str
    camera_make: str | None = None
    camera_model: str | None = None
    lens_model: str | None = None
    focal_length: float | None = None
    f_number: float | None = None
    exposure_time: float | None = None
    iso: float | None = None
    pixel_pitch: float | None = None
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
    orientation: int = 1

    def sensor(self, pixel_pitch: float | None = None) -> Sensor:
        """A `Sensor` for the returned images (their binning sets `downsample`).

        Args:
            pixel_pitch: sensor pixel pitch in metres; by default the file's `pixel_pitch`.

        Raises:
            ValueError: if neither `pixel_pitch` nor the file gives the pitch.
        """
        pitch = self.pixel_pitch if pixel_pitch is None else pixel_pitch
        if pitch is None:
            raise ValueError(
                f"{self.path}: the file does not state its pixel pitch (EXIF focal-plane "
                "resolution); pass pixel_pitch in metres"
            )
        return Sensor(pitch, resolution=self.raw_size, cfa=self.cfa_pattern, downsample=self.binning)

    @property
    def effective_pixel_pitch(self) -> float | None:
        """Pixel pitch of the returned images in metres: `pixel_pitch` times `binning` (`None`
        where the file does not state the pitch). The value `optics.calibrate` wants."""
        return None if self.pixel_pitch is None else self.pixel_pitch * self.binning

    def camera_settings(
        self,
        focus_distance: float | Sequence[float],
        pixel_pitch: float | None = None,
        aperture: str = "gaussian",
        *,
        focal_length: float | None = None,
        f_number: float | None = None,
    ) -> CameraSettings:
        """The `optics.CameraSettings` of the returned images: the file's focal length and
        f-number, and the effective pixel pitch (sensor pitch times `binning`).

        Most cameras do not record the focus distance, so it is always given.

        Args:
            focus_distance: metres (a number, or one per shot).
            pixel_pitch: *sensor* pixel pitch in metres; by default the file's `pixel_pitch`.
                The settings hold the effective pitch, this times `binning`.
            aperture: the PSF's spec (`"gaussian"`, `"disk"`, `"polygon:6"`, ...).
            focal_length: metres, replacing the file's (for files that do not state it).
            f_number: replacing the file's (for files that do not state it, e.g. manual lenses).

        Returns:
            `(F,)` settings (`F = 1` for one focus distance).

        Raises:
            ValueError: naming each value the file does not state and the argument to pass
                instead, or for settings `CameraSettings` refuses.

        Example:
            >>> meta = RawMetadata("a.dng", focal_length=0.05, f_number=2.8, pixel_pitch=4e-6,
            ...                    binning=2)
            >>> meta.camera_settings(2.0).to_dict()
            {'focal_length': 0.05, 'f_number': 2.8, 'focus_distance': 2.0, 'pixel_pitch': 8e-06, 'psf': 'gaussian:0.5'}
        """
        values = {
            "focal_length": self.focal_length if focal_length is None else focal_length,
            "f_number": self.f_number if f_number is None else f_number,
            "pixel_pitch": self.pixel_pitch if pixel_pitch is None else pixel_pitch,
        }
        missing = {
            "focal_length": "its focal length (EXIF FocalLength): pass focal_length in metres",
            "f_number": "its f-number (EXIF FNumber): pass f_number",
            "pixel_pitch": "its pixel pitch (EXIF focal-plane resolution): pass pixel_pitch, "
            "the sensor pitch in metres",
        }
        problems = [why for name, why in missing.items() if values[name] is None]
        if problems:
            raise ValueError(f"{self.path}: the file does not state " + "; nor ".join(problems))
        return CameraSettings(
            values["focal_length"], values["f_number"], focus_distance,
            values["pixel_pitch"] * self.binning, aperture=aperture,
        )


def _check_choice(name: str, value: str, allowed: Sequence[str]) -> str:
    if not isinstance(value, str) or value.lower() not in allowed:
        raise ValueError(f"{name} must be one of {list(allowed)}, got {value!r}")
    return value.lower()


def _positive_or_none(value: Any) -> float | None:
    try:
        number = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    # LibRaw stores floats in single precision: keep the digits the camera wrote (5.6, not 5.5999).
    return float(f"{number:.6g}") if math.isfinite(number) and number > 0 else None


def _ratio(tag: Any) -> float | None:
    """The first value of an exifread tag as a float (rationals included)."""
    try:
        value = tag.values[0] if isinstance(tag.values, list) else tag.values
        return _positive_or_none(float(value.num) / float(value.den) if hasattr(value, "num")
                                 else value)
    except (AttributeError, IndexError, TypeError, ValueError, ZeroDivisionError):
        return None


def _exif(path: Path) -> dict[str, Any]:
    """EXIF tags of `path` (an empty dict where exifread cannot parse the file)."""
    import exifread

    logger = logging.getLogger("exifread")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with open(path, "rb") as handle:
            return dict(exifread.process_file(handle, details=False))
    except Exception:  # exifread raises many kinds on damaged files; metadata is optional
        return {}
    finally:
        logger.setLevel(level)


def _first_tag(tags: dict[str, Any], *names: str) -> Any:
    for name in names:
        for prefix in ("EXIF ", "Image ", "MakerNote "):
            if prefix + name in tags:
                return tags[prefix + name]
    return None


def _text(tag: Any) -> str | None:
    if tag is None:
        return None
    text = str(tag.printable if hasattr(tag, "printable") else tag).strip().strip("\x00")
    return text or None


def _pixel_pitch(tags: dict[str, Any]) -> float | None:
    resolution = _ratio(_first_tag(tags, "FocalPlaneXResolution"))
    if resolution is None:
        return None
    unit_tag = _first_tag(tags, "FocalPlaneResolutionUnit")
    unit = int(unit_tag.values[0]) if unit_tag is not None else 2
    metres_per_unit = {2: 0.0254, 3: 0.01, 4: 0.001, 5: 1e-6}.get(unit, 0.0254)
    return metres_per_unit / resolution


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


def _open(path: Path):
    import rawpy

    try:
        return rawpy.imread(str(path))
    except rawpy.LibRawError as error:
        raise _read_error(path, error) from None


def read_raw_metadata(path: str | PathLike) -> RawMetadata:
    """Read only the metadata of a raw photo (works on files whose pixel data are missing).

    Args:
        path: raw file (DNG, CR2, NEF, ARW, RW2, ...).

    Returns:
        the `RawMetadata`, with `white_balance` set to the camera's.

    Raises:
        FileNotFoundError: if `path` does not exist.
        RawReadError: if LibRaw cannot parse the file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"raw file not found: {path}")
    import rawpy

    with _open(path) as raw:
        try:
            return _metadata(path, raw)
        except rawpy.LibRawError as error:
            raise _read_error(path, error) from None


#: LibRaw's `flip` (0, 3: 180 degrees, 5: 90 counter-clockwise, 6: 90 clockwise) as the EXIF
#: orientation that turns the image upright.
_LIBRAW_FLIP_TO_EXIF = {0: 1, 3: 3, 5: 8, 6: 6}


def _metadata(path: Path, raw: Any) -> RawMetadata:
    tags = _exif(path)
    other, lens = raw.other, raw.lens
    sizes = raw.sizes
    pattern = None
    if raw.raw_pattern is not None and raw.raw_pattern.shape == (2, 2) and raw.num_colors == 3:
        desc = raw.color_desc.decode()
        pattern = "".join(desc[i] for i in raw.raw_pattern.reshape(-1))
    camera_wb = _wb_rgb(raw.camera_whitebalance)
    matrix = raw.color_matrix[:, :3]
    xyz_cam = raw.rgb_xyz_matrix[:3]
    focal_mm = _positive_or_none(other.focal_length) or _ratio(_first_tag(tags, "FocalLength"))
    return RawMetadata(
        path=str(path),
        camera_make=_text(_first_tag(tags, "Make")),
        camera_model=_text(_first_tag(tags, "Model", "UniqueCameraModel")),
        lens_model=(lens.model.strip() or None) if lens is not None else None,
        focal_length=None if focal_mm is None else focal_mm * 1e-3,
        f_number=_positive_or_none(other.aperture) or _ratio(_first_tag(tags, "FNumber")),
        exposure_time=_positive_or_none(other.shutter_speed)
        or _ratio(_first_tag(tags, "ExposureTime")),
        iso=_positive_or_none(other.iso_speed) or _ratio(_first_tag(tags, "ISOSpeedRatings")),
        pixel_pitch=_pixel_pitch(tags),
        cfa_pattern=pattern,
        black_level=[float(v) for v in raw.black_level_per_channel],
        white_level=float(raw.white_level),
        camera_white_balance=camera_wb,
        daylight_white_balance=_wb_rgb(raw.daylight_whitebalance),
        white_balance=camera_wb or (1.0, 1.0, 1.0),
        colour_matrix=matrix.tolist() if bool((matrix != 0).any()) else None,
        xyz_to_camera=xyz_cam.tolist() if bool((xyz_cam != 0).any()) else None,
        raw_size=(int(sizes.height), int(sizes.width)),
        orientation=_LIBRAW_FLIP_TO_EXIF.get(int(sizes.flip), 1),
    )


def _srgb_to_xyz() -> Tensor:
    import colour

    return torch.as_tensor(colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ)


def read_raw(
    path: str | PathLike,
    white_balance: str = "camera",
    colour_space: str = "camera",
    binning: int = 1,
    demosaic: str = "ahd",
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> tuple[Tensor, RawMetadata]:
    """Decode a raw photo to linear RGB (no gamma, no auto-brightness) and read its metadata.

    Args:
        path: raw file (DNG, CR2, NEF, ARW, RW2, ...).
        white_balance: `"camera"` (as shot; daylight where the file has none), `"daylight"`
            or `"none"` (unit multipliers: raw camera response).
        colour_space: `"camera"` (camera RGB), `"srgb"` (linear sRGB, D65) or `"xyz"`
            (CIE XYZ, D65). The last two need white balance.
        binning: integer factor by which to shrink the image. 1 demosaics at full resolution;
            an even factor first bins each 2x2 Bayer quad into one RGB pixel (LibRaw's half
            size: no interpolation), then averages `binning/2` squares; an odd one averages
            after demosaicing. The effective pixel pitch is the sensor pitch times `binning`
            (`metadata.sensor()` knows it).
        demosaic: LibRaw algorithm, one of `DEMOSAIC_ALGORITHMS`.
        dtype: floating-point dtype of the image.
        device: device of the image.

    Returns:
        `(image, metadata)`: the image `(1, 3, H, W)` with 0 at the black level and 1 at the
        white level (before white balance), and its `RawMetadata`.

    Raises:
        FileNotFoundError: if `path` does not exist.
        RawReadError: if LibRaw cannot decode the file, or it decodes to no data (a constant
            image, e.g. a file whose pixel data were stripped).
        ValueError: for an unknown option, or a colour conversion without a colour matrix or
            without white balance.
        TypeError: if `dtype` is not a floating-point dtype (integers would truncate the
            white balance).

    Example:
        >>> image, meta = read_raw(raw_samples / "canon_eos_6d.dng", binning=4)  # doctest: +SKIP
        >>> image.shape, meta.focal_length, meta.f_number  # doctest: +SKIP
        (torch.Size([1, 3, 204, 306]), 0.065, 5.6)
    """
    import rawpy

    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise TypeError(
            f"dtype must be a floating-point torch dtype (torch.float32, torch.float64, ...), "
            f"got {dtype!r}: the image is scaled to [0, 1] and white-balanced, which integers "
            "would truncate"
        )
    white_balance = _check_choice("white_balance", white_balance, WHITE_BALANCES)
    colour_space = _check_choice("colour_space", colour_space, COLOUR_SPACES)
    demosaic = _check_choice("demosaic", demosaic, DEMOSAIC_ALGORITHMS)
    if isinstance(binning, bool) or not isinstance(binning, int) or binning < 1:
        raise ValueError(f"binning must be an integer >= 1, got {binning!r}")
    if colour_space != "camera" and white_balance == "none":
        raise ValueError(
            f"colour_space={colour_space!r} needs white-balanced camera RGB; "
            "use white_balance='camera' or 'daylight'"
        )
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"raw file not found: {path}")
    with _open(path) as raw:
        try:
            meta = _metadata(path, raw)
            visible = raw.raw_image_visible
        except rawpy.LibRawError as error:
            raise _read_error(path, error) from None
        # A stripped file is far smaller than any encoding of its pixels (real raws, even lossy
        # DNGs, take > 0.3 byte per photosite; stripped ones < 0.01), and LibRaw then fills the
        # missing data with zeros or stale memory from an earlier file, so its values cannot tell.
        bytes_per_photosite = path.stat().st_size / max(visible.size, 1)
        sample = visible.reshape(-1)[:: max(visible.size // 100_000, 1)]
        distinct = len(np.unique(sample)) if sample.size else 0
        if bytes_per_photosite < MIN_BYTES_PER_PHOTOSITE or distinct <= 16:
            raise RawReadError(
                f"{path}: the file holds no image data ({path.stat().st_size} bytes for "
                f"{visible.size} photosites, {distinct} distinct raw values); its pixel data "
                "are probably stripped or truncated. Use read_raw_metadata() for its metadata"
            )
        bayer = meta.cfa_pattern is not None
        half = bayer and binning % 2 == 0
        algorithm = getattr(rawpy.DemosaicAlgorithm, demosaic.upper())
        try:
            rgb = raw.postprocess(
                gamma=(1, 1), no_auto_bright=True, output_bps=16, user_wb=[1.0, 1.0, 1.0, 1.0],
                output_color=rawpy.ColorSpace.raw, adjust_maximum_thr=0.0, half_size=half,
                demosaic_algorithm=algorithm, user_flip=0,
            )
        except rawpy.LibRawError as error:
            raise _read_error(path, error) from None
    image = torch.from_numpy(rgb.astype("float32")).to(device=device, dtype=dtype)
    image = image.permute(2, 0, 1).unsqueeze(0) / 65535.0
    pool = binning // 2 if half else binning
    if pool > 1:
        image = F.avg_pool2d(image, pool)
    meta.binning = binning

    if white_balance == "camera" and meta.camera_white_balance is None:
        warnings.warn(f"{path}: no as-shot white balance in the file; using daylight", stacklevel=2)
        white_balance = "daylight"
    multipliers = {
        "camera": meta.camera_white_balance,
        "daylight": meta.daylight_white_balance,
        "none": (1.0, 1.0, 1.0),
    }[white_balance]
    if multipliers is None:
        raise ValueError(f"{path}: the file has no {white_balance} white balance")
    meta.white_balance = multipliers
    image = image * torch.tensor(multipliers, dtype=dtype, device=image.device).view(1, 3, 1, 1)

    if colour_space != "camera":
        if meta.colour_matrix is None:
            raise ValueError(f"{path}: the file has no colour matrix; use colour_space='camera'")
        matrix = torch.tensor(meta.colour_matrix, dtype=torch.float64)
        if colour_space == "xyz":
            matrix = _srgb_to_xyz() @ matrix
        image = torch.einsum("ij,bjhw->bihw", matrix.to(image), image)
    meta.colour_space = colour_space
    return image, meta


def read_raw_stack(
    paths: Sequence[str | PathLike], progress: bool = False, **kwargs: Any
) -> tuple[Tensor, list[RawMetadata]]:
    """Read several raw photos of one size with `read_raw`.

    Args:
        paths: raw files, all of the same image size.
        progress: show a tqdm progress bar.
        **kwargs: options of `read_raw`.

    Returns:
        `(images, metadata)`: `(N, 3, H, W)` images and a list of `N` `RawMetadata`.

    Raises:
        ValueError: if `paths` is empty or the images differ in size (the message names both).
    """
    from .progress import progress_bar

    paths = list(paths)
    if not paths:
        raise ValueError("paths must name at least one raw file, got an empty list")
    images, metas = [], []
    for path in progress_bar(paths, desc="reading raw", disable=not progress):
        image, meta = read_raw(path, **kwargs)
        if images and image.shape != images[0].shape:
            raise ValueError(
                f"all images must have one size: {paths[0]} is {tuple(images[0].shape[-2:])}, "
                f"{path} is {tuple(image.shape[-2:])}"
            )
        images.append(image)
        metas.append(meta)
    return torch.cat(images), metas
