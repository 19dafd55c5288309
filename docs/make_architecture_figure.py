"""Draw docs/img/architecture.png: the package layers and the path of data (architecture page).

Run from the repository root: `python docs/make_architecture_figure.py`. Uses
`matplotlib.figure.Figure` directly (no pyplot, no backend switch).
"""

from __future__ import annotations

from pathlib import Path

from matplotlib.figure import Figure
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

OUT = Path(__file__).resolve().parent / "img" / "architecture.png"

LAYER_COLOURS = {"defocus": "#f4d8c8", "models": "#d6e6f5", "datasets": "#dcefd8", "optics": "#ece3f5"}
STEP_COLOUR = "#ffffff"


def box(ax, x, y, w, h, text, colour, size=10, weight="normal", style="round,pad=0.02,rounding_size=0.08"):
    ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle=style, facecolor=colour, edgecolor="#444444",
                                linewidth=1.0))
    ax.text(x + w / 2, y + h / 2, text, ha="center", va="center", fontsize=size, weight=weight,
            linespacing=1.3)


def arrow(ax, start, end, colour="#333333", style="-|>", width=1.4, dashed=False, rad=0.0):
    ax.add_patch(FancyArrowPatch(start, end, arrowstyle=style, mutation_scale=14, color=colour,
                                 linewidth=width, linestyle="--" if dashed else "-",
                                 connectionstyle=f"arc3,rad={rad}", shrinkA=2, shrinkB=2))


def draw() -> Figure:
    fig = Figure(figsize=(15.4, 6.4), dpi=90)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(0, 15.4)
    ax.set_ylim(0, 6.4)
    ax.axis("off")

    # left: the layers (imports point down)
    ax.text(2.0, 6.1, "Layers (imports point down)", ha="center", fontsize=12, weight="bold")
    box(ax, 0.3, 4.75, 3.4, 1.05, "defocus\ncommands (parse, print) -> app\n(workflows, report callbacks);\n"
        "options, errors", LAYER_COLOURS["defocus"], size=9.5, weight="bold")
    box(ax, 0.3, 2.85, 1.45, 1.2, "models\nnetworks, training,\nevaluate, load_\ndepth_model,\n"
        "depth_from_photos", LAYER_COLOURS["models"], size=9)
    box(ax, 2.25, 2.85, 1.45, 1.2, "datasets\nloaders, synthetic\nscenes, focus,\nphoto files",
        LAYER_COLOURS["datasets"], size=9)
    box(ax, 0.3, 0.7, 3.4, 1.4, "optics\nThinLens, Sensor, apertures, Camera,\nCameraSettings, render/ "
        "(backends),\nphoto metadata + settings resolver,\ncalibration/, checks",
        LAYER_COLOURS["optics"], size=9)
    for x in (1.0, 3.0):
        arrow(ax, (x, 4.75), (x, 4.05))
        arrow(ax, (x, 2.85), (x, 2.1))
    arrow(ax, (2.0, 4.75), (2.0, 2.1), rad=0.0)
    ax.text(2.0, 0.28, "models and datasets never import each other;\na public module imports no "
            "private name", ha="center", fontsize=8.5, style="italic", color="#444444")

    # right: the path of data
    ax.text(6.8, 6.1, "Path of data (one training step)", ha="center", fontsize=12, weight="bold")
    steps = [
        ("camera settings\noptics.CameraSettings  (B, F)", "optics"),
        ("circle of confusion in pixels\nThinLens -> Sensor -> Camera.coc_px(depth)", "optics"),
        ("renderer\nrender_defocus(image, coc_px, psf)", "optics"),
        ("loss\nmodels.losses: rendered vs real focused photos", "models"),
        ("network\nmodels.networks: all-in-focus image -> depth", "models"),
    ]
    top, height, gap = 5.2, 0.72, 0.33
    for i, (text, layer) in enumerate(steps):
        y = top - i * (height + gap)
        box(ax, 4.5, y, 4.6, height, text, LAYER_COLOURS[layer], size=9.5)
        if i:
            arrow(ax, (6.8, y + height + gap), (6.8, y + height))
    # depth from the network feeds the CoC (the loop of self-supervision)
    y_net = top - 4 * (height + gap) + height / 2
    y_coc = top - 1 * (height + gap) + height / 2
    arrow(ax, (9.1, y_net), (9.1, y_coc), colour="#1f5fa8", rad=0.45, dashed=True)
    ax.text(10.2, (y_net + y_coc) / 2, "predicted\ndepth", ha="center", va="center", fontsize=8.5,
            color="#1f5fa8")
    ax.text(6.8, 0.28, "gradients flow back from the loss through the renderer and the CoC\n"
            "to the network (and to the camera parameters when calibrating)", ha="center", fontsize=8.5, style="italic",
            color="#444444")

    # far right: depth from photos (what `defocus predict` runs)
    ax.text(12.95, 6.1, "Depth from photos (predict)", ha="center", fontsize=12, weight="bold")
    steps = [
        "photos + CameraSettings\n(options, --camera JSON or EXIF)",
        "estimate_depth(method=\"auto\")\npicks a method by the photos",
        "working resolution, aligned shots\ndepth_from_photos.resolution",
        "cost per candidate depth\nsweep: thin-lens blur vs photo",
        "aggregate, select, smooth\nthin_lens, semi_global, smoothing",
    ]
    for i, text in enumerate(steps):
        y = top - i * (height + gap)
        box(ax, 10.75, y, 4.4, height, text, LAYER_COLOURS["models"], size=9.5)
        if i:
            arrow(ax, (12.95, y + height + gap), (12.95, y + height))
    ax.text(12.95, 0.28, "models.depth_from_photos: no network, no training;\n"
            "each method a small class with one call signature", ha="center", fontsize=8.5,
            style="italic", color="#444444")
    return fig


def main() -> None:
    OUT.parent.mkdir(parents=True, exist_ok=True)
    draw().savefig(OUT, dpi=90, metadata={"Software": None})
    print(f"wrote {OUT} ({OUT.stat().st_size // 1024} KiB)")


if __name__ == "__main__":
    main()
