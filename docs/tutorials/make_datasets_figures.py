"""Make the pictures of the datasets tutorial (offline: scikit-image's motorcycle scene).

    .venv/bin/python docs/tutorials/make_datasets_figures.py

writes ``docs/tutorials/img/datasets_sample.png`` (one sample in the common format) and
``docs/tutorials/img/datasets_refocus.png`` (shift-and-add refocusing of a light field).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from kornia.color import linear_rgb_to_rgb  # noqa: E402

from datasets import LightFieldCalibration, Middlebury, refocus  # noqa: E402

OUT = Path(__file__).resolve().parent / "img"


def show(ax, image, title):
    ax.imshow(linear_rgb_to_rgb(image.clamp(0, 1)).permute(1, 2, 0).numpy())
    ax.set_title(title, fontsize=9)
    ax.axis("off")


def sample_figure() -> None:
    sample = Middlebury(None, size=(250, 370))[0]
    cam = sample["camera"]
    fig, axes = plt.subplots(1, 4, figsize=(13, 2.8), constrained_layout=True)
    show(axes[0], sample["image"], "image (all in focus)")
    depth = sample["depth"][0].masked_fill(~sample["mask"][0], float("nan"))
    im = axes[1].imshow(depth.numpy(), cmap="magma_r")
    axes[1].set_title("depth (m), unknown = white", fontsize=9)
    axes[1].axis("off")
    fig.colorbar(im, ax=axes[1], shrink=0.8)
    for i in range(2):
        show(axes[2 + i], sample["focused"][i],
             f"focused[{i}]: {1000 * float(cam['focal_length'][i]):.0f} mm, "
             f"f/{float(cam['f_number'][i]):.1f}, focus {float(cam['focus_distance'][i]):.1f} m")
    fig.savefig(OUT / "datasets_sample.png", dpi=72)
    plt.close(fig)


def synthetic_light_field(image, depth, calib, n_views=7):
    """Views of an image with depth by backward warping with its disparity (no occlusion)."""
    disparity = calib.disparity(depth)[0]  # (H,W) pixels per view step
    h, w = disparity.shape
    ys, xs = torch.meshgrid(torch.arange(h, dtype=image.dtype), torch.arange(w, dtype=image.dtype),
                            indexing="ij")
    c = n_views // 2
    views = torch.empty(n_views, n_views, 3, h, w)
    for s in range(n_views):
        for t in range(n_views):
            x = xs - disparity * (t - c)
            y = ys - disparity * (s - c)
            grid = torch.stack([2 * x / (w - 1) - 1, 2 * y / (h - 1) - 1], dim=-1)[None]
            views[s, t] = F.grid_sample(image[None], grid, align_corners=True,
                                        padding_mode="border")[0]
    return views


def refocus_figure() -> None:
    sample = Middlebury(None, size=(200, 296))[0]
    calib = LightFieldCalibration(baseline=8e-3, zero_disparity_distance=3.0)  # a wide array
    views = synthetic_light_field(sample["image"], sample["depth"], calib)
    near, far = (float(calib.disparity(torch.tensor(d))) for d in (2.3, 4.5))
    fig, axes = plt.subplots(1, 3, figsize=(10, 2.6), constrained_layout=True)
    show(axes[0], views[3, 3], "centre view (all in focus)")
    for ax, d, label in ((axes[1], near, "2.3 m"), (axes[2], far, "4.5 m")):
        show(ax, refocus(views, d, radius=3.0), f"refocused at d = {d:.2f} px/view ({label})")
    fig.savefig(OUT / "datasets_refocus.png", dpi=72)
    plt.close(fig)


if __name__ == "__main__":
    OUT.mkdir(parents=True, exist_ok=True)
    with torch.no_grad():
        sample_figure()
        refocus_figure()
    for path in sorted(OUT.glob("datasets_*.png")):
        print(f"wrote {path} ({path.stat().st_size // 1024} KB)")
