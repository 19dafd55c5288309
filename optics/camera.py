"""A camera: a lens, a sensor and an aperture shape, composed."""

from __future__ import annotations

from os import PathLike
from typing import TYPE_CHECKING, Any

from torch import Tensor, nn

from .aperture import Aperture, Gaussian
from .aperture_spec import aperture_spec
from .lens import ThinLens
from .sensor import Sensor

if TYPE_CHECKING:
    from .settings import CameraSettings


class Camera(nn.Module):
    """Thin lens + sensor + aperture: maps depth (metres) to CoC (pixels) and renders defocus.

    Args:
        lens: the `ThinLens` (focal length, f-number, focus distance in metres).
        sensor: the `Sensor` (pixel pitch in metres, downsampling).
        aperture: PSF shape; `Gaussian` (`sigma = 0.5 * CoC`) by default.

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

    def settings(self) -> CameraSettings:
        """This camera's settings as `CameraSettings` of one shot per batch item.

        Raises:
            ValueError: if the aperture has no spec string (a `Mask`).

        Example:
            >>> from optics import Disk
            >>> Camera(ThinLens(0.035, 2.8, 2.0), Sensor(5.6e-6), Disk()).settings().aperture
            'disk'
        """
        from .settings import CameraSettings

        return CameraSettings(
            self.lens.focal_length, self.lens.f_number, self.lens.focus_distance,
            self.sensor.effective_pixel_pitch, aperture=aperture_spec(self.aperture),
        )

    def to_json(self, path: str | PathLike, **extra: Any) -> None:
        """Write the camera's settings (metres), its PSF spec and any `extra` JSON values."""
        self.settings().to_json(path, **extra)

    @classmethod
    def from_json(cls, path: str | PathLike) -> Camera:
        """Load a camera written by `to_json` (or a calibration's JSON).

        Example:
            >>> import tempfile, pathlib
            >>> from optics import Disk
            >>> path = pathlib.Path(tempfile.mkdtemp()) / "camera.json"
            >>> Camera(ThinLens(0.035, 2.8, 2.0), Sensor(5.6e-6), Disk()).to_json(path)
            >>> Camera.from_json(path).lens.f_number
            tensor(2.8000, dtype=torch.float64)
        """
        from .settings import CameraSettings

        settings = CameraSettings.from_json(path)
        if settings.n_shots != 1:
            raise ValueError(f"{path}: holds {settings.n_shots} shots; read it with "
                             "CameraSettings.from_json and pick one with .shot(i)")
        return settings.shot(0)

    def coc_px(self, depth: Tensor) -> Tensor:
        """CoC diameter in (effective) pixels for depths in metres (same shape as `depth`).

        Computed in `depth`'s dtype promoted to at least float32 (a `float16`/`bfloat16` depth
        gives a float32 map, so every camera parameter gets a finite gradient); `render` casts
        it to the image's dtype.

        Raises:
            ValueError: if a lens or sensor value is no longer finite and > 0 (e.g. after an
                optimiser step), naming it, or `depth` is not > 0 or NaN.
        """
        return self.sensor.to_pixels(self.lens.coc_diameter(depth))

    def signed_coc_px(self, depth: Tensor) -> Tensor:
        """Signed CoC diameter in pixels: negative in front of the focus plane."""
        return self.sensor.to_pixels(self.lens.signed_coc_diameter(depth))

    def forward(self, depth: Tensor) -> Tensor:
        return self.coc_px(depth)

    def render(self, image: Tensor, depth: Tensor, **kwargs: Any) -> Tensor:
        """Render `image` `(B,C,H,W)` as this camera sees a scene of `depth` `(B,1,H,W)`.

        Keyword arguments go to `optics.render_defocus` (`mode`, `max_kernel_size`, ...).

        Raises:
            ValueError: for a NaN or infinite pixel in `image` (named, with its position), an
                invalid depth, or a camera value out of range (named).
        """
        from .render import render_defocus

        return render_defocus(image, self.coc_px(depth), psf=self.aperture, depth=depth, **kwargs)

