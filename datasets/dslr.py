"""DSLR aperture pairs of Carvalho et al. 2018: real photos at f/2.8 and f/8 with depth PNGs.

Folder layout (`root`)::

    train/f2.8/<name>.png     wide-open photos (the real focused images)
    train/f8/<name>.png       f/8 photos of the same scenes (the near all-in-focus reference)
    train/depth/<name>.png    16-bit depth, `stored * depth_scale` metres, 0 = unknown
    test/...                  the same three folders

Photos may be PNG or JPEG (8 or 16 bit, sRGB; decoded to linear intensity). The folder names can
be changed with `wide`, `reference` and `depth`. Focused images are real, so no synthesis
happens; the camera of the wide photo is `datasets.presets.DSLR` (35 mm, f/2.8, focus
1.7 m) with the pixel pitch of the full-frame sensor scaled to the stored photo's width.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .base import DepthDataset
from .depth import fill_unknown, require_valid_depth, valid_depth_mask
from .focus import CameraPreset
from .io import DataFormatError, read_depth_png, read_rgb, require_root
from .presets import DSLR as DSLR_PRESET

LAYOUT = (
    "  <root>/<split>/f2.8/<name>.png|jpg   (wide-open photos)\n"
    "  <root>/<split>/f8/<name>.png|jpg     (f/8 reference photos)\n"
    "  <root>/<split>/depth/<name>.png      (16-bit depth, 0 = unknown)"
)


class DSLR(DepthDataset):
    """Real defocus: an f/8 photo as the all-in-focus image and the f/2.8 photo as focused image.

    Args:
        root: dataset folder.
        split: sub-folder, `"train"` or `"test"`.
        depth_scale: metres per stored depth unit (`1e-3`: millimetres).
        sensor_width_px: width in pixels of the full sensor whose pitch the preset gives (the
            Nikon D810 records 7360); the effective pitch is scaled by this over the photo width.
        wide: sub-folder of the wide-open photos.
        reference: sub-folder of the f/8 reference photos.
        depth: sub-folder of the depth PNGs.
        preset: the camera of the wide photo (`datasets.presets.DSLR` by default).
        **kwargs: `size`, `crop`, `augment`, `dtype` of
            `DepthDataset` (no synthesis, so no cache is needed).

    Raises:
        FileNotFoundError: `root`, a folder, or a photo or depth file of a scene is missing.
        DataFormatError: an unreadable file, or photos and depth of different sizes.
    """

    name = "dslr"

    def __init__(
        self,
        root: str | Path,
        split: str = "train",
        depth_scale: float = 1e-3,
        sensor_width_px: int = 7360,
        wide: str = "f2.8",
        reference: str = "f8",
        depth: str = "depth",
        preset: CameraPreset = DSLR_PRESET,
        **kwargs: Any,
    ):
        super().__init__(preset, **kwargs)
        if not depth_scale > 0:
            raise ValueError(f"depth_scale must be > 0 metres per unit, got {depth_scale}")
        self.root = require_root(root, "DSLR", LAYOUT)
        self.depth_scale = float(depth_scale)
        self.sensor_width_px = int(sensor_width_px)
        folders = [self.root / split / name for name in (wide, reference, depth)]
        for folder in folders:
            if not folder.is_dir():
                raise FileNotFoundError(f"DSLR: missing folder {str(folder)!r}. Expected:\n{LAYOUT}")
        self.files: list[tuple[Path, Path, Path]] = []
        for wide_path in sorted(p for p in folders[0].iterdir() if p.suffix.lower() in
                                (".png", ".jpg", ".jpeg")):
            matches = [
                [p for p in folder.glob(f"{wide_path.stem}.*")] for folder in folders[1:]
            ]
            for folder, found in zip(folders[1:], matches, strict=True):
                if not found:
                    raise FileNotFoundError(
                        f"missing file {str(folder / (wide_path.stem + '.png'))!r}: expected the "
                        f"{folder.name} image of scene {wide_path.stem!r}"
                    )
            self.files.append((wide_path, matches[0][0], matches[1][0]))
            self.ids.append(wide_path.stem)
        if not self.files:
            raise FileNotFoundError(f"DSLR: no photos in {str(folders[0])!r}")

    def load(self, index: int) -> dict[str, Any]:
        wide_path, ref_path, depth_path = self.files[index]
        focused = read_rgb(wide_path, dtype=self.dtype)
        image = read_rgb(ref_path, dtype=self.dtype)
        depth = read_depth_png(depth_path, self.depth_scale, dtype=self.dtype)
        for path, tensor in ((ref_path, image), (depth_path, depth)):
            if tensor.shape[-2:] != focused.shape[-2:]:
                raise DataFormatError(
                    f"{str(path)!r} is {tuple(tensor.shape[-2:])} pixels but {str(wide_path)!r} "
                    f"is {tuple(focused.shape[-2:])}; all three files of a scene must match"
                )
        camera = self.preset.settings(self.dtype)
        camera = camera.replace(
            pixel_pitch=camera.pixel_pitch * (self.sensor_width_px / image.shape[-1])
        )
        mask = valid_depth_mask(depth)
        require_valid_depth(mask, repr(str(depth_path)))
        return {"image": image, "focused": focused[None], "camera": camera,
                "depth": fill_unknown(depth, mask), "mask": mask}
