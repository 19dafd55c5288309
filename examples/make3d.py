"""Train and evaluate depth from defocus on Make3D (400 train / 134 test photos).

Data: the Make3D laser-depth archives (http://make3d.cs.cornell.edu/data.html): Train400Img,
Train400Depth, Test134Img, Test134Depth. The folder given as ``--root`` must hold::

    Train400Img/img-<name>.jpg     Train400Depth/depth_sph_corr-<name>.mat   (Position3DGrid)
    Test134Img/img-<name>.jpg      Test134Depth/depth_sph_corr-<name>.mat

Photos are resized to 460x345 by default (the common protocol; the pixel pitch follows);
evaluation caps depth at 70 m.

Training takes random crops (``crop``) of the full-resolution samples, after their focal
stacks were synthesised at 460x345 (cached: the blur in pixels stays the camera's); evaluation
runs on whole images.

The recipe is ``examples/make3d.yaml``; ``--set KEY=VALUE`` changes any of its keys or
of the `TrainConfig` fields (the options of ``defocus train``).

CPU (default; a 10-minute training budget, it prints the plan first)::

    python examples/make3d.py --root data/make3d

GPU, the paper's protocol (Gur & Wolf 2019: ResNet-50 + dense ASPP + attention network, Adam lr
2e-5, Gaussian PSF sigma = CoC/2, camera preset `datasets.presets.MAKE3D` (ours); here 256x256
crops, batch 8, 20000 steps)::

    python examples/make3d.py --root data/make3d --set device=cuda network=paper lr=2e-5 \\
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
