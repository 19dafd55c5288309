"""A camera: a lens, a sensor and an aperture shape, composed."""

from __future__ import annotations

import json
from collections.abc import Mapping
from os import PathLike
from pathlib import Path
from typing import Any

import torch
from torch import Tensor, nn

from .aperture import Aperture, Disk, Gaussian, Polygon
from .lens import ThinLens
from .sensor import Sensor


class Camera(nn.Module):
    """Thin lens + sensor + aperture: maps depth (metres) to CoC (pixels) and renders defocus.

    Args:
        lens: the :class:`~optics.ThinLens` (focal length, f-number, focus distance in metres).
        sensor: the :class:`~optics.Sensor` (pixel pitch in metres, downsampling).
        aperture: PSF shape; :class:`~optics.Gaussian` (``sigma = 0.5 * CoC``) by default.

    Example:
        >>> camera = Camera(ThinLens(0.035, 2.8, 2.0), Sensor(5.6e-6, downsample=4))
        >>> camera.coc_px(torch.tensor([1.0, 2.0, 8.0]))
        tensor([9.9396, 0.0000, 7.4547])
    """

    def __init__(self, lens: ThinLens, sensor: Sensor, aperture: Aperture | None = None):
        super().__init__()
        for name, value, cls in (("lens", lens, ThinLens), ("sensor", sensor, Sensor)):
            if not isinstance(value, cls):
                raise TypeError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")
        if aperture is None:
            aperture = Gaussian()
        elif not isinstance(aperture, Aperture):
            raise TypeError(f"aperture must be an Aperture, got {type(aperture).__name__}")
        self.lens = lens
        self.sensor = sensor
        self.aperture = aperture

    #: Keys of :meth:`settings` / :meth:`from_settings`, each in metres except the f-number.
    SETTING_KEYS = ("focal_length", "f_number", "focus_distance", "pixel_pitch")

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], aperture: Aperture | None = None) -> Camera:
        """Build a camera from a dict of settings (the ``camera`` entry of a dataset sample).

        Args:
            settings: ``focal_length``, ``f_number``, ``focus_distance`` and ``pixel_pitch``
                (the *effective* pitch of the images, metres); floats, 0-d or ``(B,)`` tensors.
            aperture: PSF shape, :class:`~optics.Gaussian` by default.

        Example:
            >>> cam = Camera.from_settings({"focal_length": 0.035, "f_number": 2.8,
            ...                             "focus_distance": torch.tensor([2.0, 8.0]),
            ...                             "pixel_pitch": 22.4e-6})
            >>> cam.coc_px(torch.full((2, 1, 1, 1), 4.0)).flatten()
            tensor([4.9698, 2.4521])
        """
        missing = [k for k in cls.SETTING_KEYS if k not in settings]
        if missing:
            raise ValueError(
                f"settings is missing {missing}; expected the keys {list(cls.SETTING_KEYS)}"
            )
        lens = ThinLens(settings["focal_length"], settings["f_number"], settings["focus_distance"])
        return cls(lens, Sensor(settings["pixel_pitch"]), aperture)

    def settings(self) -> dict[str, Tensor]:
        """The camera's settings as a dict of tensors (inverse of :meth:`from_settings`)."""
        return {
            "focal_length": self.lens.focal_length,
            "f_number": self.lens.f_number,
            "focus_distance": self.lens.focus_distance,
            "pixel_pitch": self.sensor.effective_pixel_pitch,
        }

    def to_json(self, path: str | PathLike, **extra: Any) -> None:
        """Write :meth:`settings` (metres), the PSF shape and any ``extra`` JSON values to ``path``.

        Parameters of one value become numbers, ``(B,)`` ones lists. The PSF is written as
        ``{"family": "gaussian", "scale": s}``, ``{"family": "disk"}`` or
        ``{"family": "polygon", "n_blades": n, "rotation": r}`` (a ``Mask`` cannot be written).
        """
        data: dict[str, Any] = {}
        for key, value in self.settings().items():
            values = value.detach().cpu().reshape(-1).tolist()
            data[key] = values[0] if value.numel() == 1 else values
        data["psf"] = _aperture_to_dict(self.aperture)
        data.update(extra)
        Path(path).write_text(json.dumps(data, indent=2) + "\n")

    @classmethod
    def from_json(cls, path: str | PathLike) -> Camera:
        """Load a camera written by :meth:`to_json` (or a calibration's JSON).

        Example:
            >>> import tempfile, pathlib
            >>> path = pathlib.Path(tempfile.mkdtemp()) / "camera.json"
            >>> Camera(ThinLens(0.035, 2.8, 2.0), Sensor(5.6e-6), Disk()).to_json(path)
            >>> Camera.from_json(path).lens.f_number
            tensor(2.8000, dtype=torch.float64)
        """
        data = json.loads(Path(path).read_text())
        if not isinstance(data, dict):
            raise ValueError(f"{path}: expected a JSON object of camera settings")
        try:
            aperture = _aperture_from_dict(data.get("psf", {"family": "gaussian", "scale": 0.5}))
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"{path}: bad 'psf' entry {data.get('psf')!r}: {error}") from None
        settings = {
            k: torch.tensor(v, dtype=torch.float64) for k, v in data.items() if k in cls.SETTING_KEYS
        }
        return cls.from_settings(settings, aperture)

    def coc_px(self, depth: Tensor) -> Tensor:
        """CoC diameter in (effective) pixels for depths in metres (same shape as ``depth``)."""
        return self.sensor.to_pixels(self.lens.coc_diameter(depth))

    def signed_coc_px(self, depth: Tensor) -> Tensor:
        """Signed CoC diameter in pixels: negative in front of the focus plane."""
        return self.sensor.to_pixels(self.lens.signed_coc_diameter(depth))

    def forward(self, depth: Tensor) -> Tensor:
        return self.coc_px(depth)

    def render(self, image: Tensor, depth: Tensor, **kwargs: Any) -> Tensor:
        """Render ``image`` ``(B,C,H,W)`` as this camera sees a scene of ``depth`` ``(B,1,H,W)``.

        Keyword arguments go to :func:`optics.render_defocus` (``mode``, ``max_kernel_size``, ...).
        """
        from .render import render_defocus

        return render_defocus(image, self.coc_px(depth), psf=self.aperture, depth=depth, **kwargs)


def _aperture_to_dict(aperture: Aperture) -> dict[str, Any]:
    if isinstance(aperture, Gaussian):
        return {"family": "gaussian", "scale": float(aperture.scale.detach().reshape(-1)[0])}
    if isinstance(aperture, Polygon):
        return {"family": "polygon", "n_blades": aperture.n_blades, "rotation": aperture.rotation}
    if isinstance(aperture, Disk):
        return {"family": "disk"}
    raise ValueError(f"cannot write a {type(aperture).__name__} aperture to JSON")


def _aperture_from_dict(data: Mapping[str, Any]) -> Aperture:
    family = data["family"]
    if family == "gaussian":
        return Gaussian(float(data.get("scale", 0.5)))
    if family == "disk":
        return Disk()
    if family == "polygon":
        return Polygon(int(data["n_blades"]), float(data.get("rotation", 0.0)))
    raise ValueError(f"unknown PSF family {family!r}; expected gaussian, disk or polygon")
