"""Make the pictures of the focus-pair section of the own-photos tutorial.

    .venv/bin/python docs/tutorials/make_focus_pair_figures.py

reads the real "breakfast" pair (Watanabe and Nayar 1998; ``../shared/data/real/breakfast``, or
the folder in ``$DEFOCUS_REAL_DATA``), runs the relative blur of ``estimate_depth`` on it exactly
as ``defocus predict --focused near.png far.png ... --linear`` does, and writes
``docs/tutorials/img/focus_pair_breakfast.png``: the two photos, the fused all-in-focus image and
the depth map with the regions the pair's README names.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from kornia.color import linear_rgb_to_rgb  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from datasets.photos import read_photo  # noqa: E402
from models.depth_from_photos import estimate_depth  # noqa: E402
from optics import CameraSettings  # noqa: E402

OUT = Path(__file__).resolve().parent / "img"
REAL = Path(os.environ.get("DEFOCUS_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))
#: rows y0:y1, columns x0:x1 of the regions the pair's README states
REGIONS = {"background": (10, 120, 20, 620), "bread": (200, 400, 50, 200),
           "cup": (180, 330, 280, 500), "table front": (440, 475, 20, 620)}


def main() -> int:
    folder = REAL / "breakfast"
    if not (folder / "breakfast_near.png").is_file():
        print(f"no real pair under {folder}: nothing drawn")
        return 1
    torch.set_num_threads(1)
    near, _ = read_photo(folder / "breakfast_near.png", encoding="linear")
    far, _ = read_photo(folder / "breakfast_far.png", encoding="linear")
    settings = CameraSettings(0.025, 8.3, [0.529, 0.869], 25e-6, aperture="disk")
    out = estimate_depth(torch.stack([near, far]), settings, (0.4, 1.5))
    depth = out["depth"][0].numpy()
    fig, axes = plt.subplots(1, 4, figsize=(13, 2.9))
    for ax, image, title in ((axes[0], near, "focused at 0.529 m"),
                             (axes[1], far, "focused at 0.869 m"),
                             (axes[2], out["all_in_focus"], "all in focus (fused)")):
        ax.imshow(linear_rgb_to_rgb(image.clamp(0, 1)).permute(1, 2, 0).numpy())
        ax.set_title(title, fontsize=9)
    shown = axes[3].imshow(depth, cmap="magma_r", vmin=0.4, vmax=1.5)
    axes[3].set_title("depth (m), relative blur", fontsize=9)
    for name, (y0, y1, x0, x1) in REGIONS.items():
        axes[3].add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, color="#3a9"))
        axes[3].text(x0 + 4, y0 + 18, f"{name} {np.median(depth[y0:y1, x0:x1]):.2f}",
                     color="white", fontsize=7)
    fig.colorbar(shown, ax=axes[3], fraction=0.04)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    path = OUT / "focus_pair_breakfast.png"
    fig.savefig(path, dpi=72)
    plt.close(fig)
    from PIL import Image

    Image.open(path).convert("RGB").quantize(256, dither=Image.Dither.NONE).save(path, optimize=True)
    print(f"wrote {path}; region medians: " + ", ".join(
        f"{name} {np.median(depth[y0:y1, x0:x1]):.2f} m" for name, (y0, y1, x0, x1)
        in REGIONS.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
