"""Train and evaluate depth from defocus on Make3D (400 train / 134 test photos).

Data: the Make3D laser-depth archives (http://make3d.cs.cornell.edu/data.html): Train400Img,
Train400Depth, Test134Img, Test134Depth. The folder given as ``--root`` must hold::

    Train400Img/img-<name>.jpg     Train400Depth/depth_sph_corr-<name>.mat   (Position3DGrid)
    Test134Img/img-<name>.jpg      Test134Depth/depth_sph_corr-<name>.mat

Photos are resized to 460x345 by default; evaluation caps depth at 70 m.

    python examples/make3d.py --root data/make3d --cache-dir cache/make3d
"""

from __future__ import annotations

import sys

from _common import build_parser, dataset_kwargs, train_and_evaluate

from datasets import JointAugment, Make3D


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(__doc__.splitlines()[0], "runs/make3d")
    parser.set_defaults(size=[460, 345])
    args = parser.parse_args(argv)
    kwargs = dataset_kwargs(args)
    train = Make3D(args.root, "train", augment=JointAugment(hflip=0.5, gain=0.1), **kwargs)
    test = Make3D(args.root, "test", **kwargs)
    train_and_evaluate("Make3D", args, train, test, depth_range=(1.0, 70.0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
