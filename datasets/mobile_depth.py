"""Mobile Depth (Suwajanakorn et al., "Depth from Focus with Your Mobile Phone", CVPR 2015):
focal stacks of 13 scenes filmed with a phone sweeping its focus; no depth.

Layouts read (checked against `fuy34/DFV` at 5a42ad1: `data_preprocess/reorganize_mobelDepth.py`
and `eval_mobile_Depth.py`; `albert100121/AiFDepthNet` at 4fa8376:
`data/Mobile_Depth_Gen/gen_txt_mobile.py`; the zips themselves were not at hand)::

    depth_from_focus_data3.zip, as released:
        <root>/Aligned/Figure<N>/<scene>/a00.jpg, a01.jpg, ...   aligned frames in capture order
    depth_from_focus_data2.zip, as released (optional, the calibration):
        <root>/calibration/<name>/calibrated.txt   one line "<focus value> <aperture>" per frame,
                                                   then a last line with the focal length alone
    or the folders after DFV's reorganisation:
        <root>/<scene>/a00.jpg, ...                the aligned frames
        <root>/<scene>/focus_dpth.txt              column 0 of calibrated.txt, one value a frame

`root` may be any folder above the scene folders (they are found up to three levels down). Four
scenes are named differently in the calibration (`CALIBRATION_NAMES`); `bucket` and `kitchen`
have none. The calibrated values are not metric (their units are disputed), so focus distances
come, in this order, from `focus_distances` (metres, given by the user), from `focus_dpth.txt` or
`calibrated.txt` (mapped affinely in inverse distance onto `focus_range`, the largest value the
nearest, except in `REVERSED_FOCUS` where DFV's evaluation negates them; they must be strictly
monotonic in frame order unless `sort_by_focus=True`, which orders the frames by their values as
DFV does), or from the frame order alone (equally spaced in inverse distance over `focus_range`,
the first frame the farthest). The phone camera's focal length, f-number and pitch are nominal
(a 2015 phone: 4 mm, f/2.2, 1.12 um pixels of a 4128-pixel-wide sensor), not from the dataset,
which states none. Samples have `mask` all False: the benchmark is judged by eye.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from optics import CameraSettings

from .focus import CameraPreset
from .io import DataFormatError, read_numbers, require_args, require_one_size, require_root
from .photos import read_photo
from .stacks import FocalStackDataset

FRAME = re.compile(r"^a(\d+)\.jpe?g$", re.IGNORECASE)
#: Nominal phone camera: focal length (m), f-number, sensor pitch (m) at the sensor width (px).
PHONE = {"focal_length": 4.0e-3, "f_number": 2.2, "pixel_pitch": 1.12e-6, "sensor_width_px": 4128}
#: Aligned scene name -> its folder name in the calibration zip, where they differ.
CALIBRATION_NAMES = {"metals": "metal", "largemotion": "GTLarge", "smallmotion": "GTSmall",
                     "zeromotion": "GT"}
#: Scenes whose calibrated values run the other way (DFV's evaluation negates them).
REVERSED_FOCUS = frozenset({"metals"})
#: How deep below `root` scene folders are searched (Aligned/Figure<N>/<scene>).
SEARCH_DEPTH = 3
LAYOUT = (
    "  <root>/Aligned/Figure<N>/<scene>/a00.jpg, a01.jpg, ...  aligned frames in capture order\n"
    "  <root>/calibration/<name>/calibrated.txt  optional: '<focus value> <aperture>' a frame\n"
    "  or <root>/<scene>/a00.jpg, ... with optional <root>/<scene>/focus_dpth.txt (DFV's)"
)


def find_scenes(root: Path, depth: int = SEARCH_DEPTH) -> list[Path]:
    """Folders holding frames `a<N>.jpg` at most `depth` levels below `root`, by name.

    Raises:
        DataFormatError: two scene folders share a name (which one is meant is unknown).
    """
    found: dict[str, Path] = {}

    def visit(folder: Path, level: int) -> None:
        children = sorted(folder.iterdir())
        if any(FRAME.match(p.name) for p in children if p.is_file()):
            if folder.name in found:
                raise DataFormatError(f"MobileDepth: two scene folders named {folder.name!r}: "
                                      f"{str(found[folder.name])!r} and {str(folder)!r}")
            found[folder.name] = folder
        if level < depth:
            for child in children:
                if child.is_dir() and child.name != "calibration":
                    visit(child, level + 1)

    visit(root, 0)
    return [found[name] for name in sorted(found)]


def read_calibrated(path: Path) -> list[float]:
    """The per-frame focus values of a release `calibrated.txt` (column 0 of every line but the
    last, which holds the focal length alone).

    Raises:
        DataFormatError: a line that is not numbers, or no frame line.
    """
    numbers = read_numbers(path, "'<focus value> <aperture>' a frame, then the focal length")
    values = [row[0] for row in numbers[:-1]]
    if not values or any(len(row) < 2 for row in numbers[:-1]):
        raise DataFormatError(f"{str(path)!r}: expected one line '<focus value> <aperture>' a "
                              "frame and a last line with the focal length")
    return values


def list_frames(scene: Path) -> list[Path]:
    """The frames `a<N>.jpg` of a scene folder in frame order.

    Raises:
        DataFormatError: the folder holds fewer than 2 frames (a focal stack of one photo has
            no defocus to compare), or the numbering has a gap or a repeat (a frame missing or
            two files for one number), so the order is not known.
    """
    found = sorted(((int(m.group(1)), p) for p in scene.iterdir()
                    if (m := FRAME.match(p.name))), key=lambda x: x[0])
    if len(found) < 2:
        raise DataFormatError(f"{str(scene)!r}: {len(found)} frame(s) a<N>.jpg; a focal stack "
                              "needs 2 or more")
    numbers = [n for n, _ in found]
    expected = list(range(numbers[0], numbers[0] + len(numbers)))
    if numbers != expected:
        missing = sorted(set(expected) - set(numbers))
        raise DataFormatError(f"{str(scene)!r}: frames out of order: numbers {numbers} are not "
                              f"consecutive (missing {missing} or repeated); frame order is focus "
                              "order, so every frame must be there")
    return [p for _, p in found]


def focus_from_calibration(values: Sequence[float], near: float, far: float,
                           source: str = "focus values") -> list[float]:
    """Focus distances (metres) from relative calibrated values, affine in inverse distance:
    the largest value maps to `near`, the smallest to `far`.

    Raises:
        DataFormatError: naming `source` for non-finite values or values that are not strictly
            monotonic in frame order.

    Example:
        >>> tuple(round(d, 3) for d in focus_from_calibration([0.0, 0.5, 1.0], 0.1, 1.0))
        (1.0, 0.182, 0.1)
    """
    v = np.asarray(values, dtype=np.float64)
    steps = np.diff(v)
    if not np.isfinite(v).all() or not (np.all(steps > 0) or np.all(steps < 0)):
        raise DataFormatError(f"{source}: focus values {v.tolist()} must be finite and strictly "
                              "increasing or decreasing in frame order (frames out of order? "
                              "sort_by_focus=True orders them by value)")
    t = (v - v.min()) / (v.max() - v.min())
    return (1.0 / (1.0 / far + t * (1.0 / near - 1.0 / far))).tolist()


class MobileDepth(FocalStackDataset):
    """Mobile Depth focal stacks (real phone frames); no depth.

    Args:
        root: folder of scene folders.
        scenes: names of the scenes to use (all folders with frames by default).
        focus_distances: metres per frame, one list for every scene or a dict scene -> list;
            overrides the calibration files.
        focus_range: `(near, far)` metres that relative focus values are mapped onto.
        n_shots: use this many frames, evenly spaced over the stack (all by default).
        camera: the phone's `focal_length`, `f_number`, `pixel_pitch` and
            `sensor_width_px` (nominal by default, see above).
        calibration: the folder of the release's per-scene calibration folders
            (`<name>/calibrated.txt`); by default `calibration/` in `root` or up to two
            folders above it, where present.
        sort_by_focus: order each scene's frames by their calibrated focus values (as DFV's
            evaluation does) instead of failing where the values are not monotonic in frame
            order.
        **kwargs: `size`, `crop`, `augment`, `dtype`, `memory_cache_mb` of `DepthDataset`.

    Raises:
        FileNotFoundError: `root` or a scene folder is missing, or a scene has no frames.
        DataFormatError: frames out of order, a focus file with a value missing (or extra) for
            a frame, focus values not monotonic in frame order (without `sort_by_focus`), two
            scene folders of one name, or unreadable frames.

    Example:
        >>> import tempfile
        >>> from PIL import Image
        >>> root = Path(tempfile.mkdtemp())
        >>> scene = root / "Aligned" / "Figure1" / "keyboard"
        >>> scene.mkdir(parents=True)
        >>> for n in range(3):
        ...     Image.new("RGB", (16, 12), (40 * n, 90, 200)).save(scene / f"a{n:02d}.jpg")
        >>> data = MobileDepth(root, focus_range=(0.1, 1.0))
        >>> data.ids, tuple(round(d, 3) for d in data.focus[0])
        (['keyboard'], (1.0, 0.182, 0.1))
    """

    name = "mobile_depth"

    def __init__(self, root: str | Path, scenes: Sequence[str] | None = None,
                 focus_distances: Sequence[float] | Mapping[str, Sequence[float]] | None = None,
                 focus_range: tuple[float, float] = (0.1, 1.0), n_shots: int | None = None,
                 camera: Mapping[str, float] | None = None,
                 calibration: str | Path | None = None, sort_by_focus: bool = False,
                 **kwargs: Any):
        near, far = (float(d) for d in focus_range)
        require_args(("focus_range", tuple(focus_range), 0 < near < far,
                      "metres (near, far) with 0 < near < far"),
                     ("n_shots", n_shots, n_shots is None or n_shots >= 1, ">= 1 frames"))
        self.phone = {**PHONE, **dict(camera or {})}
        super().__init__(CameraPreset(self.phone["focal_length"], self.phone["pixel_pitch"],
                                      (near, far), (self.phone["f_number"],), depth_cap=far),
                         **kwargs)
        self.root = require_root(root, "MobileDepth", LAYOUT)
        found = {p.name: p for p in find_scenes(self.root)}
        missing = [s for s in scenes or () if s not in found]
        folders = [found[s] for s in (found if scenes is None else scenes) if s in found]
        if missing or not folders:
            named = f"named {missing} " if missing else ""
            raise FileNotFoundError(f"MobileDepth: no scene folder with frames {named}under "
                                    f"{str(self.root)!r}; found {sorted(found)}. Expected:\n{LAYOUT}")
        self.focus_range, self.n_shots = (near, far), n_shots
        self.depth_range = (near, far)
        self.sort_by_focus = bool(sort_by_focus)
        self.calibration = self._calibration_folder(calibration)
        self.frames: list[list[Path]] = []
        self.focus: list[list[float]] = []
        for folder in folders:
            frames, focus = self._scene_focus(folder, list_frames(folder), focus_distances)
            self.frames.append(frames)
            self.focus.append(focus)
            self.ids.append(folder.name)

    def _calibration_folder(self, given: str | Path | None) -> Path | None:
        if given is not None:
            folder = Path(given)
            if not folder.is_dir():
                raise FileNotFoundError(f"MobileDepth: calibration folder {str(folder)!r} is "
                                        "missing (expected <name>/calibrated.txt inside)")
            return folder
        for above in (self.root, *list(self.root.resolve().parents)[:2]):
            if (above / "calibration").is_dir():
                return above / "calibration"
        return None

    def _focus_file(self, folder: Path) -> tuple[Path, list[float]] | None:
        """The scene's calibrated focus values and their file, or None where it has none."""
        own = folder / "focus_dpth.txt"
        if own.is_file():
            return own, [row[0] for row in read_numbers(own, "one focus value a line", 1)]
        if self.calibration is not None:
            name = CALIBRATION_NAMES.get(folder.name, folder.name)
            path = self.calibration / name / "calibrated.txt"
            if path.is_file():
                return path, read_calibrated(path)
        return None

    def _scene_focus(self, folder: Path, frames: list[Path],
                     given: Any) -> tuple[list[Path], list[float]]:
        """The scene's frames (reordered by focus where `sort_by_focus`) and focus, metres."""
        near, far = self.focus_range
        count = len(frames)
        if isinstance(given, Mapping):
            given = given.get(folder.name)
        if given is not None:
            values = [float(d) for d in given]
            if len(values) != count or not all(math.isfinite(v) and v > 0 for v in values):
                raise ValueError(f"focus_distances for scene {folder.name!r} must hold one "
                                 f"finite distance > 0 metres per frame ({count}), got {values}")
            return frames, values
        calibrated = self._focus_file(folder)
        if calibrated is None:
            return frames, (1.0 / np.linspace(1.0 / far, 1.0 / near, count)).tolist()
        path, values = calibrated
        if len(values) != count:
            raise DataFormatError(f"{str(path)!r}: {len(values)} focus values for {count} frames "
                                  f"in {str(folder)!r}; a focus distance is missing (or extra)")
        if folder.name in REVERSED_FOCUS:
            values = [-v for v in values]
        if self.sort_by_focus:
            order = sorted(range(count), key=lambda i: values[i])
            frames, values = [frames[i] for i in order], [values[i] for i in order]
        return frames, focus_from_calibration(values, near, far, repr(str(path)))

    def load_stack(self, index: int) -> dict[str, Any]:
        frames, focus = self.frames[index], self.focus[index]
        keep = list(range(len(frames)))
        if self.n_shots is not None and self.n_shots < len(frames):
            keep = np.linspace(0, len(frames) - 1, self.n_shots).round().astype(int).tolist()
        shots = [read_photo(frames[i], dtype=self.dtype)[0] for i in keep]
        require_one_size(*zip([frames[i] for i in keep], shots, strict=True))
        focused = torch.stack(shots)
        h, w = focused.shape[-2:]
        pitch = self.phone["pixel_pitch"] * self.phone["sensor_width_px"] / w
        camera = CameraSettings(self.phone["focal_length"], self.phone["f_number"],
                                [focus[i] for i in keep], pitch, aperture="disk").to(self.dtype)
        return {"image": None, "focused": focused, "camera": camera,
                "depth": torch.full((1, h, w), self.focus_range[1], dtype=self.dtype),
                "mask": torch.zeros(1, h, w, dtype=torch.bool)}
