"""Train and evaluate depth from defocus on Middlebury 2014 stereo scenes (depth from disparity).

Data: the Middlebury 2014 stereo set (https://vision.middlebury.edu/stereo/data/scenes2014/),
"perfect" calibration scenes. The folder given as ``--root`` must hold::

    <Scene>-perfect/im0.png  <Scene>-perfect/disp0.pfm  <Scene>-perfect/calib.txt
    train.txt, test.txt      (optional: scene folder names of each split)

Without ``train.txt``/``test.txt`` every scene is used for both. ``--root builtin`` uses the
motorcycle scene that ships with scikit-image (741x500, offline, no download). Training and
test are then the *same single scene*: the table shows whether the network recovers the
scene's depth from its defocus better than the best constant depth, not that it generalises.
Measured on 2 CPU cores (1 thread, load about 1): 300 steps in 9 min 10 s, abs rel 0.117
against 0.202 for the best constant depth (2.53 m).

Focused images are synthesised once per scene at full resolution (camera
`datasets.presets.MIDDLEBURY`, pitch set per scene so the lens keeps the scene's field of
view), cached, and training takes random crops of them: the blur in pixels stays the camera's.
Evaluation runs on whole images.

The recipe is ``examples/middlebury.yaml``; ``--set KEY=VALUE`` changes any of its keys or
of the `TrainConfig` fields (the options of ``defocus train``).

CPU (default; a 10-minute training budget, it prints the plan first)::

    python examples/middlebury.py --root builtin

GPU, the paper's protocol (Gur & Wolf 2019: ResNet-50 + dense ASPP + attention network, Adam
lr 2e-5, Gaussian PSF sigma = CoC/2; here 256x256 crops, batch 8, 20000 steps)::

    python examples/middlebury.py --root data/middlebury --set device=cuda network=paper lr=2e-5 \\
        steps=20000 crop=256 batch_size=8
"""

from __future__ import annotations

import sys
from pathlib import Path

from defocus.commands.train import recipe_main


def main(argv: list[str] | None = None) -> int:
    recipe_main(Path(__file__).with_suffix(".yaml"), argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
