"""optics: differentiable thin-lens optics and per-pixel PSF rendering for PyTorch."""

from .alignment import align_shots, estimate_motion, estimate_shift, translate, undo_motion, warp
from .aperture import Aperture, Disk, Gaussian, Mask, Polygon
from .aperture_spec import (
    APERTURE_FAMILIES,
    DEFAULT_APERTURE,
    LENS_APERTURE,
    aperture_spec,
    parse_aperture,
)
from .calibration import (
    CalibrationError,
    CalibrationPair,
    CalibrationResult,
    DepthCalibration,
    SideCues,
    calibrate,
    calibrate_from_depth,
    fit_thin_lens_curve,
    measure_blur,
    side_cues,
)
from .camera import Camera, CameraSettings
from .checks import checks_disabled, set_checks
from .collate import collate
from .focal_stack import render_focal_stack
from .learnable import LEARNABLE, LearnableCamera, LearnableMask, disk_mask
from .lens import ThinLens
from .plotting import plot_calibration, plot_depth_calibration
from .render import DefocusRenderer, render_defocus
from .sensor import Sensor, add_noise, noise_std, relative_light
from .tolerance import ROBUSTNESS, CameraTolerance

__all__ = [
    # the camera: lens, sensor, aperture, settings of a scene's shots
    "Camera",
    "CameraSettings",
    "Sensor",
    "add_noise",
    "noise_std",
    "relative_light",
    "ThinLens",
    "collate",
    # apertures (PSF shapes) and their spec strings
    "APERTURE_FAMILIES",
    "DEFAULT_APERTURE",
    "LENS_APERTURE",
    "Aperture",
    "Disk",
    "Gaussian",
    "Mask",
    "Polygon",
    "aperture_spec",
    "parse_aperture",
    # learned optics: focus distances, f-numbers and an aperture mask as parameters
    "LEARNABLE",
    "LearnableCamera",
    "LearnableMask",
    "disk_mask",
    # a camera as built: its focus, f-number and mask off their design by a tolerance
    "CameraTolerance",
    "ROBUSTNESS",
    # rendering
    "DefocusRenderer",
    "render_defocus",
    "render_focal_stack",
    # aligning shots
    "align_shots",
    "estimate_motion",
    "estimate_shift",
    "translate",
    "undo_motion",
    "warp",
    # the switch of the tensor checks (on by default)
    "checks_disabled",
    "set_checks",
    # calibration and its figures
    "CalibrationError",
    "CalibrationPair",
    "CalibrationResult",
    "DepthCalibration",
    "calibrate",
    "calibrate_from_depth",
    "fit_thin_lens_curve",
    "measure_blur",
    "SideCues",
    "side_cues",
    "plot_calibration",
    "plot_depth_calibration",
]
