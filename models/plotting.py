"""Figures of depth predictions (input, focused images, depth, ground truth, error).

Built on `matplotlib.figure.Figure`: no `pyplot` state and no backend switch, so plotting from a
notebook leaves its backend alone.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
import torch.nn.functional as F
from kornia.color import linear_rgb_to_rgb
from torch import Tensor


def linear_to_srgb(linear: Tensor) -> Tensor:
    """Encode linear intensity in [0, 1] as sRGB for display."""
    return linear_rgb_to_rgb(linear.clamp(0, 1))


def figure_title(sample_id: object, step: int) -> str:
    """The title of a training figure: which sample it shows and after which step.

    Example:
        >>> figure_title("0-0", 50)
        'sample 0-0, step 50'
        >>> figure_title(None, 50)
        'step 50'
    """
    return f"step {step}" if sample_id in (None, "") else f"sample {sample_id}, step {step}"


def plot_prediction(
    path: str | Path, image: Tensor, depth: Tensor, focused: Tensor | None = None,
    target: Tensor | None = None, mask: Tensor | None = None, title: str = "",
    depth_range: tuple[float, float] | None = None, confidence: Tensor | None = None,
    image_label: str = "all in focus (input)", stated_range: tuple[float, float] | None = None,
    mirrored_depths: tuple[float, float] | None = None, focused_labels: list[str] | None = None,
    side: tuple[str, float] | None = None, off_side: Tensor | None = None,
) -> Path:
    """Save a figure of one prediction: all-in-focus input, focused images, predicted depth,
    its confidence, ground-truth depth and the relative error `|d - g| / g` (masked pixels
    grey); the panels whose data are given.

    Args:
        path: PNG file to write (folders are created).
        image: all-in-focus image `(3,H,W)`, linear.
        depth: predicted depth `(1,H,W)` metres.
        focused: optional focused images `(F,3,H,W)`.
        target: optional ground-truth depth `(1,H,W)` metres.
        mask: optional valid-depth mask `(1,H,W)`.
        title: figure title.
        depth_range: colour range of the depth maps in metres (default: that of the data; with
            `stated_range`, its 2nd-98th percentiles, `robust_range`).
        confidence: optional confidence `(1,H,W)` in [0, 1] (e.g. `SweepDepth`'s).
        image_label: the title of the all-in-focus panel (e.g. "all in focus (fused)").
        stated_range: the depth range the user stated, metres: marked on the depth colour bar
            (dashed lines where it falls inside the colours) and named in the panel's title.
        mirrored_depths: the depths `(nearest, farthest)` metres the photos cannot place on
            either side of their one focus plane (`models.depth_from_photos.ambiguous_depths`):
            hatched on the depth colour bar, the predicted depth's pixels within it hatched,
            the span named under the panel and, in a PNG, stored as its text
            `MIRRORED_DEPTHS_KEY` (`figure_mirrored_depths` reads it back).
        focused_labels: the title of each focused image's panel (e.g. its file name and focus
            distance); by default "focused image 1", ...
        side: the stated side of one focus plane, `("beyond" | "before", focus distance
            metres)` (`estimate_depth`'s `side`): named under the depth panel, with the pixels
            of `off_side` `(1,H,W)` bool (where the photos contradict it) hatched and counted;
            in a PNG, stored as its text `SIDE_KEY`.

    Returns:
        the path written.
    """
    import matplotlib
    from matplotlib.figure import Figure

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    depth = depth.detach().float().cpu()
    target = None if target is None else target.detach().float().cpu()
    panels = _prediction_panels(image, depth, focused, target, mask, confidence, image_label,
                                stated_range, focused_labels)
    if depth_range is None and stated_range is not None:
        depth_range = robust_range(depth)
    elif depth_range is None:
        values = [depth] + ([target] if target is not None else [])
        depth_range = (min(float(v.min()) for v in values), max(float(v.max()) for v in values))
    fig = Figure(figsize=(2.8 * len(panels), 2.8), layout="constrained")
    axes = fig.subplots(1, len(panels), squeeze=False)
    for ax, (name, data, kind) in zip(axes[0], panels, strict=True):
        data = _for_display(data, kind == "rgb")
        if kind == "rgb":
            ax.imshow(linear_to_srgb(data).permute(1, 2, 0).numpy())
        else:
            cmap = matplotlib.colormaps[{"depth": "magma_r", "confidence": "gray"}.get(kind,
                                                                                       "viridis")]
            cmap = cmap.with_extremes(bad="0.6")
            limits = {"depth": depth_range, "confidence": (0.0, 1.0)}.get(kind, (0.0, 0.5))
            shown = ax.imshow(data.numpy(), cmap=cmap, vmin=limits[0], vmax=limits[1])
            bar = fig.colorbar(shown, ax=ax, shrink=0.75)
            if kind == "depth" and stated_range is not None:
                _mark(bar, limits, stated_range)
            if name.startswith("predicted depth") and mirrored_depths is not None:
                _hatch_mirrored(ax, bar, data, limits, mirrored_depths)
            if name.startswith("predicted depth") and side is not None:
                _hatch_off_side(ax, side, off_side)
        ax.set_title(name, fontsize=9)
        _hide_axes(ax)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=90, metadata=_png_text(path, mirrored_depths, side, off_side))
    return path


def _prediction_panels(image: Tensor, depth: Tensor, focused: Tensor | None,
                       target: Tensor | None, mask: Tensor | None, confidence: Tensor | None,
                       image_label: str, stated_range: tuple[float, float] | None,
                       focused_labels: list[str] | None = None,
                       ) -> list[tuple[str, Tensor, str]]:
    """`(title, data, kind)` of each panel of `plot_prediction` (kind: `"rgb"`, `"depth"`,
    `"confidence"` or `"error"`), on the CPU."""
    panels: list[tuple[str, Tensor, str]] = [(image_label, image.detach().float().cpu(), "rgb")]
    if focused is not None:
        for i, f in enumerate(focused.detach().float().cpu()):
            label = f"focused image {i + 1}" if focused_labels is None else focused_labels[i]
            panels.append((label, f, "rgb"))
    stated = "" if stated_range is None else \
        f" (stated {stated_range[0]:g}-{stated_range[1]:g})"
    panels.append((f"predicted depth (m){stated}", depth[0], "depth"))
    if confidence is not None:
        panels.append(("confidence", confidence.detach().float().cpu()[0], "confidence"))
    if target is not None:
        valid = torch.ones_like(target, dtype=torch.bool) if mask is None else mask.cpu().bool()
        panels.append(("ground truth (m)", torch.where(valid, target, torch.nan)[0], "depth"))
        error = torch.where(valid, (depth - target).abs() / target, torch.nan)[0]
        panels.append(("abs rel error", error, "error"))
    return panels


#: The PNG text key under which `plot_prediction` stores the mirrored depths it hatched.
MIRRORED_DEPTHS_KEY = "Mirrored depths (m)"
#: Hatching (pattern, colour) of the depths that may lie on the other side of the focus plane.
_MIRROR_HATCH = ("//", "#2b8cbe")
#: The PNG text key under which `plot_prediction` stores the stated side: "SIDE FOCUS_M SHARE",
#: with SHARE the fraction of pixels whose blur contradicts it.
SIDE_KEY = "Stated side"


def figure_mirrored_depths(path: str | Path) -> tuple[float, float] | None:
    """The mirrored depths `(nearest, farthest)` metres a PNG of `plot_prediction` hatched, or
    None where it hatched none.

    Example:
        >>> import tempfile
        >>> path = plot_prediction(Path(tempfile.mkdtemp()) / "figure.png",
        ...                        torch.rand(3, 8, 8), torch.rand(1, 8, 8) + 1,
        ...                        mirrored_depths=(1.2, 1.8))
        >>> figure_mirrored_depths(path)
        (1.2, 1.8)
    """
    from PIL import Image

    with Image.open(path) as figure:
        text = getattr(figure, "text", {}).get(MIRRORED_DEPTHS_KEY)
    if text is None:
        return None
    near, far = (float(v) for v in text.split())
    return near, far


def _hatch_mirrored(ax, bar, depth: Tensor, limits: tuple[float, float],
                    span: tuple[float, float]) -> None:
    """Mark the depths of `span` (metres) that may lie mirrored across the focus plane: hatched
    on the colour bar (its part within `limits`), hatched over the pixels of `depth` within it,
    and named under the panel."""
    import matplotlib

    hatch, colour = _MIRROR_HATCH
    low, high = max(span[0], limits[0]), min(span[1], limits[1])
    inside = ((depth >= span[0]) & (depth <= span[1])).float().numpy()
    # the hatch colour is a setting read when a patch is made (matplotlib >= 3.7)
    with matplotlib.rc_context({"hatch.color": colour, "hatch.linewidth": 0.8}):
        if high > low:
            bar.ax.axhspan(low, high, facecolor="none", edgecolor=colour, linewidth=0,
                           hatch=hatch)
        if inside.any():
            ax.contourf(inside, levels=[0.5, 1.5], colors="none", hatches=[hatch])
    ax.set_xlabel(f"hatched: {span[0]:.2f}-{span[1]:.2f} m, may lie\nmirrored across the "
                  "focus plane", fontsize=7)


def _png_text(path: Path, mirrored_depths: tuple[float, float] | None,
              side: tuple[str, float] | None, off_side: Tensor | None) -> dict[str, str] | None:
    """The text a PNG of `plot_prediction` stores: `MIRRORED_DEPTHS_KEY`, `SIDE_KEY`."""
    text = {} if path.suffix.lower() != ".png" else {
        **({} if mirrored_depths is None else
           {MIRRORED_DEPTHS_KEY: f"{mirrored_depths[0]:.6g} {mirrored_depths[1]:.6g}"}),
        **({} if side is None else {SIDE_KEY: f"{side[0]} {side[1]:.6g} {_share(off_side):.6g}"})}
    return text or None


def _share(mask: Tensor | None) -> float:
    return 0.0 if mask is None or not mask.numel() else float(mask.float().mean())


def _hatch_off_side(ax, side: tuple[str, float], off_side: Tensor | None) -> None:
    """Name the stated side of the focus plane under the depth panel; hatch the pixels whose
    blur only the other side explains (`off_side`)."""
    import matplotlib

    from .depth_from_photos.side import OTHER_SIDE

    stated, focus = side
    other = OTHER_SIDE[stated]
    share = _share(off_side)
    if share:
        hatch, colour = _MIRROR_HATCH
        with matplotlib.rc_context({"hatch.color": colour, "hatch.linewidth": 0.8}):
            # at the panel's displayed size (`_for_display`), as the depth it covers
            shown = _for_display(off_side.detach().cpu()[0].float(), smooth=False)
            ax.contourf(shown.numpy(), levels=[0.5, 1.5],
                        colors="none", hatches=[hatch])
    ax.set_xlabel(f"stated: the scene lies {stated} {focus:.3g} m\n" + (
        f"hatched ({share:.1%}): blurred as only {other} it can be" if share else
        "no pixel contradicts it"), fontsize=7)


def _hide_axes(ax) -> None:
    """No ticks and no frame, but the axis label (a note under a panel) kept."""
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_visible(False)


def percentile_range(depth: Tensor, low: float = 2.0, high: float = 98.0) -> tuple[float, float]:
    """The `low`-th and `high`-th percentiles of the finite values of `depth` (equal for a
    flat map; `(nan, nan)` where no value is finite).

    Example:
        >>> tuple(round(v, 2) for v in percentile_range(torch.linspace(1.0, 3.0, 101)))
        (1.04, 2.96)
    """
    values = depth.detach().float().flatten()
    values = values[torch.isfinite(values)]
    if values.numel() == 0:
        return (math.nan, math.nan)
    a, b = (float(v) for v in torch.quantile(values[:: max(1, values.numel() // 1_000_000)],
                                             torch.tensor([low / 100, high / 100])))
    return a, b


def robust_range(depth: Tensor, low: float = 2.0, high: float = 98.0) -> tuple[float, float]:
    """A colour scale that follows the result, not its few extreme pixels (nor the stated
    range, which would show a 0.9-2 m answer in a 0.5-10 m range as one flat colour): the
    `percentile_range`, widened by 1 % about a flat map's one value.

    Example:
        >>> robust_range(torch.full((4, 4), 8.0))
        (7.92, 8.08)
    """
    a, b = percentile_range(depth, low, high)
    if math.isnan(a):
        return (0.0, 1.0)
    return (a, b) if b > a else (a - 0.01 * max(abs(a), 0.1), b + 0.01 * max(abs(b), 0.1))


def _mark(bar, limits: tuple[float, float], stated: tuple[float, float]) -> None:
    """Dashed lines on a colour bar at the ends of the stated range that fall inside it."""
    for value in stated:
        if limits[0] < value < limits[1]:
            bar.ax.axhline(value, color="#2b8cbe", linestyle="--", linewidth=1.2)


def save_depth_preview(path: str | Path, depth: Tensor,
                       limits: tuple[float, float] | None = None) -> Path:
    """Save depth `(H,W)` or `(1,H,W)` metres as a colour-mapped PNG to look at: the map at the
    photo's own pixels (near bright, far dark, as in the figures; colours over `limits`, by
    default `robust_range`; unknown, non-finite depth grey) with a colour scale in metres to its
    right (`PREVIEW_BAR_PX` pixels wide; the image at least `PREVIEW_MIN_HEIGHT` pixels high).
    The scale's ends are stored as the PNG's text `DEPTH_SCALE_KEY`. The metric depth is in
    `depth.npy` and the millimetre PNG.

    Example:
        >>> import tempfile
        >>> from PIL import Image
        >>> path = save_depth_preview(Path(tempfile.mkdtemp()) / "depth.png",
        ...                           torch.rand(1, 8, 8) + 1, (1.0, 2.0))
        >>> Image.open(path).text[DEPTH_SCALE_KEY]
        '1 2'
    """
    import matplotlib
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from PIL import Image, PngImagePlugin

    depth = depth.detach().float().cpu().reshape(depth.shape[-2:])
    low, high = limits or robust_range(depth)
    cmap = matplotlib.colormaps["magma_r"]
    scaled = ((depth - low) / max(high - low, 1e-12)).clamp(0, 1).numpy()
    h, w = scaled.shape
    width, height = w + PREVIEW_BAR_PX, max(h, PREVIEW_MIN_HEIGHT)
    # matplotlib draws the scale alone (a strip `PREVIEW_BAR_PX` wide); the map's pixels are
    # copied beside it as they are (a 12-megapixel map through its renderer takes seconds)
    fig = Figure(figsize=(PREVIEW_BAR_PX / 100, height / 100), dpi=100, facecolor="white")
    bar_axes = fig.add_axes((10 / PREVIEW_BAR_PX, 0.08, 14 / PREVIEW_BAR_PX, 0.84))
    bar = fig.colorbar(ScalarMappable(Normalize(low, high), cmap), cax=bar_axes)
    bar.ax.tick_params(labelsize=7)
    bar.set_label("depth (m)", fontsize=8)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    strip = np.asarray(canvas.buffer_rgba())[..., :3]
    rgb = np.full((height, width, 3), 255, dtype=np.uint8)
    rgb[:h, :w] = cmap(scaled, bytes=True)[..., :3]  # uint8: 3 bytes a pixel
    rgb[:h, :w][~np.isfinite(depth.numpy())] = 153
    rgb[:, w:] = strip[:height, :PREVIEW_BAR_PX]
    text = PngImagePlugin.PngInfo()
    text.add_text(DEPTH_SCALE_KEY, f"{low:.6g} {high:.6g}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgb).save(path, pnginfo=text, compress_level=PNG_COMPRESS_LEVEL)
    return path


#: Width (pixels) of the colour scale right of the map in `save_depth_preview`.
PREVIEW_BAR_PX = 90
#: Least height (pixels) of `save_depth_preview`'s image: room for the scale's labels.
PREVIEW_MIN_HEIGHT = 200
#: The PNG text key under which `save_depth_preview` stores its scale's ends, metres.
DEPTH_SCALE_KEY = "Depth scale (m)"
#: zlib level of the large PNGs `defocus predict` writes (12-megapixel maps): 1 writes several
#: times faster than the default 6, the files a little larger.
PNG_COMPRESS_LEVEL = 1


#: Longest side (pixels) of a panel's data: a figure panel shows a few hundred pixels, and a
#: 12-megapixel photo held at full size by matplotlib would cost gigabytes.
DISPLAY_PX = 1024


def _for_display(data: Tensor, smooth: bool) -> Tensor:
    """`data` `(3,H,W)` or `(H,W)` shrunk to at most `DISPLAY_PX` on its longer side (area
    averaged where `smooth`, else nearest, which keeps NaNs and sharp values)."""
    h, w = data.shape[-2:]
    if max(h, w) <= DISPLAY_PX:
        return data
    size = (max(1, round(h * DISPLAY_PX / max(h, w))), max(1, round(w * DISPLAY_PX / max(h, w))))
    batch = data[None] if data.dim() == 3 else data[None, None]
    small = F.interpolate(batch, size=size, mode="area" if smooth else "nearest")
    return small[0] if data.dim() == 3 else small[0, 0]


def plot_comparison(
    path: str | Path, sample: dict, predictions: dict[str, Tensor],
    depth_range: tuple[float, float],
) -> Path:
    """Save one figure comparing several methods on one scene: the input and the ground truth,
    then each method's depth (top row) and its abs rel error (bottom row; unknown depth grey).

    Args:
        path: PNG file to write.
        sample: a sample dict with `image` `(3,H,W)`, `depth` and `mask` `(1,H,W)`.
        predictions: method name -> depth `(1,H,W)` metres.
        depth_range: colour range of the depth maps in metres.
    """
    import matplotlib
    from matplotlib.figure import Figure

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    target, mask = sample["depth"][0], sample["mask"][0]
    n = len(predictions) + 1
    fig = Figure(figsize=(3.0 * n, 4.6), layout="constrained")
    axes = fig.subplots(2, n, squeeze=False)
    axes[0, 0].imshow(linear_to_srgb(sample["image"]).permute(1, 2, 0).numpy())
    axes[0, 0].set_title("all in focus", fontsize=9)
    cmap = matplotlib.colormaps["magma_r"].with_extremes(bad="0.6")
    shown = axes[1, 0].imshow(torch.where(mask, target, torch.nan).numpy(), cmap=cmap,
                              vmin=depth_range[0], vmax=depth_range[1])
    axes[1, 0].set_title("ground truth (m)", fontsize=9)
    fig.colorbar(shown, ax=axes[1, 0], shrink=0.8)
    errors = matplotlib.colormaps["viridis"].with_extremes(bad="0.6")
    for i, (name, depth) in enumerate(predictions.items(), start=1):
        d = depth.reshape(target.shape)
        im = axes[0, i].imshow(d.numpy(), cmap=cmap, vmin=depth_range[0], vmax=depth_range[1])
        axes[0, i].set_title(f"{name} (m)", fontsize=9)
        error = torch.where(mask, (d - target).abs() / target, torch.nan)
        err = axes[1, i].imshow(error.numpy(), vmin=0, vmax=0.5, cmap=errors)
        axes[1, i].set_title(f"abs rel error, mean {float(error.nanmean()):.3f}", fontsize=9)
    fig.colorbar(im, ax=axes[0, 1:].tolist(), shrink=0.8)
    fig.colorbar(err, ax=axes[1, 1:].tolist(), shrink=0.8)
    for ax in axes.flat:
        ax.axis("off")
    fig.savefig(path, dpi=100)
    return path
