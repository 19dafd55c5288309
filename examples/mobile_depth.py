"""Depth from focus on the Mobile Depth stacks (phone photos, no ground truth: judged by eye).

Data: Mobile Depth of Suwajanakorn et al., "Depth from Focus with Your Mobile Phone" (CVPR
2015): 13 scenes filmed while the phone sweeps its focus. Download depth_from_focus_data3.zip
(the aligned frames) and, for the calibration, depth_from_focus_data2.zip from
supasorn.com/dffdownload.html, unzip both into one folder and give it as ``--root``::

    Aligned/Figure<N>/<scene>/a00.jpg, ...   aligned frames in capture order
    calibration/<name>/calibrated.txt        optional calibrated focus value per frame (relative)

(DFV's reorganised folders, ``<scene>/a00.jpg`` with ``<scene>/focus_dpth.txt``, read as well.)

The focus distances are not metric (the calibration recovers them up to an affine map of inverse
distance): they are spread over ``--focus-range``. No depth comes with the data, so nothing is
scored: the example prints each scene's depth range for a look at the maps.

CPU (default; 8 scenes, 5 frames each, a few minutes)::

    python examples/mobile_depth.py --root data/mobile_depth

GPU (every scene, every frame)::

    python examples/mobile_depth.py --root data/mobile_depth --device cuda --frames 0
"""

from __future__ import annotations

import sys

from datasets import MobileDepth
from defocus.app import request_from
from defocus.app.experiment import ScriptRequest, run_benchmark_example
from defocus.commands.evaluate import benchmark_parser
from defocus.errors import script_errors


def main(argv: list[str] | None = None) -> int:
    parser = benchmark_parser("mobile_depth", None, __doc__.splitlines()[0])
    parser.add_argument("--focus-range", type=float, nargs=2, metavar=("NEAR", "FAR"),
                        default=[0.1, 1.0], help="metres the frames' focus is spread over")
    parser.add_argument("--frames", type=int, default=5,
                        help="frames per scene, evenly spaced (0: all)")
    args = parser.parse_args(argv)
    dataset = MobileDepth(args.root, focus_range=tuple(args.focus_range),
                          n_shots=args.frames or None)
    with script_errors():
        run_benchmark_example("Mobile Depth", request_from(ScriptRequest, args), dataset, None, report=print)
    return 0


if __name__ == "__main__":
    sys.exit(main())
