"""Reading dataset files with errors that name the file and say what was expected.

Every reader raises `FileNotFoundError` for a missing file and `DataFormatError`
(a `ValueError`) for a file that exists but cannot be read as expected (truncated, wrong format,
wrong shape), so a broken download fails at once with the path in the message instead of deep
inside a DataLoader worker.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor


class DataFormatError(ValueError):
    """A dataset file exists but does not hold what the loader expects."""


class ArgumentError(ValueError, TypeError):
    """An argument refused at a loader's door, for its value or its type (catch either)."""


def require_args(*rules: tuple[str, Any, Any, str]) -> None:
    """The door of a constructor: refuse the first `(name, value, ok, allowed)` rule whose `ok`
    is false with one `ArgumentError` naming the argument, what is allowed and the value given.

    Example:
        >>> require_args(("split", "tset", "tset" in ("train", "test"), "one of ('train', 'test')"))
        Traceback (most recent call last):
        ...
        datasets.io.ArgumentError: split must be one of ('train', 'test'), got 'tset'
    """
    for name, value, ok, allowed in rules:
        if not ok:
            raise ArgumentError(f"{name} must be {allowed}, got {value!r}")


def is_size(size: Any) -> bool:
    """Whether `size` is `(height, width)` pixels, both > 0 (None too: no size).

    Example:
        >>> is_size((96, 128)), is_size((96, 0)), is_size(None)
        (True, False, True)
    """
    return size is None or (len(size) == 2 and all(int(s) > 0 for s in size))


def require_root(root: str | Path | None, dataset: str, layout: str) -> Path:
    """Check that a dataset's `root` folder exists; `layout` describes what it must hold."""
    path = Path(root or "").expanduser()
    if root is None or not path.is_dir():
        raise FileNotFoundError(
            f"{dataset}: root folder {None if root is None else str(path)!r} does not exist or is "
            f"not a folder (root must be the dataset folder). Expected:\n{layout}")
    return path


def require_file(path: Path, what: str) -> Path:
    """Raise `FileNotFoundError` naming `path` and `what` it should hold unless it exists
    (`IsADirectoryError` where it is a folder).

    Example:
        >>> require_file(Path("."), "a photo")
        Traceback (most recent call last):
        ...
        IsADirectoryError: '.' is a folder: expected a photo, a file
    """
    if path.is_dir():
        raise IsADirectoryError(f"{str(path)!r} is a folder: expected {what}, a file")
    if not path.is_file():
        raise FileNotFoundError(f"missing file {str(path)!r}: expected {what}")
    return path


def read_text(path: Path, what: str = "a text file") -> str:
    """The text of a dataset's text file (UTF-8); a file that is not is refused naming it.

    A leading byte-order mark (as Windows editors write) is dropped, so it does not become part
    of the first name in a list.

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "list.txt"
        >>> _ = path.write_bytes(bytes([115, 99, 101, 110, 101, 255]))
        >>> read_text(path, "a scene list")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        datasets.io.DataFormatError: ...list.txt': expected a scene list in UTF-8 text, but byte 6 is 0xff (a binary or otherwise encoded file)
    """
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as error:
        raise DataFormatError(
            f"{str(path)!r}: expected {what} in UTF-8 text, but byte {error.start + 1} is "
            f"0x{error.object[error.start]:02x} (a binary or otherwise encoded file)") from None


def check_array_shape(path: Path, name: str, array: np.ndarray, dims: Sequence[int | None]) -> None:
    """Raise `DataFormatError` unless `array` has `len(dims)` axes of those sizes.

    `None` in `dims` accepts any size.
    """
    shape = tuple(array.shape)
    if len(shape) != len(dims) or any(
        d is not None and d != s for d, s in zip(dims, shape, strict=True)
    ):
        wanted = "(" + ", ".join("any" if d is None else str(d) for d in dims) + ")"
        raise DataFormatError(f"{str(path)!r}: {name} must have shape {wanted}, got {shape}")


def read_list(path: Path, what: str = "a list of names") -> list[str]:
    """The names of a list file (one per line; blank lines skipped, spaces around a name
    dropped), refused where it names none or one twice (a duplicate would be counted twice).

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "test.txt"
        >>> _ = path.write_text("a\\nb\\n\\na\\n")
        >>> read_list(path, "a scene list")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        datasets.io.DataFormatError: ...test.txt': 'a' is listed twice (lines 1 and 4); a scene list must name each entry once
    """
    first: dict[str, int] = {}
    for number, line in enumerate(read_text(path, what).splitlines(), start=1):
        name = line.strip()
        if not name:
            continue
        if name in first:
            raise DataFormatError(f"{str(path)!r}: {name!r} is listed twice (lines {first[name]} "
                                  f"and {number}); {what} must name each entry once")
        first[name] = number
    if not first:
        raise DataFormatError(f"{str(path)!r}: {what} names nothing (the file is empty or blank)")
    return list(first)


def read_numbers(path: Path, what: str, columns: int | None = None) -> list[list[float]]:
    """The rows of a text table of numbers (blank lines and `#` comments skipped), refused
    naming the file and line where a line is not numbers or, with `columns`, not that many.

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "focus.txt"
        >>> _ = path.write_text("0.1\\n0.2 1\\n")
        >>> read_numbers(path, "one focus value a line", 1)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        datasets.io.DataFormatError: ...focus.txt': not lines of numbers (one focus value a line): line 2 is '0.2 1', 2 columns
    """
    rows = []
    for number, line in enumerate(read_text(require_file(path, what), what).splitlines(), 1):
        if not (fields := line.split("#")[0].split()):
            continue
        try:
            rows.append([float(v) for v in fields])
        except ValueError:
            rows.append(None)
        if rows[-1] is None or columns is not None and len(fields) != columns:
            raise DataFormatError(f"{str(path)!r}: not lines of numbers ({what}): line {number} "
                                  f"is {line.strip()!r}" + (f", {len(fields)} columns" if rows[-1]
                                                            else ""))
    return rows


#: The most pixels of an image file that is decoded (100 megapixels), for every format: a PNG,
#: JPEG or TIFF whose header states more (`check_image_size`) or a raw file whose metadata states
#: more photosites (`datasets.photos.read_raw`) is refused before any pixel is decoded.
MAX_IMAGE_PIXELS = 100_000_000


def oversize_reason(height: int, width: int, what: str = "pixels",
                    max_pixels: int = MAX_IMAGE_PIXELS) -> str | None:
    """Why an image whose file states `height` x `width` `what` (pixels, photosites) is not
    decoded, or None where it is within `max_pixels`.

    Example:
        >>> oversize_reason(20000, 20000)
        '20000x20000 pixels (400 megapixels); at most 100 megapixels are read'
        >>> oversize_reason(4000, 6000) is None
        True
    """
    height, width = int(height), int(width)
    if height * width <= max_pixels:
        return None
    return (f"{height}x{width} {what} ({height * width / 1e6:.4g} megapixels); at most "
            f"{max_pixels / 1e6:g} megapixels are read")


def check_image_size(path: Path, what: str = "an image",
                     max_pixels: int = MAX_IMAGE_PIXELS) -> tuple[int, int] | None:
    """The `(H, W)` an image file's header states, read without decoding a pixel; refused
    (`DataFormatError`) above `max_pixels`. None where Pillow cannot read the header (other
    readers then try the file).

    Example:
        >>> import tempfile
        >>> from PIL import Image
        >>> path = Path(tempfile.mkdtemp()) / "photo.png"
        >>> Image.new("RGB", (40, 30)).save(path)
        >>> check_image_size(path)
        (30, 40)
        >>> check_image_size(path, max_pixels=1000)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        datasets.io.DataFormatError: ...photo.png': its header states 30x40 pixels (0.0012 megapixels); at most 0.001 megapixels are read
    """
    import warnings

    from PIL import Image

    too_large = f"at most {max_pixels / 1e6:g} megapixels are read"
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as opened:
                width, height = opened.size
    except Image.DecompressionBombError as error:  # beyond Pillow's own limit
        stated = re.search(r"\((\d+) pixels\)", str(error))
        count = f"{int(stated[1]) / 1e6:.4g} megapixels" if stated else "too many pixels"
        raise DataFormatError(f"{str(path)!r}: its header states {count}; {too_large}") from None
    except Exception:  # noqa: BLE001 (not an image Pillow reads: the caller's reader decides)
        return None
    check_stated_size(path, height, width, max_pixels)
    return height, width


def check_stated_size(path: Path, height: int, width: int,
                      max_pixels: int = MAX_IMAGE_PIXELS) -> None:
    """Refuse (`DataFormatError`) an image whose header states more than `max_pixels` pixels.

    Example:
        >>> check_stated_size(Path("a.tif"), 20000, 20000)
        Traceback (most recent call last):
        ...
        datasets.io.DataFormatError: 'a.tif': its header states 20000x20000 pixels (400 megapixels); at most 100 megapixels are read
    """
    reason = oversize_reason(height, width, "pixels", max_pixels)
    if reason is not None:
        raise DataFormatError(f"{str(path)!r}: its header states {reason}")


def read_image(path: Path, what: str = "an image") -> np.ndarray:
    """Read a PNG/JPEG as an `(H,W)` or `(H,W,C)` array of its stored dtype (uint8/uint16);
    a header that states more than `MAX_IMAGE_PIXELS` is refused before decoding."""
    import imageio.v3 as iio

    require_file(path, what)
    check_image_size(path, what)
    try:
        array = iio.imread(path)
    except Exception as error:  # imageio raises many types for broken files
        raise DataFormatError(
            f"{str(path)!r}: cannot be read as {what} ({type(error).__name__}: {error}); "
            "the file may be truncated or not an image"
        ) from error
    return np.asarray(array)


def to_unit_range(path: Path, name: str, array: np.ndarray) -> np.ndarray:
    """An image array as float64 in [0, 1]: integers divided by their dtype's maximum, floats
    kept as they are but required to be finite and within [0, 1].

    Raises:
        DataFormatError: naming `path` for a float image outside [0, 1] (e.g. 0-255 stored as
            float) or with NaN/inf values, or an unsupported dtype (bool, complex, signed ints).
    """
    if np.issubdtype(array.dtype, np.unsignedinteger):
        return array.astype(np.float64) / float(np.iinfo(array.dtype).max)
    floating = np.issubdtype(array.dtype, np.floating)
    values = array.astype(np.float64) if floating else np.zeros(0)
    finite = np.isfinite(values)
    low, high = (float(values[finite].min()), float(values[finite].max())) if finite.any() \
        else (0.0, 0.0)
    if not floating or not finite.all() or low < 0 or high > 1:
        hint = " (it looks like 0-255 stored as float: divide by 255)" if 1 < high <= 255 else ""
        raise DataFormatError(
            f"{str(path)!r}: {name} has dtype {array.dtype}, {int((~finite).sum())} NaN or "
            f"infinite value(s) and values in [{low:.4g}, {high:.4g}]; expected uint8, uint16 or "
            f"a float image, finite and in [0, 1]{hint}")
    return values


def require_one_size(*files: tuple[Path, Tensor | np.ndarray | None]) -> None:
    """Refuse the files of one sample unless their arrays (`None`: absent, skipped) share the
    first one's size `(H, W)`, the last two axes, naming the file that differs and the first.

    Example:
        >>> require_one_size((Path("a.png"), np.zeros((3, 4, 6))), (Path("b.png"), None))
        >>> require_one_size((Path("a.png"), np.zeros((4, 6))), (Path("d.png"), np.zeros((4, 5))))
        Traceback (most recent call last):
        ...
        datasets.io.DataFormatError: 'd.png' is (4, 5) pixels but 'a.png' is (4, 6); the files of a sample must have one size
    """
    first_path, size = files[0][0], tuple(files[0][1].shape[-2:])
    for path, array in files[1:]:
        if array is not None and tuple(array.shape[-2:]) != size:
            raise DataFormatError(f"{str(path)!r} is {tuple(array.shape[-2:])} pixels but "
                                  f"{str(first_path)!r} is {size}; the files of a sample must "
                                  "have one size")


def read_depth_png(path: Path, scale: float, dtype: torch.dtype = torch.float32) -> Tensor:
    """Read a 16-bit single-channel depth PNG as `(1,H,W)` metres (`stored * scale`).

    Zero means "no measurement" in KITTI and DSLR depth PNGs; it is returned as 0 for the caller
    to mask.

    Raises:
        FileNotFoundError: `path` does not exist.
        DataFormatError: unreadable, not single-channel, or not 16 bit.
    """
    array = read_image(path, "a 16-bit depth PNG")
    if array.ndim != 2 or array.dtype != np.uint16:
        raise DataFormatError(
            f"{str(path)!r}: expected a single-channel 16-bit depth PNG, got shape {array.shape} "
            f"and dtype {array.dtype}"
        )
    return torch.from_numpy(array.astype(np.float64) * scale).to(dtype)[None]


#: The most values of a `.npy` array that is read (`read_npy`): 400 million, 1.6 GB of float32.
MAX_NPY_VALUES = 400_000_000


def read_npy(path: Path, what: str = "an array", max_values: int = MAX_NPY_VALUES) -> np.ndarray:
    """Read a `.npy` file (no pickled objects), its header checked before any data is read:
    a shape of more than `max_values` values, or an object dtype, is refused.

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "depth.npy"
        >>> np.save(path, np.ones((2, 3), np.float32))
        >>> read_npy(path).shape
        (2, 3)
    """
    require_file(path, what)
    try:
        with open(path, "rb") as file:
            version = np.lib.format.read_magic(file)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, _, dtype = read_header(file)
            count = int(np.prod(shape, dtype=np.float64))
            if count <= max_values and not dtype.hasobject:
                return np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError, SyntaxError) as error:
        raise DataFormatError(f"{str(path)!r}: cannot be read as {what} in .npy format "
                              f"({error}); the file may be truncated") from None
    why = f"{count:.3g} values (at most {max_values:.3g} are read)" if count > max_values \
        else f"Python objects ({dtype})"
    raise DataFormatError(f"{str(path)!r}: its header states shape {shape} of {why}; "
                          f"expected {what}")


def read_pfm(path: Path) -> np.ndarray:
    """Read a PFM file (Middlebury disparities) as an upright float32 `(H,W)` or `(H,W,3)`.

    PFM stores rows bottom to top; the result is flipped so row 0 is the top of the picture.
    The scale line's sign gives the byte order (negative: little endian).

    Raises:
        FileNotFoundError: `path` does not exist.
        DataFormatError: not a PFM header, a width or height that is not > 0, a scale that is
            0 or not finite, or a raster shorter or longer than the header states.
    """
    require_file(path, "a PFM disparity map")
    data = path.read_bytes()
    expected = "expected 'Pf'/'PF', 'width height', scale lines"
    try:
        header, rest = data.split(b"\n", 1)
        dims, rest = rest.split(b"\n", 1)
        scale_line, raster = rest.split(b"\n", 1)
        channels = {b"Pf": 1, b"PF": 3}[header.strip()]
        width, height = (int(v) for v in dims.split())
        scale = float(scale_line)
    except (ValueError, KeyError) as error:
        raise DataFormatError(f"{str(path)!r}: not a PFM file ({expected})") from error
    if width <= 0 or height <= 0 or not math.isfinite(scale) or scale == 0:
        raise DataFormatError(
            f"{str(path)!r}: PFM header states width {width}, height {height} and scale "
            f"{scale:g}; width and height must be > 0 and the scale a finite non-zero number "
            "(its sign gives the byte order)")
    count = width * height * channels
    if not 4 * count <= len(raster) < 4 * count + 4:  # a trailing newline is tolerated
        why = "truncated PFM" if len(raster) < 4 * count else "PFM with more data than stated"
        raise DataFormatError(
            f"{str(path)!r}: {why}, header says {width}x{height}x{channels} floats "
            f"({4 * count} bytes) but {len(raster)} bytes follow ('Pf' is 1 channel, 'PF' 3)"
        )
    endian = "<" if scale < 0 else ">"
    array = np.frombuffer(raster[: 4 * count], dtype=f"{endian}f4").reshape(height, width, channels)
    array = np.flipud(array).astype(np.float32)
    return array[..., 0] if channels == 1 else array


def write_pfm(path: Path, array: np.ndarray) -> None:
    """Write an upright `(H,W)` float array as a little-endian PFM (inverse of `read_pfm`)."""
    array = np.asarray(array, dtype="<f4")
    height, width = array.shape[:2]
    header = f"Pf\n{width} {height}\n-1.0\n".encode()
    Path(path).write_bytes(header + np.flipud(array).tobytes())


def load_mat(path: Path, what: str) -> dict[str, np.ndarray]:
    """Read a MATLAB v5 `.mat` file with scipy (use `open_mat73` for v7.3 / HDF5)."""
    import scipy.io

    require_file(path, what)
    try:
        return scipy.io.loadmat(path)
    except NotImplementedError:  # MAT 7.3 is HDF5: read it with h5py
        with open_mat73(path, what) as file:
            return {k: np.asarray(v).T for k, v in file.items() if hasattr(v, "shape")}
    except Exception as error:
        raise DataFormatError(
            f"{str(path)!r}: cannot be read as a MATLAB .mat file holding {what} "
            f"({type(error).__name__}: {error}); the file may be truncated"
        ) from error


def open_mat73(path: Path, what: str):
    """Open a MATLAB v7.3 (HDF5) `.mat` file with h5py, with a clear error if it is broken.

    MATLAB stores arrays column-major: an `(H,W,C,N)` MATLAB array reads as `(N,C,W,H)`.
    """
    import h5py

    require_file(path, what)
    try:
        return h5py.File(path, "r")
    except OSError as error:
        raise DataFormatError(
            f"{str(path)!r}: cannot be opened as a MATLAB v7.3 / HDF5 file holding {what} "
            f"({error}); the file may be truncated or saved in another format"
        ) from error
