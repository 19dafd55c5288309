"""Make the training tutorial's pictures from a finished ``defocus demo`` run.

Usage: ``python docs/tutorials/make_train_figures.py [runs/demo]``; writes
``docs/tutorials/img/train_loss.png`` and ``docs/tutorials/img/train_motorcycle.png``.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

HERE = Path(__file__).resolve().parent


def main(run: Path) -> None:
    out = HERE / "img"
    out.mkdir(exist_ok=True)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.2), constrained_layout=True)
    for ax, method, key, label in (
        (axes[0], "self_supervised", "loss", "self-supervised loss (no depth labels)"),
        (axes[1], "supervised", "loss", "supervised loss (mean |d - g| / g)"),
    ):
        with (run / method / "train_log.csv").open() as handle:
            rows = list(csv.DictReader(handle))
        ax.plot([int(r["step"]) for r in rows], [float(r[key]) for r in rows])
        ax.set_xlabel("step")
        ax.set_title(label, fontsize=10)
        ax.set_yscale("log")
    fig.savefig(out / "train_loss.png", dpi=80)
    plt.close(fig)
    # The demo's comparison figure at half resolution, pixel for pixel.
    image = plt.imread(run / "motorcycle_comparison.png")
    plt.imsave(out / "train_motorcycle.png", image[::2, ::2])
    print(f"wrote {out / 'train_loss.png'} and {out / 'train_motorcycle.png'}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("runs/demo"))
