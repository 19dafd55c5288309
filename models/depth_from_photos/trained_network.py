"""A network trained for one camera (`defocus train`) as a method of `estimate_depth`.

Such a network has learnt the blur of its training camera at its training resolution, so it runs
on the photos as they are (no working resolution) and answers depth within the range it was
trained for.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor, nn

from optics import Aperture, CameraSettings
from optics.camera import SETTING_FIELDS

from .tiling import check_tiling, run_network

#: Relative difference below which two camera values count as the same (`camera_mismatch`).
CAMERA_TOLERANCE = 0.02


def camera_record(settings: CameraSettings) -> dict[str, list[float]]:
    """The camera of `settings` as plain data for a checkpoint: each of focal length, f-number,
    focus distance and pixel pitch as a list of floats, one per shot (`(F,)`; the first of a
    batch).

    Example:
        >>> camera_record(CameraSettings(0.05, 1.4, [2.0, 6.0], 1e-5))["focus_distance"]
        [2.0, 6.0]
    """
    values = [getattr(settings, name) for name in SETTING_FIELDS]
    values = torch.broadcast_tensors(*values)
    return {name: [float(v) for v in (value[0] if value.ndim > 1 else value).reshape(-1)]
            for name, value in zip(SETTING_FIELDS, values, strict=True)}


def describe_camera(record: Mapping[str, Sequence[float]]) -> str:
    """A camera of `camera_record` in a few words: f-number, focus distances, focal length and
    pixel pitch.

    Example:
        >>> describe_camera(camera_record(CameraSettings(0.05, 1.4, [2.0, 6.0], 1.8e-4)))
        'f/1.4 focused at 2, 6 m (focal length 50 mm, pixel pitch 180 um)'
    """
    def values(name: str, scale: float = 1.0) -> str:
        return "/".join(dict.fromkeys(f"{v * scale:.3g}" for v in record[name]))

    focus = ", ".join(f"{v:.3g}" for v in record["focus_distance"])
    return (f"f/{values('f_number')} focused at {focus} m (focal length "
            f"{values('focal_length', 1e3)} mm, pixel pitch {values('pixel_pitch', 1e6)} um)")


def camera_mismatch(trained: Mapping[str, Sequence[float]] | None, settings: CameraSettings,
                    tolerance: float = CAMERA_TOLERANCE) -> str | None:
    """One line saying that the photos' camera `settings` is not the camera `trained` (a
    `camera_record`) that a network was trained for, naming both and what to do; None where
    they agree within `tolerance` (relative) or the training camera is unknown.

    Example:
        >>> trained = camera_record(CameraSettings(0.05, 1.4, [2.0, 6.0], 1.8e-4))
        >>> camera_mismatch(trained, CameraSettings(0.05, 1.4, [2.01, 6.0], 1.8e-4)) is None
        True
        >>> camera_mismatch(trained, CameraSettings(0.05, 1.8, [2.3, 4.6], 1.8e-4))[:60]
        'the photos were taken with f/1.8 focused at 2.3, 4.6 m (foca'
    """
    if not trained or any(name not in trained for name in SETTING_FIELDS):
        return None
    photos = camera_record(settings)
    same = all(len(trained[name]) == len(photos[name]) and all(
        abs(a - b) <= tolerance * max(abs(a), abs(b)) for a, b in zip(trained[name],
                                                                      photos[name], strict=True))
        for name in SETTING_FIELDS)
    if same:
        return None
    return (f"the photos were taken with {describe_camera(photos)} but the network was trained "
            f"for {describe_camera(trained)}: its depth is likely wrong; run without a model "
            "file (the label-free methods work with any camera) or train one for this camera "
            "with `defocus train`")


class TrainedNetwork(nn.Module):
    """A depth network of `defocus train` (`models.loading.load_depth_model`), called like every
    method of `estimate_depth`.

    Args:
        network: the trained network (`models.networks.build_network`), called as
            `network(image, focused, settings)`, depth `(B,1,H,W)` metres.
        input_mode: its input mode, `"aif"` (the all-in-focus photo only) or `"aif+focused"`.
        n_focus: focused photos the network reads in `"aif+focused"` mode.
        depth_range: `(near, far)` metres the network was trained for.
        max_pixels: photos up to this many pixels go through whole; larger ones in tiles of
            `tile` pixels square with `overlap` pixels of context (memory stays bounded; the
            networks' group normalisation sees each tile's statistics, so seams may show).
        tile: side of a tile's kept centre, pixels.
        overlap: context around each tile, pixels.
        camera: the camera it was trained for (`camera_record`), None where unknown.
        aperture: the mask it learned with its camera (`TrainConfig.learn_optics`), which a
            network that reads the sweep (`TrainConfig.sweep_inputs`) renders it through;
            None: the settings' PSF.

    Example:
        >>> import torch
        >>> from models.networks import build_network
        >>> model = TrainedNetwork(build_network("small", "aif", 0, 1.0, 10.0, width=4), "aif", 0,
        ...                        (1.0, 10.0))
        >>> model(torch.zeros(1, 3, 4, 4), None, None, 1.0, 10.0)["depth"].shape
        torch.Size([1, 1, 4, 4])
    """

    #: It runs on the photos at their own resolution.
    native_resolution = True
    #: It needs an all-in-focus photo.
    needs_image = True

    def __init__(self, network: nn.Module, input_mode: str, n_focus: int,
                 depth_range: tuple[float, float], max_pixels: int = 2_000_000,
                 tile: int = 1024, overlap: int = 64,
                 camera: Mapping[str, Sequence[float]] | None = None,
                 aperture: Aperture | None = None):
        super().__init__()
        check_tiling(tile, overlap)
        self.max_pixels, self.tile, self.overlap = int(max_pixels), int(tile), int(overlap)
        self.network, self.input_mode, self.n_focus = network, input_mode, int(n_focus)
        self.depth_range = (float(depth_range[0]), float(depth_range[1]))
        self.camera = None if camera is None else {k: list(v) for k, v in camera.items()}
        self.aperture = aperture

    def forward(self, image: Tensor, focused: Tensor | None, settings: CameraSettings | None,
                near: float, far: float) -> dict[str, Tensor]:
        """Depth `(B,1,H,W)` metres of the all-in-focus `image` `(B,3,H,W)` and, in
        `"aif+focused"` mode, the `n_focus` `focused` photos `(B,F,3,H,W)` with their settings
        (the caller gives what the network reads); `near` and `far` are not used (the network
        answers within its trained range)."""
        return {"depth": run_network(self.network, image, focused, settings, self.max_pixels,
                                     self.tile, self.overlap, self.aperture)}
