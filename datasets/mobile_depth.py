"""Mobile Depth (Suwajanakorn et al., "Depth from Focus with Your Mobile Phone", CVPR 2015):
focal stacks of 13 scenes filmed with a phone sweeping its focus; no depth.

Layout (checked against the Mobile Depth evaluation of `fuy34/DFV`, `eval_mobile_Depth.py`,
which reads the aligned frames of `depth_from_focus_data2.zip` after its reorganisation; the
original zip was not at hand)::

    <root>/<scene>/a00.jpg, a01.jpg, ...   the aligned frames, in capture order (the number
                                           after `a`, without gaps)
    <root>/<scene>/focus_dpth.txt          optional: one calibrated focus value per frame

The dataset's calibration recovers each frame's focus only up to an affine map of inverse
distance, so nothing here is metric. Focus distances come, in this order, from
`focus_distances` (metres, given by the user), from `focus_dpth.txt` (its values are mapped
affinely in inverse distance onto `focus_range`, the largest value the nearest; they must be
strictly monotonic in frame order), or from the frame order alone (equally spaced in inverse
distance over `focus_range`, the first frame the farthest). The phone camera's focal length,
f-number and pitch are nominal (a 2015 phone: 4 mm, f/2.2, 1.12 um pixels of a 4128-pixel-wide
sensor), not from the dataset. Samples have `mask` all False: the benchmark is judged by eye.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from optics import CameraSettings

from .focus import CameraPreset
from .io import DataFormatError, read_rgb, require_root
from .stacks import FocalStackDataset

FRAME = re.compile(r"^a(\d+)\.jpe?g$", re.IGNORECASE)
#: Nominal phone camera: focal length (m), f-number, sensor pitch (m) at the sensor width (px).
PHONE = {"focal_length": 4.0e-3, "f_number": 2.2, "pixel_pitch": 1.12e-6, "sensor_width_px": 4128}
LAYOUT = (
    "  <root>/<scene>/a00.jpg, a01.jpg, ...  aligned frames in capture order\n"
    "  <root>/<scene>/focus_dpth.txt         optional calibrated focus value per frame"
)


def list_frames(scene: Path) -> list[Path]:
    """The frames `a<N>.jpg` of a scene folder in frame order.

    Raises:
        FileNotFoundError: the folder holds no frame.
        DataFormatError: the numbering has a gap or a repeat (a frame missing or two files
            for one number), so the order is not known.
    """
    found = sorted(((int(m.group(1)), p) for p in scene.iterdir()
                    if (m := FRAME.match(p.name))), key=lambda x: x[0])
    if not found:
        raise FileNotFoundError(f"MobileDepth: no frames a<N>.jpg in {str(scene)!r}. "
                                f"Expected:\n{LAYOUT}")
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
                              "increasing or decreasing in frame order (frames out of order?)")
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
        **kwargs: `size`, `crop`, `augment`, `dtype`, `memory_cache_mb` of `DepthDataset`.

    Raises:
        FileNotFoundError: `root` or a scene folder is missing, or a scene has no frames.
        DataFormatError: frames out of order, a focus file with a value missing (or extra) for
            a frame, or unreadable frames.
    """

    name = "mobile_depth"

    def __init__(self, root: str | Path, scenes: Sequence[str] | None = None,
                 focus_distances: Sequence[float] | Mapping[str, Sequence[float]] | None = None,
                 focus_range: tuple[float, float] = (0.1, 1.0), n_shots: int | None = None,
                 camera: Mapping[str, float] | None = None, **kwargs: Any):
        near, far = (float(d) for d in focus_range)
        if not 0 < near < far:
            raise ValueError(f"focus_range must be metres (near, far) with 0 < near < far, "
                             f"got {tuple(focus_range)!r}")
        if n_shots is not None and n_shots < 1:
            raise ValueError(f"n_shots must be >= 1 frames, got {n_shots}")
        self.phone = {**PHONE, **dict(camera or {})}
        super().__init__(CameraPreset(self.phone["focal_length"], self.phone["pixel_pitch"],
                                      (near, far), (self.phone["f_number"],), depth_cap=far),
                         **kwargs)
        self.root = require_root(root, "MobileDepth", LAYOUT)
        folders = [self.root / s for s in scenes] if scenes is not None else sorted(
            p for p in self.root.iterdir() if p.is_dir() and any(FRAME.match(f.name) for f in
                                                                 p.iterdir()))
        if not folders:
            raise FileNotFoundError(f"MobileDepth: no scene folders with frames in "
                                    f"{str(self.root)!r}. Expected:\n{LAYOUT}")
        self.focus_range, self.n_shots = (near, far), n_shots
        self.depth_range = (near, far)
        self.frames: list[list[Path]] = []
        self.focus: list[list[float]] = []
        for folder in folders:
            if not folder.is_dir():
                raise FileNotFoundError(f"MobileDepth: missing scene folder {str(folder)!r}")
            frames = list_frames(folder)
            self.frames.append(frames)
            self.focus.append(self._scene_focus(folder, len(frames), focus_distances))
            self.ids.append(folder.name)

    def _scene_focus(self, folder: Path, count: int, given: Any) -> list[float]:
        near, far = self.focus_range
        if isinstance(given, Mapping):
            given = given.get(folder.name)
        if given is not None:
            values = [float(d) for d in given]
            if len(values) != count:
                raise ValueError(f"focus_distances for scene {folder.name!r} must hold one value "
                                 f"per frame ({count}), got {len(values)}")
            return values
        calibration = folder / "focus_dpth.txt"
        if calibration.is_file():
            try:
                values = np.atleast_1d(np.loadtxt(calibration, dtype=np.float64)).tolist()
            except ValueError as error:
                raise DataFormatError(f"{str(calibration)!r}: not a list of numbers ({error})") \
                    from None
            if len(values) != count:
                raise DataFormatError(f"{str(calibration)!r}: {len(values)} focus values for "
                                      f"{count} frames; a focus distance is missing (or extra)")
            return focus_from_calibration(values, near, far, repr(str(calibration)))
        return (1.0 / np.linspace(1.0 / far, 1.0 / near, count)).tolist()

    def load_stack(self, index: int) -> dict[str, Any]:
        frames, focus = self.frames[index], self.focus[index]
        keep = list(range(len(frames)))
        if self.n_shots is not None and self.n_shots < len(frames):
            keep = np.linspace(0, len(frames) - 1, self.n_shots).round().astype(int).tolist()
        shots = [read_rgb(frames[i], dtype=self.dtype) for i in keep]
        for i, shot in zip(keep, shots, strict=True):
            if shot.shape != shots[0].shape:
                raise DataFormatError(f"{str(frames[i])!r} is {tuple(shot.shape[-2:])} pixels but "
                                      f"{str(frames[keep[0]])!r} is {tuple(shots[0].shape[-2:])}")
        focused = torch.stack(shots)
        h, w = focused.shape[-2:]
        pitch = self.phone["pixel_pitch"] * self.phone["sensor_width_px"] / w
        camera = CameraSettings(self.phone["focal_length"], self.phone["f_number"],
                                [focus[i] for i in keep], pitch, aperture="disk").to(self.dtype)
        return {"image": None, "focused": focused, "camera": camera,
                "depth": torch.full((1, h, w), self.focus_range[1], dtype=self.dtype),
                "mask": torch.zeros(1, h, w, dtype=torch.bool)}
