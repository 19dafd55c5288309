"""Calibrating a camera from photos: `calibrate` (pairs of a sharp reference and a defocused shot)
and `calibrate_from_depth` (photos with depth maps), one job per module.

| module | job |
|---|---|
| `fit` | `calibrate`: the camera that turns each sharp reference into its defocused photo |
| `pair` | `CalibrationPair`: a sharp reference, its defocused photo and the depth it shows |
| `measure` | each pair's own blur (`measure_blur`), the thin-lens curve through it, FFT blurs |
| `problem` | validating the arguments: the pairs, the PSF, the known and the fitted parameters |
| `start` | the initial guess, the margin left out and the FFT padding |
| `model` | the residuals of a camera in log-space parameters |
| `optimise` | Adam then L-BFGS, and the Gauss-Newton uncertainty |
| `result` | `CalibrationResult` |
| `blur_curve` | from photos with depth maps: the blur by depth, the thin lens with a floor |
| `side` | from photos with depth maps: does the lens tell near from far of the focus plane |

Everything public here is also in `optics`; the figures are `optics.plotting.plot_calibration`
and `optics.plotting.plot_depth_calibration`.
"""

from .blur_curve import (
    BlurCurve,
    BlurCurveFit,
    DepthCalibration,
    calibrate_from_depth,
    fit_blur_curve,
    measure_blur_curve,
)
from .fit import CalibrationError, calibrate
from .measure import fit_thin_lens_curve, measure_blur
from .pair import CalibrationPair
from .problem import PARAMETERS, PSF_FAMILIES
from .result import CalibrationResult
from .side import SideCues, mirror_bin_edges, side_cues

__all__ = [
    "PARAMETERS",
    "PSF_FAMILIES",
    "BlurCurve",
    "BlurCurveFit",
    "CalibrationError",
    "CalibrationPair",
    "CalibrationResult",
    "DepthCalibration",
    "SideCues",
    "calibrate",
    "calibrate_from_depth",
    "fit_blur_curve",
    "fit_thin_lens_curve",
    "measure_blur",
    "measure_blur_curve",
    "mirror_bin_edges",
    "side_cues",
]
