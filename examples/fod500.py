"""Score depth from defocus on FoD500 (DefocusNet's renders) with the protocol of its tables.

Data: FoD500 of Maximov et al., "Focus on Defocus" (CVPR 2020): 500 Blender scenes, 5 renders
each focused at 0.1, 0.15, 0.3, 0.7 and 1.5 m (2.9 mm lens at f/1), with depth. Download the
folder linked from the dvl-tum/defocus-net readme (Google Drive) and give it as ``--root``::

    <6-digit scene>...All.tif   5 renders per scene (256x256)
    <6-digit scene>...Dpt.exr   depth in metres (OpenEXR)

Scenes 400-499 are the test split. No network is trained: the label-free method of ``defocus
predict`` reads each stack (the relative blur between the renders; the sweep where an
all-in-focus ``...Aif.tif`` render is present), and the table follows DFV's FoD500 evaluation
(Yang et al., CVPR 2022: depth clipped at 1.5 m, deltas in %, bumpiness).

CPU (default; 8 test scenes, a few minutes)::

    python examples/fod500.py --root data/fs_6

GPU, the paper's protocol (all 100 test scenes)::

    python examples/fod500.py --root data/fs_6 --device cuda --split test
"""

from __future__ import annotations

import sys

from datasets import FoD500
from defocus.app import request_from
from defocus.app.experiment import ScriptRequest, run_benchmark_example
from defocus.commands.evaluate import benchmark_parser
from defocus.errors import script_errors


def main(argv: list[str] | None = None) -> int:
    args = benchmark_parser("fod500", "test", __doc__.splitlines()[0]).parse_args(argv)
    with script_errors():
        run_benchmark_example("FoD500", request_from(ScriptRequest, args), FoD500(args.root, args.split), "fod500", report=print)
    return 0


if __name__ == "__main__":
    sys.exit(main())
