"""Make the picture of the calibration tutorial's section on photos with depth.

    .venv/bin/python docs/tutorials/make_dslr_figures.py

reads the DFD-indoor training scenes (``../shared/data/real/dfd_indoor``, or the folder in
``$DEFOCUS_DSLR_DATA``), fits the camera on the first 61 of them by time (every third scene, as
``examples/dslr.py`` does; the last 20 stay for validation) exactly as
``defocus calibrate --data dslr --aperture gaussian`` does, and writes
``docs/tutorials/img/dslr_calibration.png``: the blur measured by depth and the fitted thin lens
with its floor.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from datasets import DSLR  # noqa: E402
from datasets.calibration import calibrate_dataset  # noqa: E402
from optics import plot_depth_calibration  # noqa: E402

DATA = Path(os.environ.get("DEFOCUS_DSLR_DATA", ROOT / ".." / "shared" / "data" / "real" /
                           "dfd_indoor"))


def main() -> int:
    if not DATA.is_dir():
        print(f"no DFD-indoor folder at {DATA}: set DEFOCUS_DSLR_DATA", file=sys.stderr)
        return 1
    train = DSLR(DATA, scenes=range(0, 61))
    fit = calibrate_dataset(train, range(0, 61, 3), aperture="gaussian:0.5", progress=True)
    out = ROOT / "docs" / "tutorials" / "img" / "dslr_calibration.png"
    plot_depth_calibration(fit, out)
    print(fit.settings.to_dict(), fit.extras())
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
