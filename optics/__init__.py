"""optics: differentiable thin-lens optics and per-pixel PSF rendering for PyTorch."""

from .aperture import Aperture, Disk, Gaussian, Mask, Polygon
from .camera import Camera
from .lens import ThinLens
from .render import DefocusRenderer, render_defocus
from .sensor import Sensor

__all__ = [
    "Aperture",
    "Camera",
    "DefocusRenderer",
    "Disk",
    "Gaussian",
    "Mask",
    "Polygon",
    "Sensor",
    "ThinLens",
    "render_defocus",
]
