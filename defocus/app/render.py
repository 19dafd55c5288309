"""The focus sweep figure of the real motorcycle scene (`defocus render`, and `defocus demo`)."""

from __future__ import annotations

from pathlib import Path

from optics import LENS_APERTURE

from .outputs import creating_folder, plan_files
from .sample import check_folder_name, check_scene_scale, render_problem


def write_focus_sweep(out: Path | str, focus_distances=(2.2, 3.0, 4.0, 5.0), focal_length=0.085,
                      f_number=1.4, aperture=LENS_APERTURE, mode="scatter", scale=0.5,
                      overwrite: bool = False) -> Path:
    """Render the sweep (`datasets.middlebury.motorcycle_focus_sweep`) and save
    `out/focus_sweep.png` (`optics.plotting.plot_focus_sweep`) whole, replacing an earlier one
    only with `overwrite` (`defocus.app.outputs`); returns its path.

    Raises:
        ValueError: an empty `out`, or a `scale` outside (0, 1] or so small that the scene
            would have no pixels (`defocus.app.sample.check_scene_scale`).
    """
    from datasets.middlebury import motorcycle_focus_sweep
    from optics.plotting import plot_focus_sweep

    out = check_folder_name(out, "--out", "runs/render")
    scale = check_scene_scale(scale, render_problem, what="renders")
    plan, paths = plan_files(out, {"focus_sweep.png": "focus sweep figure"}, overwrite)
    path = paths["focus_sweep.png"]
    with creating_folder(out, "--out"):
        sweep = motorcycle_focus_sweep(focus_distances, focal_length, f_number, aperture, mode,
                                       scale)
        with plan.writing() as write:
            write(path, lambda tmp: plot_focus_sweep(sweep["image"], sweep["depth"],
                                                     sweep["renders"], sweep["coc_px"],
                                                     sweep["settings"], tmp))
    return path
