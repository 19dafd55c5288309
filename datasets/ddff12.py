"""DDFF-12 (Hazirbas et al., "Deep Depth From Focus", ACCV 2018): focal stacks of 12 indoor
scenes refocused from Lytro Illum light fields, with disparity from a registered depth sensor.

Release (checked against the official readers: `soyers/ddff-pytorch`
`FocalStackDDFFH5Reader.py` and `DDFFEval.py`, the calibration and `refocus.py` of
`hazirbas/ddff-toolbox`, and the DDFF-12 loaders of `fuy34/DFV` and `princeton-vl/FOSSA`)::

    ddff-dataset-trainval.h5   stack_train (N,10,383,552,3) uint8 (0-255, sRGB)
                               disp_train  (N,383,552) float32, pixels; 0 = no measurement
                               stack_val, disp_val: the same for the validation scenes
    ddff-dataset-test.h5       stack_test (no disparity: the benchmark server scores it)

DFV's re-split `my_ddff_trainVal.h5` uses the same keys (its stacks are float32 in 0-255 and it
adds `AiF_train`/`AiF_val`, the centre sub-aperture view, which is read as the all-in-focus
image). `root` is the folder holding the file, or the `.h5` file itself.

Disparity is the shift in pixels between neighbouring sub-aperture views, so depth is
`Z = f_sub * B / d` with the sub-aperture focal length `f_sub = 521.4052` px and the baseline
`B = K2 / f_lens * 1e-3` m from the toolbox's `IntParamLF.mat` (`K2 = 1982.02508`,
`f_lens = 7317.02064`): `f_sub * B = 0.141237` m px. The official evaluation ignores
disparities outside [0.0202, 0.2825] px (0.5 m to 7 m) and scores disparity, not depth
(`models.protocols.PROTOCOLS["ddff12"]`).

Slice `i` of a stack is the light field refocused (shift-and-add over the whole view grid) at
disparity `d_i = linspace(f_sub B / 0.5, f_sub B / 7, 10)[i]`: slice 0 is focused at 0.5 m, the
nearest, slice 9 at 7 m; the focus distance is `f_sub * B / d_i`. Its thin-lens equivalent
(as `datasets.LightFieldCalibration` derives it): a point at disparity `d` is spread over
`(views - 1) * |d - d_i|` pixels, the CoC of a lens of focal length `f_sub * pitch` and aperture
`(views - 1) * B`. The pitch is the Lytro Illum's micro-lens pitch (7728 sensor pixels of
1.4 um over 552 sub-aperture pixels: 19.6 um; only `f / pitch` matters for the blur in
pixels), and `views = 9` (a 9x9 grid of views; the view count was not checked against the raw
light fields). The aperture is a square of views; the settings call it a disk.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from kornia.color import rgb_to_linear_rgb

from optics import CameraSettings

from .focus import CameraPreset
from .io import DataFormatError, require_args, require_file
from .stacks import FocalStackDataset

#: Sub-aperture focal length in pixels (toolbox `refocus.py`, `IntParamLF_SubAperture.mat`).
SUBAPERTURE_FOCAL_PX = 521.4052
#: Baseline between neighbouring views in metres: `K2 / f_lens * 1e-3` from `IntParamLF.mat`.
BASELINE_M = 1982.02508 / 7317.02064 * 1e-3
#: `f_sub * B` in metres times pixels: depth = this / disparity.
DISPARITY_TIMES_DEPTH = SUBAPERTURE_FOCAL_PX * BASELINE_M
#: Depth range of the refocused slices (toolbox `refocus.py`), metres.
FOCUS_RANGE_M = (0.5, 7.0)
#: Valid disparity range of the official evaluation (`DDFFEval.py`, `ClipGroundTruth`), pixels.
VALID_DISPARITY = (0.0202, 0.2825)
#: Effective pixel pitch of the sub-aperture images, metres (Lytro Illum micro-lens pitch).
PIXEL_PITCH = 7728 * 1.4e-6 / 552

FILES = {"train": "ddff-dataset-trainval.h5", "val": "ddff-dataset-trainval.h5",
         "test": "ddff-dataset-test.h5"}
LAYOUT = (
    "  <root>/ddff-dataset-trainval.h5  stack_train (N,10,383,552,3) uint8, disp_train (N,383,552) "
    "float32, stack_val, disp_val\n"
    "  <root>/ddff-dataset-test.h5      stack_test"
)


def ddff_disparity_to_depth(disparity: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth in metres and valid mask from DDFF-12 disparity in pixels: `Z = f_sub B / d`.

    Pixels count only inside the official evaluation's disparity range
    `VALID_DISPARITY` (0 marks no measurement); others get depth 7 m and mask False.

    Example:
        >>> depth, mask = ddff_disparity_to_depth(torch.tensor([0.1, 0.0, 0.5]))
        >>> depth, mask
        (tensor([1.4124, 7.0000, 7.0000]), tensor([ True, False, False]))
    """
    low, high = VALID_DISPARITY
    mask = torch.isfinite(disparity) & (disparity >= low) & (disparity <= high)
    safe = torch.where(mask, disparity, torch.ones_like(disparity))
    depth = torch.where(mask, DISPARITY_TIMES_DEPTH / safe,
                        torch.full_like(disparity, FOCUS_RANGE_M[1]))
    return depth, mask


def ddff_camera(views: int = 9, slices: int = 10, shots: list[int] | None = None,
                dtype: torch.dtype = torch.float32) -> CameraSettings:
    """The thin-lens settings of DDFF-12's refocused slices (see the module docstring).

    Args:
        views: views per side of the grid the slices average (the aperture in baselines is
            `views - 1`).
        slices: slices per stack (10 in the release).
        shots: indices of the slices kept (all by default).
        dtype: floating dtype.

    Example:
        >>> camera = ddff_camera()
        >>> round(float(camera.focus_distance[0]), 3), round(float(camera.focus_distance[-1]), 3)
        (0.5, 7.0)
        >>> round(float(camera.f_number[0]), 2)
        4.72
    """
    if views < 2:
        raise ValueError(f"views must be >= 2 views per side for a finite f-number, got {views}")
    near, far = FOCUS_RANGE_M
    disparities = np.linspace(DISPARITY_TIMES_DEPTH / near, DISPARITY_TIMES_DEPTH / far, slices)
    focus = (DISPARITY_TIMES_DEPTH / disparities).tolist()
    if shots is not None:
        focus = [focus[i] for i in shots]
    focal_length = SUBAPERTURE_FOCAL_PX * PIXEL_PITCH
    f_number = focal_length / ((views - 1) * BASELINE_M)
    return CameraSettings(focal_length, f_number, focus, PIXEL_PITCH, aperture="disk").to(dtype)


class DDFF12(FocalStackDataset):
    """DDFF-12 focal stacks from the release HDF5 files, depth from disparity in metres.

    Args:
        root: folder with the `.h5` files (or one `.h5` file).
        split: `"train"`, `"val"` or `"test"` (keys `stack_<split>`, `disp_<split>`).
        shots: indices of the slices to keep, in focus order (all 10 by default; DFV and FOSSA
            evaluate 5 with `[0, 2, 4, 6, 9]`).
        views: views per side of the refocused grid (sets the f-number, see above).
        **kwargs: `size`, `crop`, `augment`, `dtype`, `memory_cache_mb` of `DepthDataset`.

    Raises:
        FileNotFoundError: `root` or the `.h5` file is missing.
        DataFormatError: the file is not HDF5 or truncated, or a key is missing or holds the
            wrong shape, dtype or range (e.g. depth stored where disparity belongs).
    """

    name = "ddff12"

    #: Depth range of the scenes, metres (the slices' focus range): the methods' prior.
    depth_range = FOCUS_RANGE_M

    def __init__(self, root: str | Path, split: str = "val", shots: list[int] | None = None,
                 views: int = 9, **kwargs: Any):
        require_args(("split", split, split in FILES, f"one of {sorted(FILES)}"))
        self.camera = ddff_camera(views, shots=None)
        preset = CameraPreset(float(self.camera.focal_length[0]), PIXEL_PITCH,
                              tuple(self.camera.focus_distance.tolist()),
                              (float(self.camera.f_number[0]),), depth_cap=FOCUS_RANGE_M[1])
        super().__init__(preset, **kwargs)
        path = Path(root).expanduser()
        self.path = require_file(path / FILES[split] if path.is_dir() else path,
                                 f"the DDFF-12 HDF5 file with stack_{split}")
        self.split, self.views = split, int(views)
        self.stack_key, self.disp_key = f"stack_{split}", f"disp_{split}"
        with self._open() as file:  # shapes and dtypes read while the file is open
            stacks, disp = file.get(self.stack_key), file.get(self.disp_key)
            self.has_depth = disp is not None
            self.aif_key = f"AiF_{split}" if f"AiF_{split}" in file else None
            keys = sorted(file)
            count, slices, h, w = (0, 0, 0, 0) if stacks is None else stacks.shape[:4]
            expected = f"(N, slices, H, W, 3) and {self.disp_key} float ({count}, {h}, {w})"
            why = (None if stacks is not None and stacks.ndim == 5 and stacks.shape[-1] == 3 and (
                disp is None and split == "test" or disp is not None and
                np.issubdtype(disp.dtype, np.floating) and
                tuple(disp.shape) in ((count, h, w), (count, 1, h, w))) else
                f"missing key {self.stack_key!r}" if stacks is None else
                f"missing key {self.disp_key!r} (the disparity of {self.stack_key})"
                if disp is None and split != "test" else f"{self.stack_key} must have shape "
                f"{expected}, got {stacks.shape} and "
                f"{None if disp is None else (disp.shape, disp.dtype)}")
        if why:
            raise DataFormatError(f"{str(self.path)!r}: {why}; keys: {keys}. Expected:\n{LAYOUT}")
        self.shots = list(range(slices)) if shots is None else [int(i) for i in shots]
        require_args(("shots", shots, self.shots and all(0 <= i < slices for i in self.shots) and
                      sorted(set(self.shots)) == self.shots,
                      f"increasing slice indices in 0..{slices - 1}"))
        self.camera = ddff_camera(views, slices, self.shots)
        self.ids = [f"{split}_{i:04d}" for i in range(count)]

    def _open(self):
        import h5py

        try:
            return h5py.File(self.path, "r")
        except OSError as error:
            raise DataFormatError(f"{str(self.path)!r}: cannot be opened as an HDF5 file ({error});"
                                  " the download may be truncated") from None

    def _read(self, file, key: str, index: int) -> np.ndarray:
        try:
            return np.asarray(file[key][index])
        except OSError as error:
            raise DataFormatError(f"{str(self.path)!r}: cannot read {key}[{index}] ({error}); the "
                                  "file may be truncated") from None

    def _to_unit(self, key: str, array: np.ndarray) -> torch.Tensor:
        if array.dtype == np.uint8:
            values = array.astype(np.float32) / 255.0
        elif np.issubdtype(array.dtype, np.floating) and np.isfinite(array).all() and \
                array.min() >= 0 and array.max() <= 255:
            values = array.astype(np.float32) / 255.0  # DFV stores 0-255 as float32
        else:
            raise DataFormatError(f"{str(self.path)!r}: {key} must hold uint8 (or float 0-255) "
                                  f"colours, got dtype {array.dtype} with values in "
                                  f"[{float(np.nanmin(array)):.4g}, {float(np.nanmax(array)):.4g}]")
        image = torch.from_numpy(np.ascontiguousarray(np.moveaxis(values, -1, -3)))
        return rgb_to_linear_rgb(image.to(self.dtype))

    def load_stack(self, index: int) -> dict[str, Any]:
        with self._open() as file:
            stack = self._read(file, self.stack_key, index)[self.shots]
            disparity = self._read(file, self.disp_key, index) if self.has_depth else None
            aif = self._read(file, self.aif_key, index) if self.aif_key else None
        focused = self._to_unit(self.stack_key, stack)
        h, w = focused.shape[-2:]
        if disparity is None:
            depth = torch.full((1, h, w), FOCUS_RANGE_M[1], dtype=self.dtype)
            mask = torch.zeros(1, h, w, dtype=torch.bool)
        else:
            disparity = disparity.reshape(h, w)
            valid = disparity[np.isfinite(disparity) & (disparity > 0)]
            if valid.size and float((valid > 2 * VALID_DISPARITY[1]).mean()) > 0.5:
                raise DataFormatError(
                    f"{str(self.path)!r}: {self.disp_key}[{index}] has median "
                    f"{float(np.median(valid)):.4g}, but DDFF-12 disparity lies in "
                    f"{VALID_DISPARITY[0]}-{VALID_DISPARITY[1]} px: is this depth (metres or mm) "
                    "stored where disparity belongs?")
            depth, mask = ddff_disparity_to_depth(torch.from_numpy(disparity.astype(np.float64)))
            depth, mask = depth.to(self.dtype)[None], mask[None]
        return {"image": None if aif is None else self._to_unit(self.aif_key, aif),
                "focused": focused, "camera": self.camera.to(self.dtype), "depth": depth,
                "mask": mask}
