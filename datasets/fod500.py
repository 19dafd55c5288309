"""FoD500 (Maximov et al., "Focus on Defocus", CVPR 2020, the DefocusNet data): 500 Blender
scenes, each a focal stack of 5 renders and a depth map.

Release (checked against the official `dvl-tum/defocus-net` `source/util_func.py` and
`run_training.py`, and the FoD500 loader and evaluation of `fuy34/DFV`): one folder (`fs_6/`)
of files whose names start with the 6-digit scene index::

    <root>/<scene>...All.tif   5 renders per scene, 256x256 sRGB; in name order they are focused
                               at 0.1, 0.15, 0.3, 0.7 and 1.5 m
    <root>/<scene>...Dpt.exr   depth in metres: the R channel of a half-float OpenEXR
    <root>/<scene>...Aif.tif   optional all-in-focus render (not in the official release,
                               dvl-tum/defocus-net issue 3; some re-renders add it)

Scenes 0-399 are the training split and 400-499 the test split (DFV's readme: the first 400
stacks train, the last 100 test). The camera (DefocusNet readme and `run_training.py`): focal
length 2.9 mm, f/1, focus distances above; the sensor is 3.1 mm wide (FOSSA's
`util/gen_focal_stack.py`, the same 2.9 mm lens), so the 256-pixel renders have a pitch of
12.1 um. DefocusNet trains on depth clipped at 3 m; DFV's evaluation clips depth and
prediction at 1.5 m (`models.protocols.PROTOCOLS["fod500"]`).
"""

from __future__ import annotations

import re
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from optics import CameraSettings

from .depth import fill_unknown, require_valid_depth, valid_depth_mask
from .focus import CameraPreset
from .io import DataFormatError, require_args, require_file, require_one_size, require_root
from .photos import read_photo
from .stacks import FocalStackDataset

#: Focus distance of each render in name order, metres (DefocusNet readme).
FOCUS_DISTANCES = (0.1, 0.15, 0.3, 0.7, 1.5)
FOCAL_LENGTH = 2.9e-3
F_NUMBER = 1.0
#: Sensor width in metres over the 256-pixel width of the renders.
SENSOR_WIDTH = 3.1e-3
#: Depth cap of DefocusNet's training, metres.
DEPTH_CAP = 3.0
SPLITS = {"train": range(0, 400), "test": range(400, 500), "all": range(0, 10**6)}
LAYOUT = (
    "  <root>/<6-digit scene>...All.tif  5 renders per scene (focus 0.1, 0.15, 0.3, 0.7, 1.5 m)\n"
    "  <root>/<6-digit scene>...Dpt.exr  depth in metres (OpenEXR, R channel)\n"
    "  <root>/<6-digit scene>...Aif.tif  optional all-in-focus render"
)
PATTERN = re.compile(r"^(\d{6}).*(All\.tif|Dpt\.exr|Aif\.tif)$")


def read_exr_depth(path: Path, channel: str = "R") -> np.ndarray:
    """The depth channel of an OpenEXR file as float32 `(H,W)` (Blender writes depth into R, G
    and B; a single-channel `Z` or `Y` file is read too).

    Raises:
        FileNotFoundError: `path` does not exist.
        DataFormatError: not an OpenEXR file, truncated, or without the channel.
    """
    import OpenEXR

    require_file(path, "an OpenEXR depth map")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as file:
            channels = file.channels()
            name = next((c for c in (channel, "Z", "Y") if c in channels), None)
            if name is None:
                raise DataFormatError(f"{str(path)!r}: no channel {channel!r} (nor Z or Y) holding "
                                      f"depth; channels: {sorted(channels)}")
            return np.asarray(channels[name].pixels, dtype=np.float32)
    except (RuntimeError, ValueError, OSError) as error:
        if isinstance(error, DataFormatError):
            raise
        raise DataFormatError(f"{str(path)!r}: cannot be read as an OpenEXR depth map ("
                              f"{' '.join(str(error).split())}); the file may be truncated") from None


class FoD500(FocalStackDataset):
    """FoD500 focal stacks (5 renders each) with depth in metres.

    Args:
        root: the release folder (`fs_6/`).
        split: `"train"` (scenes 0-399), `"test"` (400-499) or `"all"`.
        **kwargs: `size`, `crop`, `augment`, `dtype`, `memory_cache_mb` of `DepthDataset`.

    Raises:
        FileNotFoundError: `root`, or a scene's depth file, is missing.
        DataFormatError: a scene has not 5 renders (one per focus distance), a file is
            unreadable or truncated, sizes differ, or the depth is not metres.
    """

    name = "fod500"

    #: Depth range of the scenes, metres (DefocusNet's cap): the methods' prior.
    depth_range = (0.1, DEPTH_CAP)

    def __init__(self, root: str | Path, split: str = "test", **kwargs: Any):
        require_args(("split", split, split in SPLITS, f"one of {sorted(SPLITS)}"))
        super().__init__(CameraPreset(FOCAL_LENGTH, SENSOR_WIDTH / 256, FOCUS_DISTANCES,
                                      (F_NUMBER,), depth_cap=DEPTH_CAP), **kwargs)
        self.root = require_root(root, "FoD500", LAYOUT)
        files: dict[str, dict[str, list[Path]]] = defaultdict(lambda: defaultdict(list))
        for path in sorted(self.root.iterdir()):
            match = PATTERN.match(path.name)
            if match and int(match.group(1)) in SPLITS[split]:
                files[match.group(1)][match.group(2)].append(path)
        if not files:
            raise FileNotFoundError(f"FoD500: no scenes of split {split!r} in {str(self.root)!r}. "
                                    f"Expected:\n{LAYOUT}")
        self.scenes: list[tuple[list[Path], Path, Path | None]] = []
        for scene, kinds in sorted(files.items()):
            renders = kinds["All.tif"]
            if len(renders) != len(FOCUS_DISTANCES):
                names = ", ".join(p.name for p in renders) or "none"
                raise DataFormatError(
                    f"FoD500 scene {scene} in {str(self.root)!r} has {len(renders)} renders "
                    f"({names}); expected {len(FOCUS_DISTANCES)}, one per focus distance "
                    f"{', '.join(f'{d:g}' for d in FOCUS_DISTANCES)} m")
            if len(kinds["Dpt.exr"]) != 1:
                raise FileNotFoundError(f"missing file {str(self.root / (scene + 'Dpt.exr'))!r}: "
                                        f"expected the depth map of FoD500 scene {scene} "
                                        f"(found {len(kinds['Dpt.exr'])})")
            aif = kinds["Aif.tif"][0] if kinds["Aif.tif"] else None
            self.scenes.append((renders, kinds["Dpt.exr"][0], aif))
            self.ids.append(scene)

    def load_stack(self, index: int) -> dict[str, Any]:
        renders, depth_path, aif_path = self.scenes[index]
        shots = [read_photo(p, dtype=self.dtype)[0] for p in renders]
        image = None if aif_path is None else read_photo(aif_path, dtype=self.dtype)[0]
        array = read_exr_depth(depth_path)
        depth = torch.from_numpy(array.astype(np.float64)).to(self.dtype)[None]
        require_one_size(*zip(renders, shots, strict=True), (depth_path, depth), (aif_path, image))
        focused = torch.stack(shots)
        mask = valid_depth_mask(depth)
        require_valid_depth(mask, repr(str(depth_path)), depth, (0.0, 100.0))
        pitch = SENSOR_WIDTH / focused.shape[-1]
        camera = CameraSettings(FOCAL_LENGTH, F_NUMBER, list(FOCUS_DISTANCES), pitch,
                                aperture="disk").to(self.dtype)
        return {"image": image, "focused": focused, "camera": camera,
                "depth": fill_unknown(depth, mask), "mask": mask}
