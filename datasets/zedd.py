"""ZEDD (Zuo, Wen, Subramanian et al., "Zero-Shot Depth from Defocus", 2026): 100 real scenes
photographed with a full-frame mirrorless camera at 9 calibrated focus distances (0.82-8.10 m)
and 5 apertures (f/1.4, 2.0, 2.8, 4.0, 5.6), plus an f/16 all-in-focus shot, with dense LiDAR
depth at 1824x1216 pixels.

Release layout (checked against `princeton-vl/FOSSA` at dd7758d: its loader `dataset/zedd.py`,
its README's file tree, `config/validation_configs.py` and the test-format check
`zedd_test/zedd_check_format.py`, which also give the protocol; the dataset card states the 9
focus distances, 6 apertures and the 1824x1216 depth; the files themselves were not at hand)::

    <root>/metadata.txt    one line per focus setting: run_<k> <TAB> <motor hex code> <TAB>
                           <focus distance, metres>, k = 1..9 ('#' starts a comment)
    <root>/<split>/<scene>/focus_stack/img_run_<k>_motor_<hex>_aperture_F<N.N>.jpg
                           the photos, e.g. img_run_1_motor_6D3E_aperture_F2.8.jpg
    <root>/<split>/<scene>/gt/depth.npy   depth in metres (val only; the test split is scored
                                          by the benchmark server)
    <root>/<split>/<scene>/gt/K.txt       3x3 intrinsics in pixels at the depth's resolution

`split` is `"val"` or `"test"`, scenes `val_0001`, .... The default protocol (FOSSA's
`zedd_F2_8_fixed_fd_0_2_4_6_8`) uses five shots at f/2.8 focused at settings 0, 2, 4, 6, 8
(runs 1, 3, 5, 7, 9) and the f/16 photo of run 5 as the all-in-focus image; valid depth lies in
[0.01, 1000] m. Photos are resized to the depth's resolution where they differ (val). `K.txt`
is in pixels at the depth's resolution, 1824x1216 (`DEPTH_SIZE`; the test split has no depth,
so its K is read at that size, as FOSSA does, whatever the photos' size). The pixel pitch is the
full-frame sensor width (36 mm, assumed: no source states the camera's sensor) over the image
width, and the focal length is `K[0][0]` times the pitch at K's resolution (only `f / pitch`
matters for the blur in pixels). FOSSA scores val at 480x640 (resized to 480 rows, then the
centre 640 columns); `crop=(0, 101, 1216, 1622), size=(480, 640)` (the crop at native
resolution, then the resize) takes the same part of the photo to within a native pixel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from optics import CameraSettings

from .depth import fill_unknown, require_valid_depth, valid_depth_mask
from .focus import CameraPreset
from .io import (
    DataFormatError,
    read_npy,
    read_numbers,
    read_text,
    require_args,
    require_file,
    require_root,
)
from .photos import read_photo
from .stacks import FocalStackDataset

APERTURES = (1.4, 2.0, 2.8, 4.0, 5.6, 16.0)
#: The default protocol: focus settings (0-based) and f-number of the shots.
DEFAULT_SHOTS = (0, 2, 4, 6, 8)
DEFAULT_F_NUMBER = 2.8
#: The all-in-focus photo: f/16 at run 5 (FOSSA's loader).
AIF_RUN, AIF_F_NUMBER = 5, 16.0
#: Valid ground truth of the official evaluation, metres.
VALID_DEPTH = (0.01, 1000.0)
SENSOR_WIDTH = 36e-3
#: Rows and columns of the depth maps, the frame of `K.txt` (dataset card; FOSSA's test check).
DEPTH_SIZE = (1216, 1824)
LAYOUT = (
    "  <root>/metadata.txt  lines run_<k> TAB <hex> TAB <focus distance m>, k = 1..9\n"
    "  <root>/<split>/<scene>/focus_stack/img_run_<k>_motor_<hex>_aperture_F<N.N>.jpg\n"
    "  <root>/<split>/<scene>/gt/depth.npy (metres; val) and gt/K.txt (3x3, pixels)"
)


def read_shot_list(path: Path) -> dict[int, tuple[str, float]]:
    """ZEDD's `metadata.txt`: run number -> (motor hex code, focus distance in metres).

    Raises:
        FileNotFoundError: the file is missing.
        DataFormatError: a line is not `run_<k> TAB <hex> TAB <metres>`, or a distance is not
            finite and positive.
    """
    require_file(path, "ZEDD's metadata.txt (run_<k> TAB <hex> TAB <focus distance in metres>)")
    runs: dict[int, tuple[str, float]] = {}
    for number, line in enumerate(read_text(path, "an intrinsics file").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split("\t") if "\t" in line else line.split()
        try:
            run, code, distance = parts
            k, metres = int(run.removeprefix("run_")), float(distance)
        except ValueError:
            metres = math.nan
        if not (math.isfinite(metres) and metres > 0):
            raise DataFormatError(f"{str(path)!r} line {number}: expected run_<k> TAB <hex> TAB "
                                  f"<focus distance, finite and > 0 metres>, got {line!r}")
        runs[k] = (code, metres)
    return runs


def read_intrinsics(path: Path) -> np.ndarray:
    """A 3x3 intrinsics matrix in pixels from a whitespace-separated text file."""
    matrix = np.array(read_numbers(path, "a 3x3 intrinsics matrix K.txt in pixels", 3))
    if matrix.shape != (3, 3) or not np.isfinite(matrix).all() or matrix[0, 0] <= 0:
        raise DataFormatError(f"{str(path)!r}: expected a 3x3 intrinsics matrix with fx > 0 "
                              f"pixels, got shape {matrix.shape}")
    return matrix


class ZEDD(FocalStackDataset):
    """ZEDD scenes: real photos at calibrated focus distances, all-in-focus f/16 photo, LiDAR
    depth in metres.

    Args:
        root: the dataset folder (holds `metadata.txt` and the split folders).
        split: `"val"` (with depth) or `"test"` (without).
        shots: focus settings (0-based, 0..8) of the focused shots.
        f_number: aperture of the focused shots, one of `APERTURES`.
        sensor_width: sensor width in metres (full frame: 36 mm) for the pixel pitch.
        **kwargs: `size`, `crop`, `augment`, `dtype`, `memory_cache_mb` of `DepthDataset`.

    Raises:
        FileNotFoundError: `root`, `metadata.txt`, the split folder or a scene's file is
            missing.
        DataFormatError: a malformed `metadata.txt` or `K.txt`, a focus setting missing from
            `metadata.txt`, an unreadable photo, or depth that is not metres.
    """

    name = "zedd"

    #: Depth range of the scenes, metres (indoor and garden scenes around the 0.82-8.1 m focus
    #: settings): the methods' prior.
    depth_range = (0.5, 20.0)

    def __init__(self, root: str | Path, split: str = "val",
                 shots: Sequence[int] = DEFAULT_SHOTS, f_number: float = DEFAULT_F_NUMBER,
                 sensor_width: float = SENSOR_WIDTH, **kwargs: Any):
        require_args(("split", split, split in ("val", "test"), "'val' or 'test'"),
                     ("f_number", f_number, float(f_number) in APERTURES, f"one of {APERTURES}"),
                     ("sensor_width", sensor_width, 0 < sensor_width < 0.1, "metres in (0, 0.1)"))
        self.root = require_root(root, "ZEDD", LAYOUT)
        self.metadata_path = self.root / "metadata.txt"
        runs = read_shot_list(self.metadata_path)
        self.shots = [int(i) for i in shots]
        for k in sorted({i + 1 for i in self.shots} | {AIF_RUN}):
            if k not in runs:
                raise DataFormatError(f"{str(self.metadata_path)!r}: no focus distance for run_{k}"
                                      f" (focus setting {k - 1}); runs listed: {sorted(runs)}")
        self.runs, self.f_number, self.sensor_width = runs, float(f_number), float(sensor_width)
        focus = [runs[i + 1][1] for i in self.shots]
        super().__init__(CameraPreset(0.05, sensor_width / 1824, tuple(focus), (self.f_number,),
                                      depth_cap=VALID_DEPTH[1]), **kwargs)
        folder = self.root / split
        self.scenes = sorted(p for p in folder.iterdir() if p.is_dir()) if folder.is_dir() else []
        if not self.scenes:
            raise FileNotFoundError(f"ZEDD: no scene folders in {str(folder)!r}. Expected:\n{LAYOUT}")
        self.split = split
        for scene in self.scenes:
            for path in self._photos(scene):
                require_file(path, f"a ZEDD photo of scene {scene.name}")
            require_file(scene / "gt" / "K.txt", "the scene's 3x3 intrinsics K.txt")
            if split == "val":
                require_file(scene / "gt" / "depth.npy", "the scene's depth in metres (float .npy)")
        self.ids = [p.name for p in self.scenes]

    def _photo(self, scene: Path, run: int, f_number: float) -> Path:
        code = self.runs[run][0]
        return scene / "focus_stack" / f"img_run_{run}_motor_{code}_aperture_F{f_number:.1f}.jpg"

    def _photos(self, scene: Path) -> list[Path]:
        return [self._photo(scene, i + 1, self.f_number) for i in self.shots] + \
            [self._photo(scene, AIF_RUN, AIF_F_NUMBER)]

    def load_stack(self, index: int) -> dict[str, Any]:
        scene = self.scenes[index]
        K = read_intrinsics(scene / "gt" / "K.txt")
        depth_path = scene / "gt" / "depth.npy"
        photos = [read_photo(p, dtype=self.dtype)[0] for p in self._photos(scene)]
        if self.split == "val":
            array = read_npy(depth_path, "a .npy depth map")
            if array.ndim != 2 or not np.issubdtype(array.dtype, np.floating):
                raise DataFormatError(f"{str(depth_path)!r}: expected an (H, W) float depth map "
                                      f"in metres, got shape {array.shape}, dtype {array.dtype}")
            depth = torch.from_numpy(array.astype(np.float64)).to(self.dtype)[None]
            require_valid_depth(valid_depth_mask(depth), repr(str(depth_path)), depth, (0.0, 200.0))
            mask = torch.isfinite(depth) & (depth >= VALID_DEPTH[0]) & (depth <= VALID_DEPTH[1])
            if not bool(mask.any()):
                raise DataFormatError(f"{str(depth_path)!r}: no depth in {VALID_DEPTH} metres")
            depth = fill_unknown(depth.nan_to_num(0.0, posinf=0.0, neginf=0.0).clamp_min(0), mask)
        else:
            h, w = photos[0].shape[-2:]
            depth = torch.full((1, h, w), 10.0, dtype=self.dtype)
            mask = torch.zeros(1, h, w, dtype=torch.bool)
        size = depth.shape[-2:]
        photos = [self._resized(p, size, path) for p, path in
                  zip(photos, self._photos(scene), strict=True)]
        pitch = self.sensor_width / size[-1]
        k_width = size[-1] if self.split == "val" else DEPTH_SIZE[1]
        focus = [self.runs[i + 1][1] for i in self.shots]
        camera = CameraSettings(float(K[0, 0]) * self.sensor_width / k_width, self.f_number,
                                focus, pitch, aperture="disk").to(self.dtype)
        return {"image": photos[-1], "focused": torch.stack(photos[:-1]), "camera": camera,
                "depth": depth, "mask": mask}

    @staticmethod
    def _resized(photo: torch.Tensor, size: Sequence[int], path: Path) -> torch.Tensor:
        h, w = photo.shape[-2:]
        if (h, w) == tuple(size):
            return photo
        if abs(h / w - size[0] / size[1]) > 0.01:
            raise DataFormatError(f"{str(path)!r} is {h}x{w} pixels, not the depth's aspect "
                                  f"{size[0]}x{size[1]}")
        return F.interpolate(photo[None], size=tuple(size), mode="bilinear", antialias=True,
                             align_corners=False)[0].clamp(0, 1)
