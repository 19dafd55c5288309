"""Make3D: outdoor photos with laser-scanned depth grids (Saxena et al.), 400 train / 134 test.

Folder layout (`root`)::

    Train400Img/img-<name>.jpg                  photos (1704x2272)
    Train400Depth/depth_sph_corr-<name>.mat     MATLAB v5, Position3DGrid (H,W,4), depth in [:,:,4]
    Test134Img/img-<name>.jpg
    Test134Depth/depth_sph_corr-<name>.mat

Both archives are on the Make3D page (make3d.cs.cornell.edu). A photo and its depth are matched
by `<name>`. The coarse depth grid (about 305x55) is resized to the photo with nearest
neighbour, then both are resized to `size` (460x345 by default, as is common). Focused images
are synthesised with `datasets.presets.MAKE3D`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from .base import DepthDataset
from .depth import fill_unknown, require_valid_depth, valid_depth_mask
from .focus import CameraPreset
from .io import DataFormatError, check_array_shape, load_mat, require_args, require_root
from .photos import read_photo
from .presets import MAKE3D

LAYOUT = (
    "  <root>/Train400Img/img-<name>.jpg, <root>/Train400Depth/depth_sph_corr-<name>.mat\n"
    "  <root>/Test134Img/img-<name>.jpg,  <root>/Test134Depth/depth_sph_corr-<name>.mat\n"
    "  (.mat: MATLAB v5 with Position3DGrid of shape (H, W, 4), depth in metres in channel 4)"
)

FOLDERS = {"train": ("Train400Img", "Train400Depth"), "test": ("Test134Img", "Test134Depth")}


#: Suffixes of the photos (any case: a copy may have been renamed to `.JPG` or `.jpeg`).
PHOTO_SUFFIXES = (".jpg", ".jpeg")


def match_files(image_dir: Path, depth_dir: Path) -> list[tuple[Path, Path]]:
    """`(photo, depth file)` pairs matched by `<name>`, sorted by photo; a photo without its
    depth file or a depth file without its photo is refused (neither is dropped silently)."""
    photos = sorted(p for p in image_dir.iterdir()
                    if p.suffix.lower() in PHOTO_SUFFIXES and p.is_file()) \
        if image_dir.is_dir() else []
    if not photos:
        raise FileNotFoundError(f"Make3D: no img-*.jpg photos in {str(image_dir)!r} (a folder). "
                                f"Expected:\n{LAYOUT}")
    names = {photo.stem.removeprefix("img-"): photo for photo in photos}
    if len(names) != len(photos):
        stems = [photo.stem for photo in photos]
        twice = sorted({s for s in stems if stems.count(s) > 1})
        raise DataFormatError(f"Make3D: {str(image_dir)!r} holds photos {twice} under two "
                              "suffixes; keep one of each")
    files = []
    for name, photo in names.items():
        depth_path = depth_dir / f"depth_sph_corr-{name}.mat"
        if not depth_path.is_file():
            raise FileNotFoundError(
                f"missing file {str(depth_path)!r}: expected the depth grid of {photo.name}"
            )
        files.append((photo, depth_path))
    orphans = sorted(p.name for p in depth_dir.glob("depth_sph_corr-*.mat")
                     if p.stem.removeprefix("depth_sph_corr-") not in names)
    if orphans:
        raise FileNotFoundError(
            f"Make3D: {len(orphans)} depth file(s) in {str(depth_dir)!r} have no photo "
            f"img-<name>.jpg in {str(image_dir)!r}, e.g. {orphans[:3]}; is the photo archive "
            "incompletely extracted?")
    return files


class Make3D(DepthDataset):
    """Make3D photos with laser depth and synthesised focused images.

    Args:
        root: folder holding `Train400Img`, `Train400Depth`, `Test134Img`, `Test134Depth`.
        split: `"train"` (400 photos) or `"test"` (134).
        preset: camera for focus synthesis (`datasets.presets.MAKE3D` by default).
        **kwargs: `size` (default `(460, 345)`), `crop`, `augment`, `cache_dir`,
            `aperture`, `render_kwargs`, `dtype` of `DepthDataset`.

    Raises:
        FileNotFoundError: `root`, a folder, or the depth file of a photo is missing.
        DataFormatError: a `.mat` file is truncated or `Position3DGrid` has the wrong shape.
    """

    name = "make3d"
    native_width = 1704

    def __init__(
        self, root: str | Path, split: str = "train", preset: CameraPreset = MAKE3D, **kwargs: Any
    ):
        kwargs.setdefault("size", (460, 345))
        super().__init__(preset, **kwargs)
        require_args(("split", split, split in FOLDERS, f"one of {tuple(FOLDERS)}"))
        self.root = require_root(root, "Make3D", LAYOUT)
        self.files = match_files(*(self.root / f for f in FOLDERS[split]))
        self.ids = [image.stem.removeprefix("img-") for image, _ in self.files]

    def load(self, index: int) -> dict[str, Any]:
        image_path, depth_path = self.files[index]
        image = read_photo(image_path, dtype=self.dtype)[0]
        grid = load_mat(depth_path, "Position3DGrid (H, W, 4)").get("Position3DGrid", np.zeros(0))
        check_array_shape(depth_path, "Position3DGrid", grid, (None, None, 4))
        depth = torch.from_numpy(grid[..., 3].astype(np.float64)).to(self.dtype)[None, None]
        depth = F.interpolate(depth, size=image.shape[-2:], mode="nearest-exact")[0]
        mask = valid_depth_mask(depth)
        require_valid_depth(mask, repr(str(depth_path)))
        return {"image": image, "depth": fill_unknown(depth, mask), "mask": mask}
