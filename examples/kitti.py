"""Train and evaluate depth from defocus on KITTI (Eigen split, LiDAR depth).

Data: the KITTI raw data (https://www.cvlibs.net/datasets/kitti/raw_data.php, synced+rectified
drives) and the projected LiDAR depth maps of the KITTI depth benchmark ("annotated depth maps"),
plus Eigen split files (e.g. from monodepth2: ``splits/eigen/{train,test}_files.txt``, renamed to
``eigen_train_files.txt`` / ``eigen_test_files.txt``). The folder given as ``--root`` must hold::

    2011_09_26/2011_09_26_drive_0002_sync/image_02/data/0000000069.png
    2011_09_26/2011_09_26_drive_0002_sync/proj_depth/groundtruth/image_02/0000000069.png
    eigen_train_files.txt, eigen_test_files.txt

Sparse LiDAR depth is densified by nearest neighbour for focus synthesis and masked for
evaluation (Garg crop, 80 m cap).

Training takes random crops (``crop``) of the full-resolution samples, after their focal
stacks were synthesised at full resolution (cached: the blur in pixels stays the camera's);
evaluation runs on whole images.

The recipe is ``examples/kitti.yaml``; ``--set KEY=VALUE`` changes any of its keys or
of the `TrainConfig` fields (the options of ``defocus train``).

CPU (default; a 10-minute training budget, it prints the plan first)::

    python examples/kitti.py --root data/kitti

GPU, the paper's protocol (Gur & Wolf 2019: ResNet-50 + dense ASPP + attention network, Adam lr
2e-5, Gaussian PSF sigma = CoC/2, camera preset `datasets.presets.KITTI` (ours: the paper gives
none); here 256x256 crops, batch 8, 20000 steps)::

    python examples/kitti.py --root data/kitti --set device=cuda network=paper lr=2e-5 \\
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
