"""Figures of optics data (focus sweeps, calibration fits), built on `matplotlib.figure.Figure`.

No `pyplot` state and no backend switch: plotting from a notebook leaves its backend alone.
"""

from __future__ import annotations

from os import PathLike

from kornia.color import linear_rgb_to_rgb
from torch import Tensor

from .settings import CameraSettings


def plot_focus_sweep(
    image: Tensor, depth: Tensor, renders: Tensor, coc_px: Tensor, settings: CameraSettings,
    path: str | PathLike | None = None,
):
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
