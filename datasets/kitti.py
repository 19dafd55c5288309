"""KITTI: raw camera frames with projected LiDAR depth (uint16 PNG / 256), Eigen split files.

Folder layout (`root`)::

    2011_09_26/2011_09_26_drive_0002_sync/image_02/data/0000000069.png          raw frame (left)
    2011_09_26/2011_09_26_drive_0002_sync/proj_depth/groundtruth/image_02/0000000069.png  depth
    eigen_train_files.txt, eigen_test_files.txt                                 split files

Frames come from the KITTI raw data, depth PNGs from the KITTI depth benchmark
("annotated depth maps"; also accepted under `<depth_root>/<drive>/`, `.../train/<drive>/` or
`.../val/<drive>/` as unzipped). Depth is `uint16 / 256` metres, 0 where LiDAR has no return.
Split files hold one frame per line, either as monodepth2 writes them
(`2011_09_26/2011_09_26_drive_0002_sync 69 l`) or as an image path relative to `root`
(`2011_09_26/.../image_02/data/0000000069.png`; further tokens are ignored).

Sparse depth: LiDAR covers about 5% of the pixels. Focus synthesis needs a depth everywhere, so by
default (`densify="nearest"`) every pixel takes the depth of the nearest LiDAR point (above the
top LiDAR row this extends the top points upward); `mask` still marks only the real LiDAR points,
so evaluation uses measured depth only. `densify="none"` fills the gaps with the depth cap.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .base import DepthDataset
from .depth import densify_nearest, fill_unknown, require_valid_depth, valid_depth_mask
from .focus import CameraPreset
from .io import (
    DataFormatError,
    read_depth_png,
    read_text,
    require_args,
    require_file,
    require_one_size,
    require_root,
)
from .photos import read_photo
from .presets import KITTI

LAYOUT = (
    "  <root>/<date>/<drive>/image_02/data/<frame>.png                 (raw frames)\n"
    "  <depth_root>/[<date>/]<drive>/proj_depth/groundtruth/image_02/<frame>.png  (uint16/256)\n"
    "  <root>/eigen_<split>_files.txt                                  (split file)"
)

#: Garg et al.'s evaluation crop as fractions of the height and width (top, bottom, left, right).
KITTI_GARG_CROP_FRACTIONS = (0.40810811, 0.99189189, 0.03594771, 0.96405229)


def garg_crop(height: int, width: int) -> tuple[int, int, int, int]:
    """Garg et al.'s KITTI evaluation crop as `(top, left, height, width)` pixels.

    Example:
        >>> garg_crop(375, 1242)
        (153, 44, 218, 1153)
    """
    top, bottom, left, right = KITTI_GARG_CROP_FRACTIONS
    t, b, l, r = int(top * height), int(bottom * height), int(left * width), int(right * width)
    return t, l, b - t, r - l


def parse_split_line(line: str, path: Path, number: int) -> tuple[str, str, str]:
    """`(drive folder, camera folder, frame name)` from one line of a split file."""
    tokens = line.split()
    if len(tokens) >= 3 and tokens[2] in ("l", "r") and tokens[1].isdigit():
        return tokens[0], "image_02" if tokens[2] == "l" else "image_03", f"{int(tokens[1]):010d}"
    parts = Path(tokens[0]).parts
    if len(parts) >= 4 and parts[-2] == "data" and parts[-3].startswith("image_"):
        return str(Path(*parts[:-3])), parts[-3], Path(parts[-1]).stem
    raise DataFormatError(
        f"{str(path)!r} line {number}: expected '<date>/<drive> <frame> l|r' or "
        f"'<date>/<drive>/image_0X/data/<frame>.png', got {line.strip()!r}"
    )


#: The range of plausible median LiDAR depths of a frame in metres: a median outside it means the
#: PNG does not hold `metres * 256` (metres stored as is give medians under 1/4 m, 8-bit or
#: disparity maps others), so every depth would be wrong by a constant factor.
MEDIAN_DEPTH_RANGE_M = (1.0, 120.0)


class KITTI(DepthDataset):
    """KITTI raw frames with LiDAR depth and synthesised focused images (Eigen split).

    Args:
        root: folder of the raw data and the split files.
        split: name of the split file `<root>/eigen_<split>_files.txt` (`"train"`,
            `"test"`, ...), or a path to a split file.
        depth_root: folder of the depth PNGs, `root` by default.
        densify: `"nearest"` (default) or `"none"`, how depth gaps are filled for synthesis.
        preset: camera for focus synthesis (`datasets.presets.KITTI` by default).
        **kwargs: `size`, `crop`, `augment`, `cache_dir`, `aperture`,
            `render_kwargs`, `dtype` of `DepthDataset`.

    Raises:
        FileNotFoundError: `root`, the split file, a frame or its depth PNG is missing.
        DataFormatError: a malformed split line, an unreadable PNG, or frame and depth sizes differ.
    """

    name = "kitti"
    native_width = 1242

    def __init__(
        self,
        root: str | Path,
        split: str | Path = "train",
        depth_root: str | Path | None = None,
        densify: str = "nearest",
        preset: CameraPreset = KITTI,
        **kwargs: Any,
    ):
        super().__init__(preset, **kwargs)
        require_args(("densify", densify, densify in ("nearest", "none"), "'nearest' or 'none'"))
        self.root = require_root(root, "KITTI", LAYOUT)
        self.depth_root = self.root if depth_root is None else require_root(
            depth_root, "KITTI depth", LAYOUT
        )
        self.densify = densify
        split_path = Path(split) if Path(split).suffix == ".txt" else (
            self.root / f"eigen_{split}_files.txt"
        )
        require_file(split_path, "a KITTI split file, one frame per line")
        self.frames: list[tuple[Path, Path]] = []
        first: dict[tuple[str, str, str], int] = {}
        twice: Any = None
        for number, line in enumerate(read_text(split_path, "a split file").splitlines(), start=1):
            if not line.strip():
                continue
            drive, camera, frame = parse_split_line(line, split_path, number)
            key = (str(Path(drive)), camera, frame)
            twice = twice or (key in first and (first[key], number, "/".join(key)))
            first.setdefault(key, number)
            self.frames.append((self._image_path(drive, camera, frame),
                                self._depth_path(drive, camera, frame)))
            self.ids.append(f"{drive}/{camera}/{frame}")
        if twice or not self.frames:
            raise DataFormatError(f"{str(split_path)!r}" + (
                " lines {} and {} both name frame {}; a split must list each frame once".format(
                    *twice) if twice else ": the split file lists no frames"))

    def _image_path(self, drive: str, camera: str, frame: str) -> Path:
        folder = self.root / drive / camera / "data"
        for ext in (".png", ".jpg"):
            if (folder / f"{frame}{ext}").is_file():
                return folder / f"{frame}{ext}"
        return require_file(folder / f"{frame}.png", "a KITTI raw frame (PNG or JPEG)")

    def _depth_path(self, drive: str, camera: str, frame: str) -> Path:
        tail = Path("proj_depth", "groundtruth", camera, f"{frame}.png")
        name = Path(drive).name
        tried = [self.depth_root / drive / tail] + [
            self.depth_root / sub / name / tail for sub in ("", "train", "val")
        ]
        for path in tried:
            if path.is_file():
                return path
        raise FileNotFoundError(
            f"missing file {str(tried[0])!r}: expected the KITTI depth PNG (uint16 / 256) of frame "
            f"{drive}/{camera}/{frame}; also looked at {[str(p) for p in tried[1:]]}"
        )

    def load(self, index: int) -> dict[str, Any]:
        image_path, depth_path = self.frames[index]
        image = read_photo(image_path, dtype=self.dtype)[0]
        depth = read_depth_png(depth_path, 1 / 256, dtype=self.dtype)
        require_one_size((image_path, image), (depth_path, depth))
        mask = valid_depth_mask(depth)
        require_valid_depth(mask, repr(str(depth_path)), depth, MEDIAN_DEPTH_RANGE_M,
                            "its LiDAR depths")
        if self.densify == "nearest":
            depth = densify_nearest(depth, mask)
        else:
            depth = fill_unknown(depth, mask, self.preset.depth_cap)
        return {"image": image, "depth": depth, "mask": mask}
