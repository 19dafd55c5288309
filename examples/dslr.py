"""Train and evaluate depth from defocus on real aperture pairs (DSLR set, Carvalho et al. 2018).

Data: the DSLR depth-from-defocus set of Carvalho et al., "Deep Depth from Defocus: how can
defocus blur improve 3D estimation using dense neural networks?" (ECCV workshops 2018), photos
at f/2.8 and f/8 with registered depth. The folder given as ``--root`` must hold::

    train/f2.8/<name>.png   train/f8/<name>.png   train/depth/<name>.png  (16-bit, millimetres)
    test/f2.8/...           test/f8/...           test/depth/...

The f/8 photo is the all-in-focus input, the f/2.8 photo the real focused image (35 mm, focus
about 1.7 m): no synthesis.

Training takes random crops (``--crop``) of the full-resolution samples (real photos: nothing is
synthesised or cached on disk); evaluation runs on whole images.

CPU (default; about 10 minutes on 2 cores, it prints the plan and ETA first)::

    python examples/dslr.py --root data/dslr

GPU, the paper's protocol (Gur & Wolf 2019: ResNet-50 + dense ASPP + attention network, Adam lr
2e-5, Gaussian PSF sigma = CoC/2, real f/2.8 and f/8 photos; here 256x256 crops, batch 8, 20000
steps)::

    python examples/dslr.py --root data/dslr --device cuda --network paper --lr 2e-5 \\
        --steps 20000 --crop 256 --batch-size 8
"""

from __future__ import annotations

import sys

from _common import build_parser, dataset_kwargs, run_example

from datasets import DSLR


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(__doc__.splitlines()[0], "runs/dslr")
    parser.add_argument("--depth-scale", type=float, default=1e-3,
                        help="metres per stored depth unit")
    args = parser.parse_args(argv)
    kwargs = dataset_kwargs(args)
    kwargs.pop("cache_dir")  # real focused images: nothing to cache
    run_example("DSLR", args, lambda split: DSLR(args.root, split, args.depth_scale, **kwargs),
                depth_range=(0.5, 10.0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
