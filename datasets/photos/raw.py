"""Reading raw photos: linear camera RGB and the metadata a calibration needs.

Raw files are decoded by LibRaw (through `rawpy`) without any tone processing: the black level is
subtracted, values are divided by `white_level - black_level` (so a saturated pixel reads 1), the
Bayer mosaic is demosaiced (or binned), and there is no gamma, no auto-brightness and no clipping
by white balance (white balance is applied here, after decoding, so balanced values may exceed 1).
Colour conversion to linear sRGB or CIE XYZ uses the camera's colour matrix (from the file, as
LibRaw reads it) and colour-science's sRGB definition.

The metadata (`datasets.photos.PhotoMetadata`: camera and lens, exposure, focal length, f-number, pixel
pitch, levels, CFA, white balance) are read by `datasets.photos.read_metadata`, the one reader of what
photo files state; `read_raw` returns them with the binning, white balance and colour space of
the decoded image.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ..io import MAX_IMAGE_PIXELS, oversize_reason, require_args, require_file, require_one_size
from .metadata import PhotoMetadata, RawReadError, metadata_from_libraw, open_raw

#: White-balance choices of `read_raw`.
WHITE_BALANCES = ("camera", "daylight", "none")
#: Output colour spaces of `read_raw` (all linear).
COLOUR_SPACES = ("camera", "srgb", "xyz")
#: Files smaller than this many bytes per photosite cannot hold the image they declare.
MIN_BYTES_PER_PHOTOSITE = 0.02
#: LibRaw demosaicing algorithms offered by `read_raw`.
DEMOSAIC_ALGORITHMS = ("linear", "ahd", "dcb", "vng", "ppg")


def _srgb_to_xyz() -> Tensor:
    import colour

    return torch.as_tensor(colour.RGB_COLOURSPACES["sRGB"].matrix_RGB_to_XYZ)


def _options(white_balance: str, colour_space: str, binning: int, demosaic: str,
             dtype: torch.dtype) -> tuple[str, str, str]:
    """`read_raw`'s door: `(white_balance, colour_space, demosaic)` in lower case, refused by one
    table naming the option."""
    white_balance, colour_space, demosaic = (v.lower() if isinstance(v, str) else v
                                             for v in (white_balance, colour_space, demosaic))
    require_args(
        ("dtype", dtype, isinstance(dtype, torch.dtype) and dtype.is_floating_point,
         "a floating-point torch dtype (torch.float32, torch.float64, ...): the image is scaled "
         "to [0, 1] and white-balanced, which integers would truncate"),
        *((name, value, value in allowed, f"one of {list(allowed)}") for name, value, allowed in (
            ("white_balance", white_balance, WHITE_BALANCES),
            ("colour_space", colour_space, COLOUR_SPACES),
            ("demosaic", demosaic, DEMOSAIC_ALGORITHMS))),
        ("binning", binning, isinstance(binning, int) and not isinstance(binning, bool) and
         binning >= 1, "an integer >= 1"),
        ("white_balance", white_balance, colour_space == "camera" or white_balance != "none",
         f"'camera' or 'daylight': colour_space={colour_space!r} needs white-balanced camera RGB"))
    return white_balance, colour_space, demosaic


def _require_image_data(path: Path, visible: np.ndarray) -> None:
    """Refuse a file whose pixel data are stripped or truncated.

    A stripped file is far smaller than any encoding of its pixels (real raws, even lossy DNGs,
    take > 0.3 byte per photosite; stripped ones < 0.01), and LibRaw then fills the missing
    data with zeros or stale memory from an earlier file, so its values cannot tell.
    """
    bytes_per_photosite = path.stat().st_size / max(visible.size, 1)
    sample = visible.reshape(-1)[:: max(visible.size // 100_000, 1)]
    distinct = len(np.unique(sample)) if sample.size else 0
    if bytes_per_photosite < MIN_BYTES_PER_PHOTOSITE or distinct <= 16:
        raise RawReadError(
            f"{path}: the file holds no image data ({path.stat().st_size} bytes for "
            f"{visible.size} photosites, {distinct} distinct raw values); its pixel data "
            "are probably stripped or truncated. Use read_metadata() for its metadata"
        )


def check_raw_size(path: Path, sizes: Any, max_pixels: int = MAX_IMAGE_PIXELS) -> None:
    """Refuse (`RawReadError`) a raw file whose metadata (LibRaw's `sizes`, read before any
    pixel is unpacked) states more than `max_pixels` photosites.

    Example:
        >>> from types import SimpleNamespace
        >>> check_raw_size(Path("x.dng"), SimpleNamespace(raw_height=12000, raw_width=12000))
        Traceback (most recent call last):
        ...
        datasets.photos.metadata.RawReadError: x.dng: its metadata states 12000x12000 photosites (144 megapixels); at most 100 megapixels are read
    """
    reason = oversize_reason(sizes.raw_height, sizes.raw_width, "photosites", max_pixels)
    if reason is not None:
        raise RawReadError(f"{path}: its metadata states {reason}")


def _decode(path: Path, demosaic: str, binning: int,
            max_pixels: int = MAX_IMAGE_PIXELS) -> tuple[np.ndarray, PhotoMetadata, bool]:
    """LibRaw's linear camera RGB `(H, W, 3)` uint16 of `path`, its metadata, and whether the
    Bayer quads were binned (half size); a file of more than `max_pixels` photosites is
    refused before anything is unpacked (`check_raw_size`)."""
    import rawpy

    with open_raw(path) as raw:
        check_raw_size(path, raw.sizes, max_pixels)
        meta = metadata_from_libraw(path, raw)
        _require_image_data(path, raw.raw_image_visible)
        half = meta.cfa_pattern is not None and binning % 2 == 0
        algorithm = getattr(rawpy.DemosaicAlgorithm, demosaic.upper())
        rgb = raw.postprocess(
            gamma=(1, 1), no_auto_bright=True, output_bps=16, user_wb=[1.0, 1.0, 1.0, 1.0],
            output_color=rawpy.ColorSpace.raw, adjust_maximum_thr=0.0, half_size=half,
            demosaic_algorithm=algorithm, user_flip=0,
        )
    return rgb, meta, half


def _white_balance_of(
    path: Path, meta: PhotoMetadata, white_balance: str
) -> tuple[float, float, float]:
    """The multipliers of `white_balance` (`"camera"` falls back to daylight, with a warning
    to `read_raw`'s caller, where the file has none)."""
    if white_balance == "camera" and meta.camera_white_balance is None:
        warnings.warn(f"{path}: no as-shot white balance in the file; using daylight", stacklevel=3)
        white_balance = "daylight"
    multipliers = {
        "camera": meta.camera_white_balance,
        "daylight": meta.daylight_white_balance,
        "none": (1.0, 1.0, 1.0),
    }[white_balance]
    if multipliers is None:
        raise ValueError(f"{path}: the file has no {white_balance} white balance")
    return multipliers


def _convert_colour(path: Path, image: Tensor, meta: PhotoMetadata, colour_space: str) -> Tensor:
    """White-balanced camera RGB `image` in `colour_space` (the file's colour matrix)."""
    if colour_space == "camera":
        return image
    if meta.colour_matrix is None:
        raise ValueError(f"{path}: the file has no colour matrix; use colour_space='camera'")
    matrix = torch.tensor(meta.colour_matrix, dtype=torch.float64)
    if colour_space == "xyz":
        matrix = _srgb_to_xyz() @ matrix
    return torch.einsum("ij,bjhw->bihw", matrix.to(image), image)


def read_raw(
    path: str | PathLike,
    white_balance: str = "camera",
    colour_space: str = "camera",
    binning: int = 1,
    demosaic: str = "ahd",
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
    max_pixels: int = MAX_IMAGE_PIXELS,
) -> tuple[Tensor, PhotoMetadata]:
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
            (`datasets.photos.settings.metadata_sensor` knows it).
        demosaic: LibRaw algorithm, one of `DEMOSAIC_ALGORITHMS`.
        dtype: floating-point dtype of the image.
        device: device of the image.
        max_pixels: the most photosites decoded (`MAX_IMAGE_PIXELS`, the limit of every photo
            format): a file whose metadata states more is refused before it is unpacked.

    Returns:
        `(image, metadata)`: the image `(1, 3, H, W)` with 0 at the black level and 1 at the
        white level (before white balance), and its `PhotoMetadata` (with the image's
        `binning`, `white_balance` and `colour_space`).

    Raises:
        FileNotFoundError: if `path` does not exist.
        RawReadError: if LibRaw cannot decode the file, it decodes to no data (a constant
            image, e.g. a file whose pixel data were stripped), or its metadata states more
            than `max_pixels` photosites.
        ValueError: for an unknown option, or a colour conversion without a colour matrix or
            without white balance.
        TypeError: if `dtype` is not a floating-point dtype (integers would truncate the
            white balance).

    Example:
        >>> image, meta = read_raw(raw_samples / "canon_eos_6d.dng", binning=4)  # doctest: +SKIP
        >>> image.shape, meta.focal_length, meta.f_number  # doctest: +SKIP
        (torch.Size([1, 3, 204, 306]), 0.065, 5.6)
    """
    white_balance, colour_space, demosaic = _options(
        white_balance, colour_space, binning, demosaic, dtype)
    path = require_file(Path(path), "a raw photo")
    rgb, meta, half = _decode(path, demosaic, binning, max_pixels)
    image = torch.from_numpy(rgb.astype("float32")).to(device=device, dtype=dtype)
    image = image.permute(2, 0, 1).unsqueeze(0) / 65535.0
    pool = binning // 2 if half else binning
    if pool > 1:
        image = F.avg_pool2d(image, pool)
    multipliers = _white_balance_of(path, meta, white_balance)
    image = image * torch.tensor(multipliers, dtype=dtype, device=image.device).view(1, 3, 1, 1)
    image = _convert_colour(path, image, meta, colour_space)
    return image, dataclasses.replace(meta, binning=binning, white_balance=multipliers,
                                      colour_space=colour_space)


def read_raw_stack(
    paths: Sequence[str | PathLike], progress: bool = False, **kwargs: Any
) -> tuple[Tensor, list[PhotoMetadata]]:
    """Read several raw photos of one size with `read_raw`.

    Args:
        paths: raw files, all of the same image size.
        progress: show a tqdm progress bar.
        **kwargs: options of `read_raw`.

    Returns:
        `(images, metadata)`: `(N, 3, H, W)` images and a list of `N` `PhotoMetadata`.

    Raises:
        ValueError: if `paths` is empty or the images differ in size (`DataFormatError`
            naming both files).
    """
    from optics.progress import progress_bar

    paths = list(paths)
    if not paths:
        raise ValueError("paths must name at least one raw file, got an empty list")
    images, metas = [], []
    for path in progress_bar(paths, desc="reading raw", disable=not progress):
        image, meta = read_raw(path, **kwargs)
        images.append(image)
        metas.append(meta)
    require_one_size(*zip((Path(p) for p in paths), images, strict=True))
    return torch.cat(images), metas
