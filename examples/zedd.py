"""Score depth from defocus on ZEDD (real photos, LiDAR depth) with its own protocol.

Data: ZEDD of Zuo, Wen, Subramanian et al., "Zero-Shot Depth from Defocus" (2026): 100 real
scenes, 9 calibrated focus distances x 5 apertures and an f/16 all-in-focus photo, dense
depth. Download it from huggingface.co/datasets/venkatsubra/ZEDD (see the princeton-vl/FOSSA
readme) and give the folder as ``--root``::

    metadata.txt                                   run_<k> TAB <hex> TAB <focus distance m>
    val/val_0001/focus_stack/img_run_<k>_motor_<hex>_aperture_F<N.N>.jpg
    val/val_0001/gt/depth.npy, gt/K.txt            depth in metres, intrinsics in pixels
    test/...                                       no depth (scored by the benchmark server)

The default protocol reads five shots at f/2.8 (focus settings 0, 2, 4, 6, 8) and the f/16
photo as the all-in-focus image; the label-free sweep of ``defocus predict`` runs without
training, and the table (deltas 1.05, 1.15, 1.25, abs rel, ...) matches Table 2 of the paper
(the paper's numbers are on the test split, scored by the server).

CPU (default; 8 validation scenes at a 250k-pixel working resolution, about 10 minutes)::

    python examples/zedd.py --root data/ZEDD

GPU, the paper's protocol (every validation scene, 1.5-megapixel working resolution)::

    python examples/zedd.py --root data/ZEDD --device cuda --split val --f-number 2.8
"""

from __future__ import annotations

import sys

from datasets import ZEDD
from defocus.app import request_from
from defocus.app.experiment import ScriptRequest, run_benchmark_example
from defocus.commands.evaluate import benchmark_parser
from defocus.errors import script_errors


def main(argv: list[str] | None = None) -> int:
    parser = benchmark_parser("zedd", "val", __doc__.splitlines()[0])
    parser.add_argument("--f-number", type=float, default=2.8,
                        help="aperture of the focused shots (1.4, 2.0, 2.8, 4.0 or 5.6)")
    parser.add_argument("--shots", type=int, nargs="+", default=[0, 2, 4, 6, 8],
                        help="focus settings (0-8) of the focused shots")
    args = parser.parse_args(argv)
    dataset = ZEDD(args.root, args.split, shots=args.shots, f_number=args.f_number)
    with script_errors():
        run_benchmark_example("ZEDD", request_from(ScriptRequest, args), dataset, "zedd" if args.split == "val" else None, report=print)
    return 0


if __name__ == "__main__":
    sys.exit(main())
