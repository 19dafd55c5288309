"""Figures of the optics package, drawn on `matplotlib.figure.Figure` objects.

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

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .calibration.result import CalibrationResult

__all__ = ["plot_calibration"]


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
