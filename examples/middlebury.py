"""Train and evaluate depth from defocus on Middlebury 2014 stereo scenes (depth from disparity).

Data: the Middlebury 2014 stereo set (https://vision.middlebury.edu/stereo/data/scenes2014/),
"perfect" calibration scenes. The folder given as ``--root`` must hold::

    <Scene>-perfect/im0.png  <Scene>-perfect/disp0.pfm  <Scene>-perfect/calib.txt
    train.txt, test.txt      (optional: scene folder names of each split)

Without ``train.txt``/``test.txt`` every scene is used for both. ``--root builtin`` uses the
motorcycle scene that ships with scikit-image (offline, no download).

    python examples/middlebury.py --root builtin --size 125 185 --steps 300
"""

from __future__ import annotations

import sys

from _common import build_parser, dataset_kwargs, train_and_evaluate

from datasets import JointAugment, Middlebury


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(__doc__.splitlines()[0], "runs/middlebury")
    args = parser.parse_args(argv)
    kwargs = dataset_kwargs(args)
    root = None if str(args.root) == "builtin" else args.root
    splits = ("all", "all") if root is None or not (root / "train.txt").is_file() else (
        "train", "test")
    train = Middlebury(root, splits[0], augment=JointAugment(hflip=0.5, gain=0.1), **kwargs)
    test = Middlebury(root, splits[1], **kwargs)
    train_and_evaluate("Middlebury", args, train, test, depth_range=(0.5, 10.0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
