"""The pieces of `optics.calibrate`, one job per module.

| module | job |
|---|---|
| `pair` | `CalibrationPair`: a sharp reference, its defocused photo and the depth it shows |
| `measure` | each pair's own blur (`measure_blur`), the thin-lens curve through it, FFT blurs |
| `problem` | validating the arguments: the pairs, the PSF, the known and the fitted parameters |
| `start` | the initial guess, the margin left out and the FFT padding |
| `model` | the residuals of a camera in log-space parameters |
| `optimise` | Adam then L-BFGS, and the Gauss-Newton uncertainty |
| `result` | `CalibrationResult` |
| `blur_curve` | from photos with depth maps: the blur by depth, the thin lens with a floor |

The public API is `optics.calibrate` (and `optics.plotting.plot_calibration`); import from there.
"""
