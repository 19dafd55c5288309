"""Train and evaluate depth from defocus on NYU Depth v2 (795 train / 654 test frames).

Data: the labeled NYU Depth v2 set and its split, from the NYU Depth v2 page
(https://cs.nyu.edu/~silberman/datasets/nyu_depth_v2.html): ``nyu_depth_v2_labeled.mat`` and
``splits.mat``. The folder given as ``--root`` must hold::

    nyu_depth_v2_labeled.mat   (MATLAB v7.3 / HDF5: images, depths)
    splits.mat                 (trainNdxs, testNdxs)

Focused images are synthesised with the paper's camera (35 mm, f/2.8, focus 2 m and 8 m, pixel
pitch 5.6 um x 4 at 640x480); evaluation uses Eigen's crop and a 10 m cap.

    python examples/nyu.py --root data/nyu --size 240 320 --cache-dir cache/nyu
"""

from __future__ import annotations

import sys

from _common import build_parser, dataset_kwargs, train_and_evaluate

from datasets import JointAugment, NYUv2


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(__doc__.splitlines()[0], "runs/nyu")
    args = parser.parse_args(argv)
    kwargs = dataset_kwargs(args)
    train = NYUv2(args.root, "train", augment=JointAugment(hflip=0.5, gain=0.1), **kwargs)
    test = NYUv2(args.root, "test", **kwargs)
    train_and_evaluate("NYU Depth v2", args, train, test, depth_range=(0.5, 10.0), crop="eigen")
    return 0


if __name__ == "__main__":
    sys.exit(main())
