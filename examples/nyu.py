"""Train and evaluate depth from defocus on NYU Depth v2 (795 train / 654 test frames).

Data: the labeled NYU Depth v2 set and its split, from the NYU Depth v2 page
(https://cs.nyu.edu/~silberman/datasets/nyu_depth_v2.html): ``nyu_depth_v2_labeled.mat`` and
``splits.mat``. The folder given as ``--root`` must hold::

    nyu_depth_v2_labeled.mat   (MATLAB v7.3 / HDF5: images, depths)
    splits.mat                 (trainNdxs, testNdxs)

Focused images are synthesised with the paper's camera (35 mm, f/2.8, focus 2 m and 8 m, pixel
pitch 5.6 um x 4 at 640x480); evaluation uses Eigen's crop and a 10 m cap.

Training takes random crops (``crop``) of the full-resolution samples, after their focal
stacks were synthesised at full resolution (cached: the blur in pixels stays the camera's);
evaluation runs on whole images.

The recipe is ``examples/nyu.yaml``; ``--set KEY=VALUE`` changes any of its keys or
of the `TrainConfig` fields (the options of ``defocus train``).

CPU (default; a 10-minute training budget, it prints the plan first)::

    python examples/nyu.py --root data/nyu

GPU, the paper's protocol (Gur & Wolf 2019: ResNet-50 + dense ASPP + attention network, Adam lr
2e-5, Gaussian PSF sigma = CoC/2, camera preset `datasets.presets.NYU`; here 256x256 crops,
batch 8, 20000 steps)::

    python examples/nyu.py --root data/nyu --set device=cuda network=paper lr=2e-5 \\
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
