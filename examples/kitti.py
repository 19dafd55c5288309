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

    python examples/kitti.py --root data/kitti --size 128 416 --cache-dir cache/kitti
"""

from __future__ import annotations

import sys

from _common import build_parser, dataset_kwargs, train_and_evaluate

from datasets import KITTI, JointAugment


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(__doc__.splitlines()[0], "runs/kitti")
    args = parser.parse_args(argv)
    kwargs = dataset_kwargs(args)
    train = KITTI(args.root, "train", augment=JointAugment(hflip=0.5, gain=0.1), **kwargs)
    test = KITTI(args.root, "test", **kwargs)
    train_and_evaluate("KITTI", args, train, test, depth_range=(1.0, 80.0), crop="garg")
    return 0


if __name__ == "__main__":
    sys.exit(main())
