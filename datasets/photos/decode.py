"""Your own photos: read a JPEG/PNG/TIFF or raw photo upright, with what its file states.

`read_photo` applies the EXIF orientation (a portrait shot stored sideways comes out upright) and
returns the file's `datasets.photos.PhotoMetadata` (`datasets.photos.read_metadata`, the one reader of what photo
files state: focal length, f-number and pixel pitch where the file states them, the pixel pitch
scaled to the stored image size). TIFFs of more than 8 bits per sample (what raw developers and
scientific cameras write, either byte order) and 16-bit colour or grey+alpha PNGs keep all their
bits: Pillow would cut them to 8, so `tifffile` and `pypng` read those. Unsigned integer samples
(8, 16 or 32 bits) are divided by their type's maximum; signed or floating-point ones are
refused, as they state no scale of light. The camera settings of photos are resolved by
`datasets.photos.settings`.
"""

from __future__ import annotations

import math
import struct
import warnings
import zlib
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch
from kornia.color import linear_rgb_to_rgb, rgb_to_linear_rgb
from torch import Tensor

from ..io import DataFormatError, check_image_size, check_stated_size, require_file
from .metadata import RAW_SUFFIXES, PhotoMetadata, read_metadata

#: How a JPEG, PNG or TIFF stores intensity (`read_photo`).
ENCODINGS = ("srgb", "linear")


def _is_tiff(path: Path) -> bool:
    with open(path, "rb") as file:
        return file.read(4) in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


#: Pillow modes that `np.asarray` gives with all their bits (16-bit grey, either byte order).
_PILLOW_16 = ("I;16", "I;16L", "I;16B")
#: What `read_photo` reads (said by its refusals).
_READ = ("read_photo reads unsigned integer samples of 8, 16 or 32 bits (grey, grey+alpha, RGB "
         "or RGBA)")


def _check_dtype(path: Path, dtype: np.dtype) -> None:
    """Refuse samples other than unsigned integers of at most 32 bits, naming `path`."""
    dtype = np.dtype(dtype)
    if dtype.kind == "u" and dtype.itemsize <= 4:
        return
    why = (" (floating-point TIFFs say nothing of their encoding)" if dtype.kind == "f" else
           ": signed, their negative values are no light" if dtype.kind == "i" else "")
    raise DataFormatError(f"{str(path)!r}: holds {dtype.name} samples{why}; {_READ}: save it "
                          "as an 8- or 16-bit photo")


def _samples(path: Path, array: np.ndarray) -> np.ndarray:
    """Decoded samples as `_to_linear` takes them: `(H,W)` grey (grey+alpha: the alpha dropped)
    or `(H,W,3|4)` RGB(A), unsigned integers in native byte order; anything else refused."""
    _check_dtype(path, array.dtype)
    if array.ndim == 3 and array.shape[2] in (1, 2):
        array = array[..., 0]
    if array.ndim != 2 and not (array.ndim == 3 and array.shape[2] in (3, 4)):
        raise DataFormatError(f"{str(path)!r}: holds samples of shape {array.shape}; {_READ}, "
                              "of shape (H, W) or (H, W, channels)")
    return array.astype(array.dtype.newbyteorder("="), copy=False)


def _pillow_samples(path: Path, image) -> np.ndarray:
    """The samples of a photo Pillow decoded: 8-bit ones as RGB (grey kept grey), 16-bit grey as
    stored; refused for any other mode (Pillow's conversion to RGB would clip it to 8 bits)."""
    from PIL import ImageMode

    if image.mode in ("L", "RGB", *_PILLOW_16):
        return np.asarray(image)
    typestr = ImageMode.getmode(image.mode).typestr
    if typestr in ("|u1", "|b1"):  # palette, grey+alpha, RGBA, CMYK, ...: 8 bits or fewer
        return np.asarray(image.convert("RGB"))
    raise DataFormatError(f"{str(path)!r}: holds samples Pillow decodes as mode {image.mode!r} "
                          f"(numpy {typestr}); {_READ}: save it as an 8- or 16-bit photo")


def _deep_samples(path: Path, opened) -> np.ndarray | None:
    """The samples, as stored, of a photo Pillow would cut to 8 bits or cannot open: a TIFF of
    more than 8 bits per sample (tifffile) or a 16-bit colour or grey+alpha PNG (pypng; Pillow
    opens the latter as RGBA); None for any other photo."""
    if _is_tiff(path) and (opened is None or
                           max(opened.tag_v2.get(258, (8,)), default=8) > 8):
        return _tiff_samples(path, opened)
    if opened is not None and opened.format == "PNG" and opened.mode in ("RGB", "RGBA"):
        import png

        with open(path, "rb") as handle:
            width, height, rows, meta = png.Reader(file=handle).asDirect()
            if meta["bitdepth"] <= 8:
                return None
            planes = meta["planes"]
            array = np.empty((height, width * planes), np.uint16)  # row by row: no 2nd copy
            for index, row in enumerate(rows):
                array[index] = row
        return array.reshape(height, width, planes)
    return None


def _tiff_samples(path: Path, opened) -> np.ndarray | None:
    """A TIFF's first image as tifffile decodes it, `(H,W)` or `(H,W,C)`; None where tifffile
    cannot decode it and Pillow (`opened`) reads it instead."""
    import tifffile
    from PIL import ImageMode

    _check_tiff_header(path)
    try:
        array = tifffile.imread(path, key=0)
    except Exception as error:  # noqa: BLE001 (tifffile raises many kinds)
        if opened is None:
            raise DataFormatError(
                f"{str(path)!r}: cannot be read as a photo ({error})") from None
        if opened.mode in _PILLOW_16:  # Pillow keeps all 16 bits
            return None
        if ImageMode.getmode(opened.mode).typestr != "|u1":
            raise DataFormatError(
                f"{str(path)!r}: tifffile cannot decode it ({error}; with the imagecodecs "
                f"package it may) and Pillow decodes it as mode {opened.mode!r}; {_READ}"
            ) from None
        warnings.warn(f"{path}: read with 8 bits per channel only, tifffile cannot decode "
                      f"it ({error}); with the imagecodecs package installed all are kept",
                      UserWarning, stacklevel=5)
        return None
    if array.ndim == 3 and array.shape[0] in (3, 4) and array.shape[-1] not in (3, 4):
        array = np.moveaxis(array, 0, -1)  # stored plane by plane
    return array


def _check_tiff_header(path: Path) -> None:
    """Refuse, from its header, a TIFF of other than unsigned integer samples, other than grey
    or RGB, or of more than `MAX_IMAGE_PIXELS` pixels: Pillow reads no floating-point TIFF's
    header (`check_image_size` cannot), and tifffile would decode it all first."""
    import tifffile

    try:
        with tifffile.TiffFile(path) as tiff:
            page = tiff.pages[0]
            shape, dtype, photometric = tuple(page.shape), page.dtype, page.photometric
    except Exception:  # noqa: BLE001 (no readable header: reading the file says what is wrong)
        return
    if dtype is not None:
        _check_dtype(path, dtype)
    grey_or_rgb = (tifffile.PHOTOMETRIC.MINISBLACK, tifffile.PHOTOMETRIC.RGB)
    if photometric not in grey_or_rgb:
        raise DataFormatError(
            f"{str(path)!r}: holds {getattr(photometric, 'name', photometric)} samples "
            f"(TIFF photometric interpretation); {_READ}: save it as grey (min-is-black) or RGB")
    if len(shape) >= 2:
        planes = len(shape) == 3 and shape[0] in (3, 4) and shape[-1] not in (3, 4)
        check_stated_size(path, *(shape[1:3] if planes else shape[:2]))


#: EXIF orientation -> the turn that shows the stored `(H,W,C)` array upright.
_UPRIGHT = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],
    3: lambda a: a[::-1, ::-1],
    4: lambda a: a[::-1],
    5: lambda a: a.swapaxes(0, 1),
    6: lambda a: np.rot90(a, -1),
    7: lambda a: a.swapaxes(0, 1)[::-1, ::-1],
    8: lambda a: np.rot90(a, 1),
}


def _orient(array: np.ndarray, orientation: int) -> np.ndarray:
    return _UPRIGHT.get(orientation, _UPRIGHT[1])(array)


def _read_raw_photo(path: Path, dtype: torch.dtype) -> tuple[Tensor, PhotoMetadata]:
    """A raw photo as linear sRGB, upright, and what its metadata says."""
    from .raw import read_raw

    # daylight white balance: the same gains for every shot (as-shot ones may differ between
    # shots), divided by the largest so that only saturated photosites reach 1
    image, meta = read_raw(path, white_balance="daylight", colour_space="srgb", dtype=dtype)
    image = (image[0] / max(meta.white_balance)).clamp(0, 1)
    upright = _orient(image.permute(1, 2, 0).numpy(), meta.orientation)
    return torch.from_numpy(np.ascontiguousarray(upright)).permute(2, 0, 1), meta


#: Values converted at a time when a photo's samples become floating point (`read_photo`): the
#: conversion holds no full-size temporary besides the photo itself.
BLOCK_VALUES = 1 << 22
#: Gives the tensor `(3, H, W)` that a photo of `(H, W)` pixels is decoded into (`read_photo`).
Allocator = Callable[[tuple[int, int]], Tensor]


def _row_blocks(height: int, width: int) -> Iterator[slice]:
    """Slices of rows that cover `height` rows of `width` RGB pixels in blocks of at most
    `BLOCK_VALUES` values (at least one row each)."""
    rows = max(1, BLOCK_VALUES // (3 * width))
    return (slice(start, start + rows) for start in range(0, height, rows))


def _to_linear(array: np.ndarray, dtype: torch.dtype, encoding: str,
               into: Allocator | None) -> Tensor:
    """`(H,W)` or `(H,W,C)` unsigned samples (`_samples`: the first three channels RGB) as a linear `(3,H,W)`
    tensor in [0, 1], converted a block of rows at a time: no full-size float temporary."""
    scale = float(np.iinfo(array.dtype).max) if np.issubdtype(array.dtype, np.integer) else 1.0
    if array.ndim == 2:  # grey: the same samples in each channel, copied block by block
        array = np.broadcast_to(array[..., None], (*array.shape, 3))
    height, width = array.shape[:2]
    # the stored layout (rows of RGB triples) unless the caller gives the tensor to fill
    image = torch.empty((height, width, 3), dtype=dtype).permute(2, 0, 1) if into is None \
        else into((height, width))
    for rows in _row_blocks(height, width):
        block = torch.from_numpy(np.array(array[rows, :, :3]))  # a small copy
        block = block.to(image.dtype).permute(2, 0, 1).div_(scale)
        image[:, rows] = rgb_to_linear_rgb(block) if encoding == "srgb" else block
    return image


def read_photo(path: str | Path, dtype: torch.dtype = torch.float32, encoding: str = "srgb",
               into: Allocator | None = None) -> tuple[Tensor, PhotoMetadata]:
    """Read an RGB photo upright as linear intensity `(3,H,W)` in [0, 1].

    The samples become floating point a block of rows at a time: a 100-megapixel photo takes
    its float32 result (1.2 GB) and its decoded samples (0.6 GB at 16 bits), no more.

    Args:
        path: JPEG, PNG or TIFF file of unsigned 8-, 16- or 32-bit samples, all bits kept
            (grey is copied to R, G and B; an alpha channel is dropped), or a raw
            photo (`RAW_SUFFIXES`: DNG, CR2, NEF, ARW, ...), decoded by LibRaw to linear sRGB
            with daylight white balance: no compression, no tone curve, the camera's own bits.
        dtype: floating dtype of the result.
        encoding: how a JPEG, PNG or TIFF stores intensity: `"srgb"` (what cameras and phones
            write) or `"linear"` (values proportional to the light, as scientific cameras and
            some 16-bit exports store them). Raw photos are always linear.
        into: called with the photo's upright `(H, W)` once it is decoded, returns the `(3,H,W)`
            tensor to write it into (e.g. one photo of a stack allocated for all of them, which
            spares a copy of each; its dtype is kept); it may refuse a size.

    Returns:
        `(image, info)`: the photo and its `datasets.photos.PhotoMetadata` (what the file states; the
        orientation is applied to the image).

    Raises:
        FileNotFoundError: `path` does not exist.
        DataFormatError: the file cannot be read as a grey or RGB photo (e.g. it holds
            signed or floating-point samples, or CMYK), or its header (a raw
            file's metadata) states more than `datasets.io.MAX_IMAGE_PIXELS` (read before any
            pixel is decoded).

    Example:
        >>> import tempfile, pathlib
        >>> from PIL import Image
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "photo.png"
        >>> Image.new("RGB", (4, 2), (255, 0, 0)).save(path)
        >>> image, info = read_photo(path)
        >>> image.shape, info.focal_length
        (torch.Size([3, 2, 4]), None)
        >>> stack = torch.zeros(2, 3, 2, 4)
        >>> _ = read_photo(path, into=lambda size: stack[1])
        >>> stack[1, 0, 0, 0].item()
        1.0
    """
    if encoding not in ENCODINGS:
        raise ValueError(f"encoding must be one of {ENCODINGS}, got {encoding!r}")
    path = Path(path)
    require_file(path, "a photo")
    if path.suffix.lower() in RAW_SUFFIXES:
        image, info = _read_raw_photo(path, dtype)
        if into is not None:
            image = into(tuple(image.shape[-2:])).copy_(image)
        return image, info
    check_image_size(path, "a photo")  # refused before decoding above MAX_IMAGE_PIXELS
    array, info = _decoded(path)
    return _to_linear(array, dtype, encoding, into), info


def _decoded(path: Path) -> tuple[np.ndarray, PhotoMetadata]:
    """The samples of a JPEG, PNG or TIFF, upright, as stored (`_samples`), and what the file
    states."""
    from PIL import Image, ImageOps, UnidentifiedImageError

    try:
        with warnings.catch_warnings():  # the size was checked: `check_image_size`
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            # from a file object, not `path`: Pillow memory-maps an uncompressed grey TIFF
            # opened by name with its turned size (orientations 5-8), which scrambles it
            with open(path, "rb") as handle, Image.open(handle) as opened:
                info = read_metadata(path, image_size=(opened.height, opened.width))
                deep = _deep_samples(path, opened)
                if deep is None:
                    upright = ImageOps.exif_transpose(opened)
                    return _samples(path, _pillow_samples(path, upright)), info
    except DataFormatError:
        raise
    except (UnidentifiedImageError, OSError, ValueError) as error:
        # Pillow reads no floating-point colour TIFF: tifffile says what it holds
        deep = _deep_samples(path, None)
        if deep is None:
            raise DataFormatError(f"{str(path)!r}: cannot be read as a photo ({error})") from None
        info = PhotoMetadata(path)
    return _orient(_samples(path, deep), info.orientation), info


#: The largest share of a photo's pixels that may be black or saturated (clipped) for defocus to
#: be read from the rest.
MAX_CLIPPED_FRACTION = 0.99


def check_photo_content(photo: Tensor, name: str = "photo") -> None:
    """Refuse a linear photo `(3,H,W)` without texture for defocus to blur: one flat colour,
    or all but `1 - MAX_CLIPPED_FRACTION` of its pixels black or saturated.

    Example:
        >>> check_photo_content(torch.rand(3, 8, 8))
        >>> check_photo_content(torch.zeros(3, 8, 8), "near.png")
        Traceback (most recent call last):
        ...
        ValueError: near.png is one flat colour (every pixel 0 in linear intensity): it has no texture for defocus to blur
    """
    # one pass, block by block (no full-size temporary): the range and the clipped pixels
    low, high, clipped = float("inf"), float("-inf"), 0
    for rows in _row_blocks(photo.shape[-2], photo.shape[-1]):
        darkest, brightest = photo[:, rows].aminmax(dim=0)
        low, high = min(low, float(darkest.min())), max(high, float(brightest.max()))
        clipped += int(((brightest <= 1e-4) | (darkest >= 0.999)).sum())
    if high - low <= 1e-6:
        raise ValueError(f"{name} is one flat colour (every pixel {low:.3g} in linear "
                         "intensity): it has no texture for defocus to blur")
    height, width = photo.shape[-2], photo.shape[-1]
    fraction = clipped / max(height * width, 1)
    if fraction > MAX_CLIPPED_FRACTION:
        raise ValueError(f"{name} is {fraction:.1%} black or saturated pixels (at most "
                         f"{MAX_CLIPPED_FRACTION:.0%} may be): too little texture for defocus "
                         "to blur; check the exposure")


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
    encoded = linear_rgb_to_rgb(image.detach().cpu().float().clamp(0, 1)).clamp(0, 1)
    array = (encoded.permute(1, 2, 0).numpy() * 65535 + 0.5).astype(np.uint16)
    path = Path(path)
    path.write_bytes(png_rgb16(array))
    return path


def png_rgb16(array: np.ndarray, level: int = 1) -> bytes:
    """The PNG file of a 16-bit RGB image `(H,W,3)` uint16, rows unfiltered, zlib `level`.

    Pillow writes no 16-bit colour PNG and pypng encodes row by row in Python (a 12-megapixel
    photo: 5.3 s against 2.8 s here, sRGB encoding included); the format is four chunks.

    Example:
        >>> import io
        >>> from PIL import Image
        >>> array = np.arange(24, dtype=np.uint16).reshape(2, 4, 3) * 2000
        >>> Image.open(io.BytesIO(png_rgb16(array))).size
        (4, 2)
    """
    h, w, _ = array.shape
    rows = np.zeros((h, 1 + w * 6), np.uint8)  # each row: filter type 0, then big-endian samples
    rows[:, 1:] = array.astype(">u2").reshape(h, -1).view(np.uint8)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data \
            + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
            + chunk(b"IDAT", _deflate(rows.tobytes(), level)) + chunk(b"IEND", b""))


def _deflate(data: bytes, level: int, parts: int = 2) -> bytes:
    """`zlib.compress(data, level)`'s stream, its parts compressed in `parts` threads (zlib
    releases the GIL): each part a run of deflate blocks ended on a byte boundary (a sync
    flush), the last one finished, between zlib's header and the Adler-32 of `data`."""
    size = math.ceil(len(data) / parts)

    def deflate(start: int) -> bytes:
        packer = zlib.compressobj(level, zlib.DEFLATED, -15)
        last = start + size >= len(data)
        return packer.compress(data[start:start + size]) \
            + packer.flush(zlib.Z_FINISH if last else zlib.Z_SYNC_FLUSH)

    with ThreadPoolExecutor(parts) as pool:
        body = b"".join(pool.map(deflate, range(0, max(len(data), 1), size or 1)))
    header = struct.pack(">BB", 0x78, 0x01)  # deflate, 32 KiB window; a valid check value
    return header + body + struct.pack(">I", zlib.adler32(data))
