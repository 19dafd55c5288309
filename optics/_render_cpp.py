"""Optional compiled CPU kernel for the Gaussian scatter filter (filled in below)."""

from __future__ import annotations

from torch import Tensor


def usable(x: Tensor) -> bool:
    return False
