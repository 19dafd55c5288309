"""Your own photos as a training set: a folder of scenes, each an all-in-focus photo and the
photos focused at the camera's focus distances, with their camera in a JSON file.

Layout (what `defocus sample DIR` writes is one such scene)::

    ROOT/
      camera.json          settings of every scene (optional where each scene has its own)
      scene_a/
        aif.png            the all-in-focus photo (a small aperture; any photo format)
        near.png far.png   the focused photos, named in camera.json's "photos" list
        camera.json        (optional) this scene's own camera
      scene_b/ ...

A camera JSON is what `defocus calibrate` and `defocus sample` write (`optics.CameraSettings`
with one focus distance and f-number per focused photo) plus `"photos"`: the file names of the
focused photos in the order of its shots. The photos have no ground-truth depth: they train a
network through the PSF layer (self-supervised), not a depth-supervised one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from optics import CameraSettings

from .base import DepthDataset
from .focus import CameraPreset
from .io import DataFormatError, read_list, require_one_size, require_root
from .photos import CameraFile, read_photo

LAYOUT = ("ROOT/<scene>/aif.<ext> and the focused photos named in ROOT/camera.json's or "
          "ROOT/<scene>/camera.json's \"photos\" list")
#: File names of the all-in-focus photo (any of these suffixes).
AIF_NAMES = ("aif.png", "aif.tif", "aif.tiff", "aif.jpg", "aif.jpeg", "aif.dng")


def split_scenes(root: Path, split: str) -> list[str]:
    """The scene folder names of `split` in the folder of scenes `root`: those listed in
    `root/<split>.txt` (one per line), else, for `"train"` and `"all"`, every folder (hidden
    and tool folders such as `.ipynb_checkpoints` and `__MACOSX` hold no scene).

    Raises:
        FileNotFoundError: the list names a folder that is not there, or another split has no
            list.
    """
    listed = root / f"{split}.txt"
    if listed.is_file():
        names = read_list(listed, f"the list of {split} scenes")
        missing = [name for name in names if not (root / name).is_dir()]
        if missing:
            raise FileNotFoundError(f"{listed} names scene folders {missing}, which are not "
                                    f"in {root}")
        return names
    if split not in ("train", "all"):
        raise FileNotFoundError(f"{root}: no {listed.name} listing the scenes of split "
                                f"{split!r}; only 'train' and 'all' take every scene folder")
    return sorted(p.name for p in root.iterdir()
                  if p.is_dir() and not p.name.startswith((".", "__")))


class PhotoFolder(DepthDataset):
    """Scenes of your own photos (module docstring), for self-supervised training.

    Args:
        root: the folder of scenes.
        split: `"train"` or `"all"`: every scene (a folder may also list its scenes of a split
            in `ROOT/<split>.txt`, one per line; any other split needs its list, and a list
            naming a folder that is not there or one twice is refused).
        **kwargs: `size`, `crop`, `augment`, `dtype` of `DepthDataset`.

    Example:
        >>> import tempfile
        >>> from defocus.app.sample import write_sample_set  # doctest: +SKIP
        >>> root = Path(tempfile.mkdtemp())  # doctest: +SKIP
        >>> _ = write_sample_set(root / "scene", scale=0.1)  # doctest: +SKIP
        >>> sample = PhotoFolder(root)[0]  # doctest: +SKIP
        >>> sample["focused"].shape  # doctest: +SKIP
        torch.Size([3, 3, 50, 74])
    """

    name = "folder"

    def __init__(self, root: str | Path, split: str = "train", **kwargs: Any):
        self.root = require_root(root, "PhotoFolder", LAYOUT)
        self.scenes = [self._scene(self.root / name) for name in split_scenes(self.root, split)]
        if not self.scenes:
            raise FileNotFoundError(f"{self.root}: no scene folders; expected {LAYOUT}")
        first = self.scenes[0]["camera"]
        counts = {scene["camera"].n_shots for scene in self.scenes}
        if len(counts) > 1:
            raise DataFormatError(f"{self.root}: scenes have {sorted(counts)} focused photos; "
                                  "a training set needs one number of shots")
        preset = CameraPreset(float(first.focal_length[0]), float(first.pixel_pitch[0]),
                              first.focus_distance.tolist(), first.f_number.tolist(),
                              aperture=first.aperture)
        super().__init__(preset, **kwargs)
        self.ids = [scene["folder"].name for scene in self.scenes]

    def _scene(self, folder: Path) -> dict[str, Any]:
        own = folder / "camera.json"
        path = own if own.is_file() else self.root / "camera.json"
        if not path.is_file():
            raise FileNotFoundError(f"{folder}: no camera.json here or in {self.root}")
        camera = CameraFile.read(path, require=("photos",))
        photos = camera.photos
        aif = next((folder / name for name in AIF_NAMES if (folder / name).is_file()), None)
        missing = [name for name in photos if not (folder / name).is_file()]
        if aif is None or missing:
            raise FileNotFoundError(f"{folder}: " + (
                f"{path} names {missing}, which are not there" if missing else
                f"no all-in-focus photo ({', '.join(AIF_NAMES)})"))
        return {"folder": folder, "camera": camera.settings, "aif": aif,
                "focused": [folder / name for name in photos]}

    def camera_settings(self, index: int) -> CameraSettings:
        return self.scenes[index]["camera"].to(self.dtype)

    def load(self, index: int) -> dict[str, Any]:
        scene = self.scenes[index]
        image, _ = read_photo(scene["aif"], dtype=self.dtype)
        focused = [read_photo(path, dtype=self.dtype)[0] for path in scene["focused"]]
        require_one_size((scene["aif"], image), *zip(scene["focused"], focused, strict=True))
        h, w = image.shape[-2:]
        return {"image": image, "focused": torch.stack(focused),
                "camera": self.camera_settings(index),
                "depth": torch.full((1, h, w), float(self.preset.depth_cap), dtype=self.dtype),
                "mask": torch.zeros(1, h, w, dtype=torch.bool)}

