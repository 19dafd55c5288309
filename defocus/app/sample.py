"""A small set of photos to try every command on (`defocus sample DIR`), photographed from the
embedded real Middlebury motorcycle scene (scikit-image; real depth 2.1-5.0 m from its
disparity) through a 50 mm f/1.8 full-frame camera by `datasets.capture.capture`: the
occlusion-aware renderer with a disk PSF, shot and read noise, 8-bit sRGB, small exposure and
white-balance differences and up to a pixel of misalignment between the shots."""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from .outputs import creating_folder, plan_files

#: Focal length (m), f-number, sensor width (m) of the sample camera.
SAMPLE_LENS = (0.050, 1.8, 0.036)
#: Focus distance of each photo, metres: near, middle, far.
SAMPLE_FOCUS = {"near": 2.3, "middle": 3.1, "far": 4.6}
#: The depth range to state for the sample scene, metres.
SAMPLE_DEPTH_RANGE = (1.5, 8.0)
#: `(H, W)` pixels of the motorcycle scene at scale 1 (`datasets.middlebury.load_motorcycle`).
SCENE_SIZE = (500, 741)
#: The files of a sample set, in the order written, and what each holds.
SAMPLE_FILES = {"aif.png": "sample all-in-focus photo",
                **{f"{name}.png": f"sample {name} photo" for name in SAMPLE_FOCUS},
                "camera.json": "sample camera JSON (near/far)",
                "camera_stack.json": "sample camera JSON (stack)",
                "depth.npy": "sample depth map"}


@dataclass
class SampleSet:
    """The files `write_sample_set` wrote (paths under its folder)."""

    folder: Path
    files: list[Path] = field(default_factory=list)


def scaled_size(scale: float) -> tuple[int, int]:
    """`(H, W)` pixels of the scene downscaled by `scale`, as `torch.nn.functional.interpolate`
    sizes it (each side rounded down).

    Example:
        >>> scaled_size(0.01)
        (5, 7)
    """
    return int(SCENE_SIZE[0] * scale), int(SCENE_SIZE[1] * scale)


def check_scale_range(scale: float) -> float:
    """`scale` as a float, refusing one that is not a number in (0, 1] by `--scale`.

    Example:
        >>> check_scale_range(0)
        Traceback (most recent call last):
        ...
        ValueError: --scale 0: must be a number in (0, 1], the fraction of the scene's 741x500 pixels
    """
    try:
        value = float(scale)
    except (TypeError, ValueError):
        value = math.nan
    if isinstance(scale, bool) or not 0 < value <= 1:
        text = f"{value:g}" if isinstance(scale, numbers.Real) else repr(scale)
        raise ValueError(f"--scale {text}: must be a number in (0, 1], the fraction of the "
                         f"scene's {SCENE_SIZE[1]}x{SCENE_SIZE[0]} pixels")
    return value


def smallest_scale(problem: Callable[[float], str | None]) -> float:
    """The smallest scale, to 4 decimals, that `problem` (None where a scale works, the
    reason where not; larger scales work where a smaller one does) lets through.

    Example:
        >>> smallest_scale(lambda scale: None if min(scaled_size(scale)) >= 6 else "small")
        0.012
    """
    low, high = 1, 10_000  # in 1/10_000
    while low < high:
        middle = (low + high) // 2
        low, high = (low, middle) if problem(middle / 10_000) is None else (middle + 1, high)
    return low / 10_000


def check_scene_scale(scale: float, problem: Callable[[float], str | None],
                      what: str = "photos") -> float:
    """`scale` as a float, refusing one outside (0, 1] (`check_scale_range`) or one that
    `problem` finds too small (e.g. too few pixels), by `--scale`, the value, the size it
    would give and the smallest `--scale` allowed (`smallest_scale`).

    Example:
        >>> check_scene_scale(0.001, lambda scale: None if min(scaled_size(scale)) else "empty")
        Traceback (most recent call last):
        ...
        ValueError: --scale 0.001 would give 0x0-pixel photos (width x height): empty; the smallest --scale is 0.002
    """
    value = check_scale_range(scale)
    reason = problem(value)
    if reason is not None:
        height, width = scaled_size(value)
        raise ValueError(f"--scale {value:g} would give {width}x{height}-pixel {what} (width x "
                         f"height): {reason}; the smallest --scale is "
                         f"{smallest_scale(problem):g}")
    return value


def sample_camera(width: int):
    """The `CameraSettings` of the sample's near, middle and far photos, `width` pixels wide."""
    from optics import LENS_APERTURE, CameraSettings

    focal_length, f_number, sensor_width = SAMPLE_LENS
    return CameraSettings(focal_length, f_number, list(SAMPLE_FOCUS.values()),
                          sensor_width / width, aperture=LENS_APERTURE)


def predict_problem(scale: float) -> str | None:
    """Why the sample set at `scale` is too small for the `defocus predict` command that
    `defocus sample` suggests (the near/far pair with the all-in-focus photo), or None: at
    least `MIN_PHOTO_SIDE` pixels a side, and blur that changes by at least
    `READABLE_DIFFERENCE_PX` pixels over `SAMPLE_DEPTH_RANGE` (the coarser the photos, the
    larger their pixels and the less their blur changes).

    Example:
        >>> predict_problem(0.35) is None
        True
    """
    from models.depth_from_photos.estimate import READABLE_DIFFERENCE_PX, check_blur_readable
    from models.depth_from_photos.resolution import MIN_PHOTO_SIDE

    height, width = scaled_size(scale)
    if min(height, width) < MIN_PHOTO_SIDE:
        return f"`defocus predict` reads photos of at least {MIN_PHOTO_SIDE} pixels a side"
    near, far = SAMPLE_DEPTH_RANGE
    try:
        check_blur_readable(sample_camera(width).select_shots([0, 2]), near, far)
    except ValueError:
        return (f"their blur would change by less than {READABLE_DIFFERENCE_PX:g} pixels over "
                f"{near:g}-{far:g} m, too little for `defocus predict` to tell depths apart")
    return None


def render_problem(scale: float) -> str | None:
    """Why the scene at `scale` is too small to render (no pixels), or None."""
    return None if min(scaled_size(scale)) >= 1 else "the scene would have no pixels"


def check_folder_name(folder: Path | str, option: str, example: str) -> Path:
    """`folder` as a `Path`, refusing an empty or blank one (`Path("")` is the current
    folder, which the user did not name).

    Example:
        >>> check_folder_name("", "FOLDER", "samples")
        Traceback (most recent call last):
        ...
        ValueError: FOLDER '': an empty path would write into the current folder; name a folder (e.g. samples, or . for the current folder)
    """
    if isinstance(folder, str) and not folder.strip():
        raise ValueError(f"{option} {folder!r}: an empty path would write into the current "
                         f"folder; name a folder (e.g. {example}, or . for the current folder)")
    return Path(folder)


def write_sample_set(folder: Path | str, scale: float = 0.35, seed: int = 0,
                     overwrite: bool = False) -> SampleSet:
    """Write `aif.png` (the all-in-focus photo), `near.png`, `middle.png`, `far.png` (photos
    focused at `SAMPLE_FOCUS`), `camera.json` (the camera of the near/far pair),
    `camera_stack.json` (of the three focused photos; each JSON names its photos under
    `"photos"`, so the folder is also a scene of `datasets.PhotoFolder`) and `depth.npy` (the
    true depth, metres) under `folder`; `scale` downsizes the 741x500 scene first.

    The files follow the output policy (`defocus.app.outputs`): every path is checked before
    any work (an earlier sample set is replaced only with `overwrite`; a folder in the way of
    a file is refused), and the set is written whole or not at all.

    Raises:
        ValueError: an empty `folder`, a `scale` outside (0, 1] or too small for the photos
            that `defocus predict` reads (`check_scene_scale`), or a `seed` that is not an
            integer >= 0.
        FileExistsError: files of an earlier set are in `folder` and `overwrite` is off.

    Example:
        >>> import tempfile
        >>> sample = write_sample_set(Path(tempfile.mkdtemp()), scale=0.1)
        >>> sorted(path.name for path in sample.files)[:3]
        ['aif.png', 'camera.json', 'camera_stack.json']
    """
    folder = check_folder_name(folder, "FOLDER", "samples")
    scale = check_scene_scale(scale, predict_problem)
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise ValueError(f"--seed {seed!r}: must be an integer >= 0 (the seed of the photos' "
                         "noise)")
    earlier = [name for name in SAMPLE_FILES if (folder / name).is_file()]
    if earlier and not overwrite:
        raise FileExistsError(f"FOLDER {folder} already holds {', '.join(earlier)} (an earlier "
                              "sample set); give --overwrite to replace them, or choose another "
                              "FOLDER")
    plan, paths = plan_files(folder, SAMPLE_FILES, overwrite, option="FOLDER")
    with creating_folder(folder, "FOLDER"):
        return _write(plan, paths, folder, scale, seed)


def _write(plan, paths: dict[str, Path], folder: Path, scale: float, seed: int) -> SampleSet:
    """Photograph the scene and write the planned files through `plan` (all or none)."""
    import numpy as np
    import torch

    from datasets.capture import capture
    from datasets.middlebury import motorcycle_scene
    from datasets.photos import save_photo

    image, depth, _ = (t[0] for t in motorcycle_scene(scale))
    names = list(SAMPLE_FOCUS)
    stack = sample_camera(image.shape[-1])
    aif, focused = capture(image, depth, stack, np.random.default_rng(seed))
    pair = stack.select_shots([0, 2])
    true_depth = depth[0].to(torch.float32).numpy()
    with plan.writing() as write:
        write(paths["aif.png"], lambda tmp: save_photo(tmp, aif))
        for name, photo in zip(names, focused, strict=True):
            write(paths[f"{name}.png"], lambda tmp, photo=photo: save_photo(tmp, photo))
        write(paths["camera.json"], lambda tmp: pair.to_json(tmp, photos=["near.png", "far.png"]))
        write(paths["camera_stack.json"],
              lambda tmp: stack.to_json(tmp, photos=[f"{name}.png" for name in names]))
        write(paths["depth.npy"], lambda tmp: np.save(tmp, true_depth))
    return SampleSet(folder, [paths[name] for name in SAMPLE_FILES])
