"""The depth head: a network's logits to metres between `depth_min` and `depth_max`, spaced in
depth or in inverse depth, or on a stated side of a single focus plane."""

from __future__ import annotations

import torch
from torch import Tensor, nn

#: How `DepthHead` spaces its output between `depth_min` and `depth_max`: evenly in depth, or
#: evenly in inverse depth (where the thin lens's blur is linear).
DEPTH_SPACINGS = ("depth", "inverse")
#: Which side of the focus plane `DepthHead` may put a blur that both sides explain: "both"
#: (no prior: the whole range), "beyond" or "before" the focus plane (a prior the user states).
SIDES = ("both", "beyond", "before")
#: With side "beyond": the share of the sigmoid's range spent on the far side, so that an
#: untrained network (sigmoid 0.5) starts beyond the focus plane.
BEYOND_SHARE = 0.8


class DepthHead(nn.Module):
    """Sigmoid output mapped to metres between `depth_min` and `depth_max`.

    `spacing="depth"`: `depth = depth_min + (depth_max - depth_min) * sigmoid(logits)`.
    `spacing="inverse"`: `1 / depth = 1 / depth_min - (1 / depth_min - 1 / depth_max) *
    sigmoid(logits)`, even in inverse depth, where the thin lens's blur is linear: a step of the
    logits changes the blur about as much anywhere in the range, and an untrained network starts
    at the harmonic middle of the range instead of far out where the blur hardly changes with
    depth (measured on the real DSLR pairs: the self-supervised network's abs rel 2.3 -> 0.63).

    One focus plane is ambiguous about its side: the blur of `1/d = 1/f - b` (beyond) equals
    that of `1/f + b` (before). With `side` and the `focus_distance` `f` the head resolves it
    (spaced evenly in inverse depth, i.e. in blur; `spacing` is then not used):

    - `"before"`: every depth in `[depth_min, f]`;
    - `"beyond"`: the blur `b` goes to the far side while the far side can explain it
      (`b <= 1/f - 1/depth_max`, the blur at the range's far end), and to the near side above
      that bound, which only a nearer depth explains (the physical tie-breaker; the rest is
      the prior). The first `BEYOND_SHARE` of the sigmoid's range is the far side.

    Example:
        >>> head = DepthHead(0.5, 10.0, spacing="inverse")
        >>> tuple(round(float(d), 3) for d in head(torch.tensor([-50.0, 0.0, 50.0])))
        (0.5, 0.952, 10.0)
        >>> beyond = DepthHead(0.5, 10.0, side="beyond", focus_distance=2.0)
        >>> tuple(round(float(d), 3) for d in beyond(torch.tensor([-50.0, 0.0, 1.3, 50.0])))
        (2.0, 4.0, 9.339, 0.5)
    """

    def __init__(self, depth_min: float, depth_max: float, spacing: str = "depth",
                 side: str = "both", focus_distance: float | None = None):
        super().__init__()
        for refused, message in (
            (not 0 < depth_min < depth_max, "depth_min and depth_max must satisfy 0 < depth_min "
             f"< depth_max metres, got {depth_min!r} and {depth_max!r}"),
            (spacing not in DEPTH_SPACINGS,
             f"spacing must be one of {DEPTH_SPACINGS}, got {spacing!r}"),
            (side not in SIDES, f"side must be one of {SIDES}, got {side!r}"),
            (side != "both" and not (focus_distance is not None
                                     and depth_min < focus_distance < depth_max),
             f"side {side!r} needs a focus_distance between depth_min {depth_min} and "
             f"depth_max {depth_max} metres, got {focus_distance!r}")):
            if refused:
                raise ValueError(message)
        self.depth_min, self.depth_max = float(depth_min), float(depth_max)
        self.spacing, self.side = spacing, side
        self.focus_distance = None if focus_distance is None else float(focus_distance)

    def forward(self, logits: Tensor) -> Tensor:
        near, far = 1 / self.depth_min, 1 / self.depth_max
        s = torch.sigmoid(logits)
        if self.side != "both":
            return 1 / self._sided_inverse(s, near, far)
        if self.spacing == "inverse":
            return 1 / (near - (near - far) * s)
        return self.depth_min + (self.depth_max - self.depth_min) * s

    def logits(self, depth: Tensor) -> Tensor:
        """The logits of `depth` metres, the inverse of `forward` for side "both" (within
        1e-3 of the sigmoid's ends: a depth at or past the range's ends has no finite logit)."""
        near, far = 1 / self.depth_min, 1 / self.depth_max
        s = (near - 1 / depth) / (near - far) if self.spacing == "inverse" else \
            (depth - self.depth_min) / (self.depth_max - self.depth_min)
        return torch.logit(s, eps=1e-3)

    def _sided_inverse(self, s: Tensor, near: float, far: float) -> Tensor:
        """Inverse depth of the sigmoid output `s` on the stated side of the focus plane."""
        focus = 1 / self.focus_distance
        if self.side == "before":
            return focus + (near - focus) * s
        bound = focus - far  # the largest blur the far side explains
        if near - focus <= bound:  # the near side explains nothing the far side does not
            return focus - bound * s
        share = BEYOND_SHARE
        beyond = focus - bound * (s / share).clamp(max=1)
        before = focus + bound + (near - focus - bound) * ((s - share) / (1 - share)).clamp(min=0)
        return torch.where(s <= share, beyond, before)

    def extra_repr(self) -> str:
        side = "" if self.side == "both" else \
            f", side={self.side!r}, focus_distance={self.focus_distance} m"
        return (f"depth_min={self.depth_min} m, depth_max={self.depth_max} m, "
                f"spacing={self.spacing!r}{side}")
