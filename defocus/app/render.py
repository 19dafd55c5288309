"""The focus sweep figure of the real motorcycle scene (`defocus render`, and `defocus demo`)."""

from __future__ import annotations

from pathlib import Path

from optics import LENS_APERTURE

from .outputs import plan_files


def write_focus_sweep(out: Path, focus_distances=(2.2, 3.0, 4.0, 5.0), focal_length=0.085,
                      f_number=1.4, aperture=LENS_APERTURE, mode="scatter", scale=0.5,
                      overwrite: bool = False) -> Path:
    """Render the sweep (`datasets.middlebury.motorcycle_focus_sweep`) and save
    `out/focus_sweep.png` (`optics.plotting.plot_focus_sweep`) whole, replacing an earlier one
    only with `overwrite` (`defocus.app.outputs`); returns its path."""
    from datasets.middlebury import motorcycle_focus_sweep
    from optics.plotting import plot_focus_sweep

    plan, paths = plan_files(Path(out), {"focus_sweep.png": "focus sweep figure"}, overwrite)
    sweep = motorcycle_focus_sweep(focus_distances, focal_length, f_number, aperture, mode, scale)
    path = paths["focus_sweep.png"]
    with plan.writing() as write:
        write(path, lambda tmp: plot_focus_sweep(sweep["image"], sweep["depth"], sweep["renders"],
                                                 sweep["coc_px"], sweep["settings"], tmp))
    return path
