"""Train depth from defocus on Lytro light fields, refocused for real by shift-and-add.

Data: Lytro Illum light fields such as the Flowers set of Srinivasan et al., "Learning to
Synthesize a 4D RGBD Light Field from a Single Image" (ICCV 2017), stored as 14x14 sub-aperture
mosaics (``*_eslf.png``, micro-lens interleaved). The folder given as ``--root`` must hold::

    <name>.png                     one mosaic per light field
    train.txt, test.txt            the mosaic file names of each split, one per line

The centre view is the all-in-focus image; focused images average the central views under a
circular aperture at two disparities. Light fields carry no depth, so the table reports the
self-supervised reconstruction losses on the test set.

Training takes random crops (``crop``) of the full-resolution samples (real refocusing:
nothing is synthesised or cached on disk); evaluation runs on whole images.

The recipe is ``examples/lightfield.yaml``; ``--set KEY=VALUE`` changes any of its keys or
of the `TrainConfig` fields (the options of ``defocus train``).

CPU (default; a 10-minute training budget, it prints the plan first)::

    python examples/lightfield.py --root data/flowers

GPU, the paper's protocol (Gur & Wolf 2019: ResNet-50 + dense ASPP + attention network, Adam lr
2e-5, Gaussian PSF sigma = CoC/2, real refocused views; here 256x256 crops, batch 8, 20000
steps)::

    python examples/lightfield.py --root data/flowers --set device=cuda network=paper lr=2e-5 \\
        steps=20000 crop=256 batch_size=8
"""

from __future__ import annotations

import sys
from pathlib import Path

from defocus.commands.train import recipe_main


def main(argv: list[str] | None = None) -> int:
    recipe_main(Path(__file__).with_suffix(".yaml"), argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
