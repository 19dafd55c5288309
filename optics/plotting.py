"""Figures of the optics package (focus sweeps, calibration fits), drawn on `matplotlib.figure.Figure` objects.

Nothing here touches pyplot or the matplotlib backend: every function builds its own `Figure`
(which renders with the Agg canvas when saved) and returns it, so it works in scripts, servers
and notebooks alike without changing global state. Show a figure in a notebook by leaving it as
a cell's value, or save it with `fig.savefig`.
"""

from __future__ import annotations

import math
from os import PathLike
from typing import TYPE_CHECKING

import torch
from torch import Tensor

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .calibration.blur_curve import DepthCalibration
    from .calibration.result import CalibrationResult
    from .camera import CameraSettings

__all__ = ["plot_calibration", "plot_depth_calibration", "plot_focus_sweep"]


def plot_calibration(result: CalibrationResult, path: str | PathLike | None = None) -> Figure:
    """Figure of a calibration: blur versus distance with the fitted thin-lens curve, and the
    residual map of each pair.

    Args:
        result: from `optics.calibrate`.
        path: where to save the figure (PNG, PDF, ...); not saved when `None`.

    Returns:
        the `matplotlib.figure.Figure` (not registered with pyplot: nothing to close).
    """
    from matplotlib.figure import Figure

    n = len(result.residuals)
    fig = Figure(figsize=(4.2 + 2.6 * n, 3.6), layout="constrained")
    axes = fig.subplots(1, n + 1, gridspec_kw={"width_ratios": [1.6] + [1] * n})
    _plot_blur_curve(axes[0], result)
    _plot_residuals(fig, list(axes[1:]), result)
    if path is not None:
        fig.savefig(path, dpi=100)
    return fig


def plot_depth_calibration(calibration: DepthCalibration,
                           path: str | PathLike | None = None) -> Figure:
    """Figure of a calibration from photos with depth: the blur measured in each depth bin
    (dot area: its pixels) and the fitted thin lens with its floor, against depth (log axis).

    Args:
        calibration: from `optics.calibrate_from_depth`.
        path: where to save the figure; not saved when `None`.

    Returns:
        the `matplotlib.figure.Figure`.
    """
    import matplotlib.ticker
    from matplotlib.figure import Figure

    curve, fit = calibration.curve, calibration.fit
    measured = curve.best_px()
    kept = ~measured.isnan()
    depth = curve.centres[kept]
    fig = Figure(figsize=(6.0, 3.8), layout="constrained")
    ax = fig.subplots()
    size = 200 * curve.pixels[kept] / curve.pixels[kept].max()
    ax.scatter(depth.numpy(), measured[kept].numpy(), s=size.numpy(), alpha=0.6,
               label="measured (area: pixels)")
    grid = torch.logspace(math.log10(float(depth.min()) / 1.2),
                          math.log10(float(depth.max()) * 1.2), 300, dtype=torch.float64)
    ax.plot(grid.numpy(), fit.blur_px(grid).numpy(), "k-",
            label=f"thin lens: focus {fit.focus_distance:.2f} m, floor {fit.floor_px:.2f} px")
    ax.axvline(fit.focus_distance, color="0.6", linestyle=":")
    ax.set_xscale("log")
    ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.set_xlabel("depth (m)")
    ax.set_ylabel(f"relative blur, {curve.aperture} CoC (px)")
    pitch = float(calibration.settings.pixel_pitch.reshape(-1)[0])
    ax.set_title(f"f/{float(calibration.settings.f_number.reshape(-1)[0]):g}, pitch "
                 f"{pitch * 1e6:.1f} um, rmse {fit.rmse_px:.2f} px", fontsize=10)
    ax.legend(fontsize=8)
    if path is not None:
        fig.savefig(path, dpi=100)
    return fig


def _plot_blur_curve(ax: Axes, result: CalibrationResult) -> None:
    """Each pair's own blur and the fitted thin-lens CoC against distance (log axis)."""
    import matplotlib.ticker

    values = result.values
    focus = values["focus_distance"]
    depths = result.depths
    lo, hi = min(depths + [focus]), max(depths)
    grid = torch.logspace(math.log10(lo / 1.5), math.log10(hi * 1.5), 200, dtype=torch.float64)
    with torch.no_grad():
        curve = result.camera().coc_px(grid)
    ax.plot(grid.numpy(), curve.numpy(), label="fitted thin lens")
    ax.plot(depths, result.measured_coc_px, "o", label="each pair's own blur")
    ax.axvline(focus, color="grey", ls=":", label="focus distance")
    ax.set_xscale("log")
    # Plain decimal ticks: distances span less than a decade, where 3x10^0-style labels collide.
    ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xticks(sorted(set(round(float(d), 2) for d in depths + [focus])))
    ax.set_xlabel("target distance (m)")
    ax.set_ylabel("CoC diameter (px)")
    ax.set_title(
        f"D_f = {focus:.3g} m, f/{values['f_number']:.3g}"
        + (f", scale {values['psf_scale']:.3g}" if result.psf == "gaussian" else "")
    )
    ax.legend(fontsize="small")


def _plot_residuals(fig: Figure, axes: list[Axes], result: CalibrationResult) -> None:
    """Each pair's residual map (channel mean) on one symmetric colour scale."""
    limit = max(float(r.abs().max()) for r in result.residuals)
    for ax, residual, name, depth in zip(
        axes, result.residuals, result.names, result.depths, strict=True
    ):
        image = ax.imshow(residual[0].mean(0).cpu().numpy(), cmap="RdBu", vmin=-limit, vmax=limit)
        ax.set_title(f"{name}: {depth:.3g} m", fontsize="small")
        ax.axis("off")
    fig.colorbar(image, ax=axes, shrink=0.8, label="residual")


def plot_focus_sweep(
    image: Tensor, depth: Tensor, renders: Tensor, coc_px: Tensor, settings: CameraSettings,
    path: str | PathLike | None = None,
) -> Figure:
    """A focus sweep: the scene and its depth, then each shot's render and CoC map.

    Args:
        image: all-in-focus image `(3,H,W)`, linear.
        depth: depth `(1,H,W)` in metres.
        renders: `(F,3,H,W)` renders, linear.
        coc_px: `(F,1,H,W)` CoC diameters in pixels.
        settings: the `(F,)` settings of the shots (titles).
        path: save the figure there when given.

    Returns:
        the `matplotlib.figure.Figure`.
    """
    from kornia.color import linear_rgb_to_rgb
    from matplotlib.figure import Figure

    def show_rgb(ax, linear: Tensor) -> None:
        ax.imshow(linear_rgb_to_rgb(linear.clamp(0, 1)).permute(1, 2, 0).cpu().numpy())
        ax.axis("off")

    n = renders.shape[0] + 1
    fig = Figure(figsize=(3.2 * n, 5.0), layout="constrained")
    axes = fig.subplots(2, n, squeeze=False)
    show_rgb(axes[0, 0], image)
    axes[0, 0].set_title("all in focus")
    im = axes[1, 0].imshow(depth[0].cpu().numpy(), cmap="magma_r")
    axes[1, 0].set_title("depth (m)")
    axes[1, 0].axis("off")
    fig.colorbar(im, ax=axes[1, 0], shrink=0.8)
    coc_max = float(coc_px.max())
    for i in range(1, n):
        show_rgb(axes[0, i], renders[i - 1])
        focus, f_number = float(settings.focus_distance[i - 1]), float(settings.f_number[i - 1])
        axes[0, i].set_title(f"focus {focus:g} m, f/{f_number:g}")
        im = axes[1, i].imshow(coc_px[i - 1, 0].cpu().numpy(), cmap="viridis", vmin=0,
                               vmax=coc_max)
        axes[1, i].set_title("CoC diameter (px)")
        axes[1, i].axis("off")
    fig.colorbar(im, ax=axes[1, 1:].tolist(), shrink=0.8)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig
