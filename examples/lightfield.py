"""Train depth from defocus on Lytro light fields, refocused for real by shift-and-add.

Data: Lytro Illum light fields such as the Flowers set of Srinivasan et al., "Learning to
Synthesize a 4D RGBD Light Field from a Single Image" (ICCV 2017), stored as 14x14 sub-aperture
mosaics (``*_eslf.png``, micro-lens interleaved). The folder given as ``--root`` must hold::

    <name>.png                     one mosaic per light field
    train.txt, test.txt            the mosaic file names of each split, one per line

The centre view is the all-in-focus image; focused images average the central views under a
circular aperture at two disparities. Light fields carry no depth, so the table reports the
self-supervised reconstruction losses on the test set.

Training takes random crops (``--crop``) of the full-resolution samples (real refocusing:
nothing is synthesised or cached on disk); evaluation runs on whole images.

CPU (default; about 10 minutes on 2 cores, it prints the plan and ETA first)::

    python examples/lightfield.py --root data/flowers

GPU, the paper's protocol (Gur & Wolf 2019: ResNet-50 + dense ASPP + attention network, Adam lr
2e-5, Gaussian PSF sigma = CoC/2, real refocused views; here 256x256 crops, batch 8, 20000
steps)::

    python examples/lightfield.py --root data/flowers --device cuda --network paper --lr 2e-5 \\
        --steps 20000 --crop 256 --batch-size 8
"""

from __future__ import annotations

import sys

from datasets import LightField
from defocus.app.experiment import run_example
from defocus.options import dataset_kwargs, example_parser


def main(argv: list[str] | None = None) -> int:
    parser = example_parser(__doc__.splitlines()[0], "runs/lightfield")
    parser.add_argument("--layout", choices=["interleaved", "tiled"], default="interleaved",
                        help="mosaic layout")
    parser.add_argument("--n-views", type=int, default=14, help="views per side in the mosaic")
    parser.add_argument("--radius", type=float, default=3.0, help="aperture radius, view steps")
    parser.add_argument("--focus-disparities", type=float, nargs="+", default=[-0.5, 0.5],
                        help="refocus disparities, pixels per view step")
    args = parser.parse_args(argv)
    kwargs = dataset_kwargs(args)
    kwargs.pop("cache_dir")  # real refocusing: nothing to cache
    lf = {"n_views": args.n_views, "layout": args.layout, "radius": args.radius,
          "focus_disparities": args.focus_disparities, **kwargs}
    run_example("Light fields", args, lambda split: LightField(args.root, split, **lf),
                depth_range=(0.5, 10.0), has_depth=False, report=print)
    return 0


if __name__ == "__main__":
    sys.exit(main())
