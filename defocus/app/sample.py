"""A small set of photos to try every command on (`defocus sample DIR`), photographed from the
embedded real Middlebury motorcycle scene (scikit-image; real depth 2.1-5.0 m from its
disparity) through a 50 mm f/1.8 full-frame camera by `datasets.capture.capture`: the
occlusion-aware renderer with a disk PSF, shot and read noise, 8-bit sRGB, small exposure and
white-balance differences and up to a pixel of misalignment between the shots."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

#: Focal length (m), f-number, sensor width (m) of the sample camera.
SAMPLE_LENS = (0.050, 1.8, 0.036)
#: Focus distance of each photo, metres: near, middle, far.
SAMPLE_FOCUS = {"near": 2.3, "middle": 3.1, "far": 4.6}
#: The depth range to state for the sample scene, metres.
SAMPLE_DEPTH_RANGE = (1.5, 8.0)


@dataclass
class SampleSet:
    """The files `write_sample_set` wrote (paths under its folder)."""

    folder: Path
    files: list[Path] = field(default_factory=list)


def write_sample_set(folder: Path, scale: float = 0.35, seed: int = 0) -> SampleSet:
    """Write `aif.png` (the all-in-focus photo), `near.png`, `middle.png`, `far.png` (photos
    focused at `SAMPLE_FOCUS`), `camera.json` (the camera of the near/far pair),
    `camera_stack.json` (of the three focused photos; each JSON names its photos under
    `"photos"`, so the folder is also a scene of `datasets.PhotoFolder`) and `depth.npy` (the
    true depth, metres) under `folder`; `scale` downsizes the 741x500 scene first.

    Example:
        >>> import tempfile
        >>> sample = write_sample_set(Path(tempfile.mkdtemp()), scale=0.1)
        >>> sorted(path.name for path in sample.files)[:3]
        ['aif.png', 'camera.json', 'camera_stack.json']
    """
    import numpy as np
    import torch

    from datasets.capture import capture
    from datasets.middlebury import motorcycle_scene
    from datasets.photos import save_photo
    from optics import LENS_APERTURE, CameraSettings

    focal_length, f_number, sensor_width = SAMPLE_LENS
    image, depth, _ = (t[0] for t in motorcycle_scene(scale))
    pitch = sensor_width / image.shape[-1]
    names = list(SAMPLE_FOCUS)
    stack = CameraSettings(focal_length, f_number, [SAMPLE_FOCUS[n] for n in names], pitch,
                           aperture=LENS_APERTURE)
    aif, focused = capture(image, depth, stack, np.random.default_rng(seed))
    folder.mkdir(parents=True, exist_ok=True)
    result = SampleSet(folder)
    result.files.append(save_photo(folder / "aif.png", aif))
    for name, photo in zip(names, focused, strict=True):
        result.files.append(save_photo(folder / f"{name}.png", photo))
    pair = stack.select_shots([0, 2])
    pair.to_json(folder / "camera.json", photos=["near.png", "far.png"])
    stack.to_json(folder / "camera_stack.json", photos=[f"{name}.png" for name in names])
    np.save(folder / "depth.npy", depth[0].to(torch.float32).numpy())
    result.files += [folder / "camera.json", folder / "camera_stack.json", folder / "depth.npy"]
    return result
