"""NYU Depth v2 (labeled subset): `nyu_depth_v2_labeled.mat` and the paper's 795/654 split.

Folder layout (`root`)::

    nyu_depth_v2_labeled.mat   MATLAB v7.3 (HDF5): images 480x640x3x1449 uint8, depths 480x640x1449
    splits.mat                 MATLAB v5: trainNdxs (795x1), testNdxs (654x1), 1-based indices

Both are on the NYU Depth v2 page (Silberman et al. 2012). MATLAB stores arrays column-major, so
h5py reads `images` as `(N, 3, W, H)` and `depths` as `(N, W, H)`; the loader transposes
them back so images come out upright. Focused images are synthesised from the ground-truth depth
with `datasets.presets.NYU` (35 mm, f/2.8, focus 2 m and 8 m, pitch 22.4 um at 640x480).
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .base import DepthDataset
from .depth import fill_unknown, require_valid_depth, valid_depth_mask
from .focus import CameraPreset
from .io import (
    DataFormatError,
    load_mat,
    open_mat73,
    require_args,
    require_file,
    require_root,
    to_unit_range,
)
from .presets import NYU

LAYOUT = (
    "  <root>/nyu_depth_v2_labeled.mat  (MATLAB v7.3 / HDF5 with 'images' and 'depths')\n"
    "  <root>/splits.mat                (MATLAB v5 with 'trainNdxs' and 'testNdxs', 1-based)"
)

#: Eigen et al.'s evaluation crop of 480x640 NYU frames, `(top, left, height, width)` pixels.
NYU_EIGEN_CROP = (45, 41, 426, 560)

SPLITS = ("train", "test", "all")

#: Largest plausible NYU depth in metres (the Kinect reaches about 10 m); float depths beyond it
#: are refused as probably millimetres.
MAX_DEPTH_M = 100.0


def split_indices(path: Path, split: str, count: int) -> np.ndarray:
    """The 0-based frame indices of `split` (`"train"` or `"test"`) in `splits.mat`.

    Raises:
        DataFormatError: the array is missing or empty, or holds values that are not whole
            numbers in 1..`count`, or one frame twice.
    """
    splits = load_mat(path, "'trainNdxs' and 'testNdxs'")
    key = "trainNdxs" if split == "train" else "testNdxs"
    values = np.asarray(splits.get(key, np.zeros(0))).reshape(-1)
    whole = np.zeros(values.shape, bool)
    if np.issubdtype(values.dtype, np.number) and not np.iscomplexobj(values):
        whole = np.isfinite(values) & (values == np.round(values)) & (values >= 1) & (values <= count)
    unique, counts = np.unique(values[whole].astype(np.int64), return_counts=True)
    why = (f"no {key!r} array" if key not in splits else f"{key} is empty" if not values.size else
           f"{key} must hold whole 1-based indices, got {values[~whole][:5].tolist()} (frames are "
           f"1..{count})" if not whole.all() else
           f"{key} lists frame(s) {unique[counts > 1][:5].tolist()} more than once"
           if (counts > 1).any() else None)
    if why:
        raise DataFormatError(f"{str(path)!r}: {why}; expected the 1-based indices of the {split} "
                              "frames, each once")
    indices = values.astype(np.int64) - 1
    return indices


class NYUv2(DepthDataset):
    """NYU Depth v2 labeled frames with synthesised focused images.

    Args:
        root: folder holding `nyu_depth_v2_labeled.mat` and `splits.mat`.
        split: `"train"` (795 frames), `"test"` (654) or `"all"` (1449, no splits.mat
            needed).
        preset: camera for focus synthesis (`datasets.presets.NYU` by default).
        **kwargs: `size`, `crop`, `augment`, `cache_dir`, `aperture`,
            `render_kwargs`, `dtype` of `DepthDataset`.

    Dtypes: `images` of uint8 (the official file) or uint16 are scaled by their maximum; float
    images must lie in [0, 1] and are used as they are. `depths` in floating point are metres
    (the official file); integer depths are read as millimetres, with a `UserWarning`. A frame
    without any valid depth pixel is refused when loaded (its focused images would be rendered
    from invented depth).

    Raises:
        FileNotFoundError: `root` or a file is missing.
        DataFormatError: a file is truncated, holds arrays of the wrong shape or dtype, float
            images outside [0, 1], float depths beyond 100 m (millimetres?), or a frame without
            valid depth.

    Example:
        >>> NYUv2("/no/such/folder")  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        FileNotFoundError: NYUv2: root folder '/no/such/folder' does not exist ...
    """

    name = "nyu"
    native_width = 640

    def __init__(
        self, root: str | Path, split: str = "train", preset: CameraPreset = NYU, **kwargs: Any
    ):
        super().__init__(preset, **kwargs)
        require_args(("split", split, split in SPLITS, f"one of {SPLITS}"))
        self.root = require_root(root, "NYUv2", LAYOUT)
        self.split = split
        self.mat_path = require_file(
            self.root / "nyu_depth_v2_labeled.mat", "the NYU Depth v2 labeled set (MAT v7.3)"
        )
        with open_mat73(self.mat_path, "'images' and 'depths'") as file:
            missing = [key for key in ("images", "depths") if key not in file]
            if not missing:
                images, depths = file["images"].shape, file["depths"].shape
                image_dtype, depth_dtype = file["images"].dtype, file["depths"].dtype
                stored = all(np.issubdtype(t, np.unsignedinteger) or np.issubdtype(t, np.floating)
                             for t in (image_dtype, depth_dtype))
            keys = sorted(file.keys())
        if missing or not stored or len(images) != 4 or images[1] != 3 or depths != (
            images[0], images[2], images[3]
        ):
            found = f"keys {keys}" if missing else f"{images} {image_dtype} and {depths} {depth_dtype}"
            raise DataFormatError(
                f"{str(self.mat_path)!r}: expected arrays 'images' (N,3,W,H) and 'depths' (N,W,H) "
                "of unsigned integers or floats, as h5py reads MATLAB's HxWx3xN and HxWxN arrays, "
                f"got {found}"
            )
        #: Metres per stored depth unit: 1 for float metres, 1e-3 for integer millimetres.
        self.depth_scale = 1.0
        if np.issubdtype(depth_dtype, np.integer):
            self.depth_scale = 1e-3
            warnings.warn(
                f"{str(self.mat_path)!r}: depths are stored as {depth_dtype} (the official file "
                "holds float metres); reading them as millimetres",
                UserWarning, stacklevel=2,
            )
        count = images[0]
        if split == "all":
            indices = np.arange(count)
        else:
            indices = split_indices(self.root / "splits.mat", split, count)
        self.indices = [int(i) for i in indices]
        self.ids = [f"{i + 1:04d}" for i in self.indices]
        self._file = None
        self._pid = -1

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_file"] = None  # reopened in the worker
        return state

    def _handle(self):
        # One HDF5 handle per process: handles do not survive a DataLoader fork.
        if self._file is None or self._pid != os.getpid():
            self._file = open_mat73(self.mat_path, "'images' and 'depths'")
            self._pid = os.getpid()
        return self._file

    def load(self, index: int) -> dict[str, Any]:
        file, i = self._handle(), self.indices[index]
        try:
            image = np.asarray(file["images"][i]).transpose(0, 2, 1)  # (3,W,H) -> (3,H,W)
            depth = np.asarray(file["depths"][i]).T  # (W,H) -> (H,W)
        except OSError as error:
            raise DataFormatError(
                f"{str(self.mat_path)!r}: cannot read frame {i + 1} ({error}); truncated file?"
            ) from error
        from kornia.color import rgb_to_linear_rgb

        source = f"{str(self.mat_path)!r} frame {i + 1}"
        image = to_unit_range(self.mat_path, f"frame {i + 1} of images", image)
        image = rgb_to_linear_rgb(torch.from_numpy(np.ascontiguousarray(image)).to(self.dtype))
        depth = np.ascontiguousarray(depth, dtype=np.float64) * self.depth_scale
        finite = depth[np.isfinite(depth)]
        if finite.size and float(finite.max()) > MAX_DEPTH_M:
            raise DataFormatError(
                f"{source}: depths reach {float(finite.max()):.6g}, more than {MAX_DEPTH_M:g} m; "
                "NYU depths are metres (up to about 10 m): is the file in millimetres?"
            )
        depth = torch.from_numpy(depth).to(self.dtype)[None]
        mask = valid_depth_mask(depth)
        require_valid_depth(mask, source)
        return {"image": image, "depth": fill_unknown(depth, mask), "mask": mask}
