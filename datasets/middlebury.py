"""Middlebury stereo scenes: real images with real depth from disparity.

scikit-image ships one of them, the *motorcycle* scene (Middlebury 2014, quarter size), so it is
the library's offline real-data default (`Middlebury(None)`).

Folder layout of the Middlebury 2014 scenes (`root`)::

    <Scene>-perfect/im0.png      left image (the all-in-focus image)
    <Scene>-perfect/im1.png      right image (not used)
    <Scene>-perfect/disp0.pfm    left disparity in pixels, `inf` where unknown
    <Scene>-perfect/calib.txt    cam0=[f 0 cx; 0 f cy; 0 0 1], doffs=..., baseline=... (mm), ...
    <split>.txt                  optional: scene folder names of a split, one per line

Depth is `Z = baseline * f / (d + doffs)`; focused images are synthesised with
`datasets.presets.MIDDLEBURY`, whose pixel pitch is set per scene to `focal_length / f`
so that the virtual lens keeps the scene's field of view.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from kornia.color import rgb_to_linear_rgb
from torch import Tensor

from optics import LENS_APERTURE

from .base import DepthDataset
from .depth import require_valid_depth
from .focus import CameraPreset
from .io import (
    DataFormatError,
    read_list,
    read_pfm,
    read_text,
    require_args,
    require_file,
    require_one_size,
    require_root,
)
from .photos import read_photo
from .presets import MIDDLEBURY

#: Calibration of scikit-image's motorcycle scene: focal length in pixels, baseline in metres,
#: disparity offset in pixels (Middlebury 2014 `calib.txt` scaled to the shipped resolution).
MOTORCYCLE_CALIB = {"focal_length_px": 994.978, "baseline_m": 0.193, "doffs_px": 31.086}


def disparity_to_depth(
    disparity: Tensor, focal_length_px: float, baseline_m: float, doffs_px: float = 0.0
) -> tuple[Tensor, Tensor]:
    """Depth in metres from stereo disparity in pixels: `Z = f_px * B / (d + doffs)`.

    Returns `(depth, mask)`; unknown disparities (`inf` or NaN, as Middlebury stores them) are
    masked out and their depth set to the largest valid depth, so the map stays finite.

    Example:
        >>> depth, mask = disparity_to_depth(torch.tensor([10.0, float("inf")]), 1000.0, 0.1, 0.0)
        >>> depth, mask
        (tensor([10., 10.]), tensor([ True, False]))
    """
    mask = torch.isfinite(disparity) & (disparity + doffs_px > 0)
    depth = (
        focal_length_px
        * baseline_m
        / torch.where(mask, disparity + doffs_px, torch.ones_like(disparity))
    )
    fill = depth[mask].max() if bool(mask.any()) else torch.ones((), dtype=depth.dtype)
    return torch.where(mask, depth, fill), mask


def load_motorcycle(dtype: torch.dtype = torch.float32) -> dict[str, Tensor]:
    """The motorcycle scene shipped with scikit-image, as tensors.

    Returns:
        dict with `image` `(1,3,H,W)` in [0,1] (sRGB-decoded to linear intensity), `depth`
        `(1,1,H,W)` metres (2.1-5.0 m), `mask` `(1,1,H,W)` bool (known disparity), and the
        calibration under `calib`.
    """
    from skimage import data

    left, _, disparity = data.stereo_motorcycle()
    srgb = torch.from_numpy(np.ascontiguousarray(left)).to(dtype).permute(2, 0, 1)[None] / 255.0
    linear = rgb_to_linear_rgb(srgb)
    depth, mask = disparity_to_depth(torch.from_numpy(disparity).to(dtype), **MOTORCYCLE_CALIB)
    return {
        "image": linear,
        "depth": depth[None, None],
        "mask": mask[None, None],
        "calib": MOTORCYCLE_CALIB,
    }


def motorcycle_focus_sweep(
    focus_distances: Sequence[float] = (2.2, 3.0, 4.0, 5.0), focal_length: float = 0.085,
    f_number: float = 1.4, aperture: str = LENS_APERTURE, mode: str = "scatter", scale: float = 0.5,
) -> dict[str, Any]:
    """Render the real motorcycle scene through a thin lens at several focus distances.

    The pixel pitch is chosen so that `focal_length` matches the scene's calibrated focal length
    in pixels (at the downscaled resolution).

    Args:
        focus_distances: metres (the scene spans about 2.1-5.0 m).
        focal_length: metres.
        f_number: dimensionless.
        aperture: PSF spec (`optics.aperture_spec`), e.g. `"disk"`, `"polygon:6"`.
        mode: renderer semantics, `"gather"`, `"scatter"` or `"layered"`.
        scale: downscale factor in (0, 1] of the 741x500 scene.

    Returns:
        dict with `image` `(3,H,W)`, `depth` `(1,H,W)` metres, `renders` `(F,3,H,W)`, `coc_px`
        `(F,1,H,W)` and the `(F,)` `settings`.

    Example:
        >>> sweep = motorcycle_focus_sweep([2.2, 5.0], scale=0.1)
        >>> sweep["renders"].shape
        torch.Size([2, 3, 50, 74])
    """
    import torch.nn.functional as F

    from optics import CameraSettings, render_focal_stack

    require_args(("scale", scale, 0 < float(scale) <= 1, "in (0, 1]"))
    scene = load_motorcycle()
    image, depth = scene["image"], scene["depth"]
    if scale != 1:
        image = F.interpolate(image, scale_factor=scale, mode="area")
        depth = F.interpolate(depth, scale_factor=scale, mode="nearest")
    pixel_pitch = focal_length / (scene["calib"]["focal_length_px"] * scale)
    settings = CameraSettings(focal_length, f_number, list(focus_distances), pixel_pitch,
                              aperture=aperture).to(image.dtype)
    n = settings.n_shots
    with torch.no_grad():
        renders = render_focal_stack(image, depth, settings, mode=mode)[0]
        coc = settings.camera().coc_px(depth.expand(n, -1, -1, -1))
    return {"image": image[0], "depth": depth[0], "renders": renders, "coc_px": coc,
            "settings": settings}


def motorcycle_scene(scale: float = 1.0) -> tuple[Tensor, Tensor, Tensor]:
    """The motorcycle's image `(1,3,H,W)` (linear), depth `(1,1,H,W)` metres and known-depth mask,
    downscaled by `scale` in (0, 1].

    Image and depth are area-averaged (depth over known pixels only); a pixel stays known only if
    all of its source pixels had known disparity. Unknown depth is filled with the farthest known
    depth, so the scene can be rendered.
    """
    import torch.nn.functional as F

    require_args(("scale", scale, 0 < float(scale) <= 1, "in (0, 1]"))
    scene = load_motorcycle()
    known = scene["mask"].to(scene["depth"].dtype)
    if scale != 1:
        image = F.interpolate(scene["image"], scale_factor=scale, mode="area")
        coverage = F.interpolate(known, scale_factor=scale, mode="area")
        depth = F.interpolate(scene["depth"] * known, scale_factor=scale, mode="area")
        depth = depth / coverage.clamp_min(1e-6)
        mask = coverage > 0.999
    else:
        image, depth, mask = scene["image"], scene["depth"], scene["mask"].bool()
    return image, torch.where(mask, depth, depth[mask].max()), mask


def motorcycle_sample(scale: float = 0.25, preset: CameraPreset | None = None) -> dict[str, Any]:
    """The real motorcycle scene in the sample format, for evaluation (the demo's test scene).

    The scene is downscaled by `scale` (area-averaged; a pixel stays valid only if all of its
    source pixels had known disparity) and its focused images are rendered from its real depth
    through `preset` (the synthetic scenes' camera by default). Unknown depth is filled with the
    farthest known depth before rendering.

    Args:
        scale: downscale factor in (0, 1] (0.25 gives 185x125 pixels).
        preset: the camera of the focused images.

    Returns:
        a sample dict (`image` `(3,H,W)`, `focused` `(F,3,H,W)`, `camera`
        `CameraSettings`, `depth` `(1,H,W)` metres, `mask`, `dataset`, `id`).

    Example:
        >>> sample = motorcycle_sample(0.1)
        >>> sample["image"].shape, sample["focused"].shape
        (torch.Size([3, 50, 74]), torch.Size([2, 3, 50, 74]))
    """
    from optics import render_focal_stack

    from .synthetic import SYNTHETIC_PRESET

    preset = preset or SYNTHETIC_PRESET
    image, depth, mask = motorcycle_scene(scale)
    settings = preset.settings()
    with torch.no_grad():
        focused = render_focal_stack(image, depth, settings)[0].clamp(0, 1)
    return {"image": image[0], "focused": focused, "camera": settings, "depth": depth[0],
            "mask": mask[0], "dataset": "middlebury", "id": "motorcycle"}


LAYOUT = (
    "  <root>/<Scene>/im0.png, <root>/<Scene>/disp0.pfm, <root>/<Scene>/calib.txt\n"
    "  <root>/<split>.txt (optional list of scene folders)"
)

#: Name of the built-in scene (scikit-image's motorcycle), used when `root` is None.
BUILTIN_SCENE = "motorcycle"


#: The smallest plausible stereo baseline in millimetres; `calib.txt` states millimetres, so a
#: smaller value is most likely metres (0.193 for 193 mm) and would make every depth 1000x small.
MIN_BASELINE_MM = 1.0


def calib_entries(path: Path, expected: str) -> dict[str, str]:
    """The `key=value` lines of a `calib.txt`; a key given twice with different values is
    refused (which one holds would be a guess)."""
    entries: dict[str, str] = {}
    for line in read_text(path, "a Middlebury calib.txt").splitlines():
        if "=" not in line:
            continue
        key, value = (part.strip() for part in line.split("=", 1))
        if key in entries and entries[key] != value:
            raise DataFormatError(f"{str(path)!r}: {key} is given twice, as {entries[key]!r} and "
                                  f"{value!r}; {expected}")
        entries[key] = value
    return entries


def _number(text: str | None) -> float:
    try:
        return float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return math.nan


def read_calib(path: Path, size: tuple[int, int] | None = None) -> dict[str, float]:
    """Read a Middlebury 2014 `calib.txt`: focal length and disparity offset in pixels, baseline
    in metres (the file gives millimetres).

    Args:
        path: the `calib.txt`.
        size: `(H, W)` of the scene's image, checked against the file's `height`/`width` where
            it states them (else its focal length and `doffs` are pixels of another resolution).

    Raises:
        FileNotFoundError: the file is missing.
        DataFormatError: `cam0`, `doffs` or `baseline` is missing, malformed or given twice,
            the baseline is under `MIN_BASELINE_MM` (metres?), or `width`/`height` differ
            from `size`.
    """
    require_file(path, "a Middlebury calib.txt (cam0=[f 0 cx; ...], doffs=, baseline=)")
    expected = "expected lines cam0=[f 0 cx; 0 f cy; 0 0 1], doffs=<px> and baseline=<mm>"
    entries = calib_entries(path, expected)
    cam0 = [_number(v) for v in re.split(r"[\s;\[\]]+", entries.get("cam0", "")) if v]
    focal, doffs, baseline = (cam0 or [math.nan])[0], *(_number(entries.get(k)) for k in (
        "doffs", "baseline"))
    missing = [key for key in ("cam0", "doffs", "baseline") if key not in entries]
    hint = " (millimetres: is it metres?)" if baseline > 0 else ""
    image = f"the image is {size[0]}x{size[1]} pixels" if size else ""
    rules = [(not missing, f"could not read {', '.join(map(repr, missing))}"),
             (len(cam0) == 9, f"cam0 must hold the 9 entries of a 3x3 matrix, got {len(cam0)} "
                              f"({entries.get('cam0')!r})"),
             (math.isfinite(focal) and focal > 0, f"cam0 focal length must be finite and > 0, "
                                                  f"got {focal:g}"),
             (math.isfinite(baseline) and baseline > MIN_BASELINE_MM,
              f"baseline must be finite and > {MIN_BASELINE_MM:g} mm, got "
              f"{entries.get('baseline')}{hint}"),
             (math.isfinite(doffs), f"doffs must be a finite number of pixels, got "
                                    f"{entries.get('doffs')}")]
    rules += [(_number(entries[key]) == actual, f"states {key}={entries[key]} but {image}; its "
               "focal length and doffs are pixels at another resolution (resize the image and "
               "disparity back, or scale cam0, doffs, width and height with them)")
              for key, actual in zip(("height", "width"), size or (), strict=False) if key in entries]
    why = next((why for ok, why in rules if not ok), None)
    if why:
        raise DataFormatError(f"{str(path)!r}: {why}; {expected}")
    return {"focal_length_px": focal, "baseline_m": baseline * 1e-3, "doffs_px": doffs}


class Middlebury(DepthDataset):
    """Middlebury 2014 stereo scenes (left image, depth from disparity) with synthesised focus.

    Args:
        root: folder of scene folders, or None for the built-in motorcycle scene that ships with
            scikit-image (no download).
        split: `"all"` (every scene folder with a `calib.txt`) or the name of a list
            `<root>/<split>.txt`.
        preset: camera for focus synthesis (`datasets.presets.MIDDLEBURY` by default); its
            pixel pitch is replaced per scene by `preset.focal_length / f_px`.
        **kwargs: `size`, `crop`, `augment`, `cache_dir`, `aperture`,
            `render_kwargs`, `dtype` of `DepthDataset`.

    Raises:
        FileNotFoundError: `root`, the split list or a scene file is missing.
        DataFormatError: a truncated PFM, a malformed calib.txt, or image and disparity sizes
            differ.

    Example:
        >>> scene = Middlebury(None, size=(50, 74))[0]
        >>> scene["image"].shape, scene["focused"].shape, scene["id"]
        (torch.Size([3, 50, 74]), torch.Size([2, 3, 50, 74]), 'motorcycle')
    """

    name = "middlebury"

    def __init__(
        self,
        root: str | Path | None = None,
        split: str = "all",
        preset: CameraPreset = MIDDLEBURY,
        **kwargs: Any,
    ):
        super().__init__(preset, **kwargs)
        self.root = None if root is None else require_root(root, "Middlebury", LAYOUT)
        if self.root is None:
            self.scenes: list[Path | None] = [None]
            self.ids = [BUILTIN_SCENE]
            return
        if split == "all":
            self.scenes = sorted(p.parent for p in self.root.glob("*/calib.txt"))
            if not self.scenes:
                raise FileNotFoundError(
                    f"Middlebury: no scene folders with calib.txt in {str(self.root)!r}. "
                    f"Expected:\n{LAYOUT}"
                )
        else:
            listing = require_file(self.root / f"{split}.txt", "a list of scene folder names")
            self.scenes = [self.root / n for n in read_list(listing, "a scene list")]
        for scene in self.scenes:
            if not scene.is_dir():
                raise FileNotFoundError(f"Middlebury: no scene folder {str(scene)!r}"
                                        f"{'' if split == 'all' else f' (listed in {split}.txt)'}. "
                                        f"Expected:\n{LAYOUT}")
            for name in ("im0.png", "disp0.pfm", "calib.txt"):
                require_file(scene / name, f"the Middlebury scene file {name}")
        self.ids = [p.name for p in self.scenes]

    def load(self, index: int) -> dict[str, Any]:
        scene = self.scenes[index]
        if scene is None:
            data = load_motorcycle(self.dtype)
            image, depth, mask = data["image"][0], data["depth"][0], data["mask"][0]
            calib = data["calib"]
        else:
            image = read_photo(scene / "im0.png", dtype=self.dtype)[0]
            calib = read_calib(scene / "calib.txt", tuple(image.shape[-2:]))
            disparity = torch.from_numpy(read_pfm(scene / "disp0.pfm").copy()).to(self.dtype)
            require_one_size((scene / "im0.png", image), (scene / "disp0.pfm", disparity))
            depth, mask = disparity_to_depth(disparity, **calib)
            require_valid_depth(mask, repr(str(scene / "disp0.pfm")))
            depth, mask = depth[None], mask[None]
        camera = self.preset.settings(self.dtype)
        camera = camera.replace(pixel_pitch=torch.full_like(
            camera.pixel_pitch, self.preset.focal_length / calib["focal_length_px"]
        ))
        return {"image": image, "depth": depth, "mask": mask, "camera": camera}
