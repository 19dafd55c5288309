"""optics: differentiable thin-lens optics and per-pixel PSF rendering for PyTorch."""

from .alignment import align_shots, estimate_motion, estimate_shift, translate, undo_motion, warp
from .aperture import Aperture, Disk, Gaussian, Mask, Polygon
from .aperture_spec import APERTURE_FAMILIES, aperture_spec, parse_aperture
from .calibrate import (
    CalibrationError,
    CalibrationPair,
    CalibrationResult,
    DepthCalibration,
    calibrate,
    calibrate_from_depth,
    fit_thin_lens_curve,
    measure_blur,
)
from .camera import Camera, CameraSettings
from .focal_stack import render_focal_stack
from .lens import ThinLens
from .plotting import plot_calibration, plot_depth_calibration
from .raw import RawMetadata, RawReadError, read_raw, read_raw_metadata, read_raw_stack
from .render import DefocusRenderer, render_defocus
from .sensor import Sensor

__all__ = [
    "APERTURE_FAMILIES",
    "align_shots",
    "estimate_motion",
    "estimate_shift",
    "translate",
    "undo_motion",
    "warp",
    "CameraSettings",
    "aperture_spec",
    "parse_aperture",
    "render_focal_stack",
    "Aperture",
    "CalibrationError",
    "CalibrationPair",
    "CalibrationResult",
    "Camera",
    "DefocusRenderer",
    "Disk",
    "Gaussian",
    "Mask",
    "Polygon",
    "RawMetadata",
    "RawReadError",
    "Sensor",
    "ThinLens",
    "calibrate",
    "calibrate_from_depth",
    "DepthCalibration",
    "plot_depth_calibration",
    "fit_thin_lens_curve",
    "measure_blur",
    "plot_calibration",
    "read_raw",
    "read_raw_metadata",
    "read_raw_stack",
    "render_defocus",
]
