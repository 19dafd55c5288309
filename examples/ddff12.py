"""Score depth from focus on DDFF-12 with its own protocol (disparity metrics and bumpiness).

Data: DDFF-12 of Hazirbas et al., "Deep Depth From Focus" (ACCV 2018): focal stacks of 10 slices
refocused from Lytro Illum light fields, with disparity from a registered depth sensor.
Download the HDF5 files listed on hazirbas.com/datasets/ddff12scene (also linked from the
soyers/ddff-pytorch readme) into the folder given as ``--root``::

    ddff-dataset-trainval.h5   stack_train, disp_train, stack_val, disp_val
    ddff-dataset-test.h5       stack_test (no disparity: scored by the benchmark server)

No network is trained: the label-free method of ``defocus predict`` reads each stack with the
thin-lens settings of its slices (``datasets.ddff12``), and the table is the paper's (MSE, RMS,
log RMS, abs rel, sq rel, deltas in %, bumpiness, all on disparity in pixels), comparable with
Table 2 of the paper.

CPU (default; 8 validation stacks at a 250k-pixel working resolution, a few minutes)::

    python examples/ddff12.py --root data/ddff12

GPU, the paper's protocol (every validation stack, full working resolution)::

    python examples/ddff12.py --root data/ddff12 --device cuda --split val
"""

from __future__ import annotations

import sys

from datasets import DDFF12
from defocus.app import request_from
from defocus.app.experiment import ScriptRequest, run_benchmark_example
from defocus.commands.evaluate import benchmark_parser
from defocus.errors import script_errors


def main(argv: list[str] | None = None) -> int:
    parser = benchmark_parser("ddff12", "val", __doc__.splitlines()[0])
    parser.add_argument("--shots", type=int, nargs="+", default=None,
                        help="slice indices to use (default: all 10; DFV uses 0 2 4 6 9)")
    args = parser.parse_args(argv)
    dataset = DDFF12(args.root, args.split, shots=args.shots)
    with script_errors():
        run_benchmark_example("DDFF-12", request_from(ScriptRequest, args), dataset, "ddff12", report=print)
    return 0


if __name__ == "__main__":
    sys.exit(main())
