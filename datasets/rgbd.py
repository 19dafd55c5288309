"""Your own RGB-D captures as a training set: a folder of scenes, each an all-in-focus photo and
its registered depth, whose focused images are synthesised the paper's way.

Layout::

    ROOT/
      camera.json          (optional) the camera that renders every scene's focused images
      train.txt test.txt   (optional) the scene folders of a split, one per line
      scene_a/
        image.png          the all-in-focus photo (PNG, JPEG or TIFF, sRGB-encoded)
        depth.npy          its depth, float metres, (H, W) or (1, H, W); NaN, inf or <= 0: unknown
        camera.json        (optional) this scene's own camera, over ROOT's
      scene_b/
        image.jpg
        depth.png          or a 16-bit single-channel PNG of millimetres; 0: unknown
      ...

The focused images are rendered from the photo and its depth through the PSF layer
(`DepthDataset`, `datasets.focus.cached_focal_stack`), as the paper (Gur & Wolf 2019) does for
NYU Depth v2. The camera is a camera JSON (`datasets.photos.CameraFile`: `focal_length`,
`f_number`, `focus_distance`, one per focused image to render, and `pixel_pitch`, the effective
pitch at the photo's resolution, in metres; optionally `aperture`), the scene's own or ROOT's;
without one it is the paper's (`datasets.presets.NYU`: 35 mm f/2.8, 5.6 um x 4 at 640 pixels
wide, scaled to the photo's width, focused at 2 m and 8 m, `PAPER_FOCUS_FRACTIONS` of the
10 m depth cap). Every scene renders the same number of focused images.

Unknown depth pixels are left out of the metrics and filled with the farthest known depth for
rendering; a depth map without any known pixel is refused.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from optics import CameraSettings

from .base import DepthDataset
from .depth import fill_unknown, require_valid_depth, valid_depth_mask
from .focus import CameraPreset
from .io import DataFormatError, read_depth_png, read_npy, require_one_size, require_root
from .photo_folder import split_scenes
from .photos import CameraFile, read_photo
from .presets import NYU

LAYOUT = ("ROOT/<scene>/image.<png|jpg|jpeg|tif|tiff> and ROOT/<scene>/depth.<npy|png> "
          "(float metres, or 16-bit millimetres with 0 = unknown), optionally camera.json in "
          "ROOT or the scene folder")
#: File names of a scene's all-in-focus photo.
IMAGE_NAMES = ("image.png", "image.jpg", "image.jpeg", "image.tif", "image.tiff")
#: File names of a scene's depth: float metres (`.npy`) or 16-bit millimetres (`.png`).
DEPTH_NAMES = ("depth.npy", "depth.png")
#: Metres per unit of a `depth.png` (millimetres).
PNG_DEPTH_SCALE = 1e-3
#: The largest plausible median depth of a scene, metres: beyond it a `depth.npy` is most
#: likely in millimetres (or another unit) and would scale every depth.
MAX_MEDIAN_M = 1000.0
#: Image width, pixels, at which the default camera's pixel pitch holds (NYU's 640).
PRESET_WIDTH = 640


def _one_file(folder: Path, names: tuple[str, ...], what: str) -> Path:
    """The one file of `names` in `folder`, refused when none or several are there."""
    found = [folder / name for name in names if (folder / name).is_file()]
    if len(found) != 1:
        why = f"no {what} ({', '.join(names)})" if not found else \
            f"{len(found)} {what}s ({', '.join(p.name for p in found)}); keep one"
        raise FileNotFoundError(f"RGBD: {folder}: {why}. Expected {LAYOUT}")
    return found[0]


def read_depth_npy(path: Path, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """A `depth.npy` as `(1,H,W)` metres: a float array `(H,W)` or `(1,H,W)`.

    Raises:
        DataFormatError: another shape, or integer values (millimetres belong in a 16-bit
            `depth.png`).

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "depth.npy"
        >>> np.save(path, np.full((2, 3), 1.5, np.float32))
        >>> read_depth_npy(path).shape
        torch.Size([1, 2, 3])
    """
    array = read_npy(path, "a depth map in metres")
    if array.ndim == 3 and array.shape[0] == 1:
        array = array[0]
    if array.ndim != 2 or not np.issubdtype(array.dtype, np.floating):
        raise DataFormatError(
            f"{str(path)!r}: expected float depth in metres of shape (H, W) or (1, H, W), got "
            f"shape {array.shape} and dtype {array.dtype} (millimetres go in a 16-bit depth.png)")
    return torch.from_numpy(np.ascontiguousarray(array, dtype=np.float64)).to(dtype)[None]


class RGBD(DepthDataset):
    """Scenes of your own RGB-D captures (module docstring) with synthesised focused images.

    Args:
        root: the folder of scenes.
        split: `"all"` or `"train"` (every scene folder), or a split listed in
            `ROOT/<split>.txt` (one scene folder per line).
        preset: the camera of the scenes without a camera JSON, and the depth range
            (`datasets.presets.NYU` by default: the paper's camera, 0-10 m); its pixel pitch
            holds at `PRESET_WIDTH` pixels wide and is scaled to each photo's width.
        **kwargs: `size`, `crop`, `augment`, `cache_dir`, `aperture`, `render_kwargs`,
            `dtype`, `memory_cache_mb` of `DepthDataset`.

    Raises:
        FileNotFoundError: `root`, a split list, a scene's photo or depth is missing (or a
            scene has two of them).
        DataFormatError: a bad camera JSON, scenes of different numbers of focused images, and
            (when a scene is read) an unreadable file, a photo and depth of different sizes, a
            depth map without a known pixel or in another unit than metres.

    Example:
        >>> import tempfile, imageio.v3 as iio
        >>> root = Path(tempfile.mkdtemp())
        >>> (root / "desk").mkdir()
        >>> iio.imwrite(root / "desk" / "image.png", np.full((6, 8, 3), 128, np.uint8))
        >>> np.save(root / "desk" / "depth.npy", np.full((6, 8), 3.0, np.float32))
        >>> sample = RGBD(root)[0]
        >>> sample["focused"].shape, sample["camera"].focus_distance.tolist(), sample["id"]
        (torch.Size([2, 3, 6, 8]), [2.0, 8.0], 'desk')
    """

    name = "rgbd"

    def __init__(self, root: str | Path, split: str = "all", preset: CameraPreset = NYU,
                 **kwargs: Any):
        super().__init__(preset, **kwargs)
        self.root = require_root(root, "RGBD", LAYOUT)
        names = split_scenes(self.root, split)
        if not names:
            raise FileNotFoundError(f"RGBD: no scene folders in {str(self.root)!r}. Expected "
                                    f"{LAYOUT}")
        shared = self.root / "camera.json"
        shared_camera = CameraFile.read(shared).settings if shared.is_file() else None
        self.scenes: list[dict[str, Any]] = []
        for name in names:
            folder = self.root / name
            own = folder / "camera.json"
            camera = CameraFile.read(own).settings if own.is_file() else shared_camera
            self.scenes.append({"image": _one_file(folder, IMAGE_NAMES, "all-in-focus photo"),
                                "depth": _one_file(folder, DEPTH_NAMES, "depth map"),
                                "camera": camera, "source": own if own.is_file() else shared})
        counts = {self._shots(scene): scene for scene in self.scenes}
        if len(counts) > 1:
            shown = ", ".join(f"{n} ({self._camera_name(s)})" for n, s in counts.items())
            raise DataFormatError(f"RGBD: {self.root}: the scenes' cameras render different "
                                  f"numbers of focused images: {shown}; a data set needs one "
                                  "number (one focus distance per focused image)")
        self.ids = list(names)

    def _shots(self, scene: dict[str, Any]) -> int:
        camera = scene["camera"]
        return self.preset.camera.n_shots if camera is None else camera.n_shots

    def _camera_name(self, scene: dict[str, Any]) -> str:
        return "the default camera" if scene["camera"] is None else str(scene["source"])

    def camera_settings(self, index: int, width: int = PRESET_WIDTH) -> CameraSettings:
        """The `(F,)` settings of scene `index`'s focused images, for its photo `width` pixels
        wide: its camera JSON's as they are, else the preset's, the pitch scaled to `width`."""
        camera = self.scenes[index]["camera"]
        if camera is not None:
            return camera.to(self.dtype)
        camera = self.preset.settings(self.dtype)
        return camera.replace(pixel_pitch=camera.pixel_pitch * (PRESET_WIDTH / width))

    def load(self, index: int) -> dict[str, Any]:
        scene = self.scenes[index]
        image = read_photo(scene["image"], dtype=self.dtype)[0]
        path = scene["depth"]
        depth = read_depth_png(path, PNG_DEPTH_SCALE, self.dtype) if path.suffix == ".png" \
            else read_depth_npy(path, self.dtype)
        require_one_size((scene["image"], image), (path, depth))
        mask = valid_depth_mask(depth)
        require_valid_depth(mask, repr(str(path)), depth, (0.0, MAX_MEDIAN_M))
        return {"image": image, "depth": fill_unknown(depth, mask), "mask": mask,
                "camera": self.camera_settings(index, image.shape[-1])}
