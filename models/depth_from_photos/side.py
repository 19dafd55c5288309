"""A stated side of one focus plane: where every shot is focused at one distance, a depth and
its mirror image across the focus plane (`1/d' = 2/f - 1/d`) blur every shot alike, and a
statement of where the scene lies (`estimate_depth`'s `side`) picks one of the two.

With `"beyond"` (a photographer who focused on the nearest thing) or `"before"`, each blur that
both sides explain is put on the stated side (`fold_to_side`); a blur that only the other side
explains (`off_side`: with `"beyond"`, a blur larger than the far end's) stays there and is
counted; the depths are swept on the stated side alone where that loses nothing
(`SideStatement`). Through an aperture without point symmetry (`optics.Aperture.oriented`) the
two sides blur differently; `models.diagnostics.side_told` measures how well one photo's blur
then tells them."""

from __future__ import annotations

import dataclasses
import math

import torch
from torch import Tensor

from optics import CameraSettings

#: The side of one focus plane opposite to each stated one.
OTHER_SIDE = {"beyond": "before", "before": "beyond"}


def mirror_depth(depth: Tensor, focus_distance: float, depth_range: tuple[float, float]) -> Tensor:
    """The depth whose thin-lens blur equals that of `depth`, on the other side of the focus
    plane: `1/d' = 2/f - 1/d`, clamped to `depth_range` (beyond infinity: the far end).

    Example:
        >>> d = torch.tensor([1.0, 2.0, 4.0])
        >>> tuple(round(float(v), 3) for v in mirror_depth(d, 2.0, (0.5, 10.0)))
        (10.0, 2.0, 1.333)
    """
    inverse = 2.0 / focus_distance - 1.0 / depth
    far = inverse <= 1.0 / depth_range[1]
    mirrored = 1.0 / inverse.clamp_min(1e-12)
    return torch.where(far, torch.full_like(depth, depth_range[1]),
                       mirrored.clamp(depth_range[0], depth_range[1]))


def fold_to_side(depth: Tensor, focus_distance: float, depth_range: tuple[float, float],
                 side: str) -> Tensor:
    """The depth a self-supervised network finds at best with one focus plane and a side prior:
    the true `depth` with each blur that both sides explain put on the stated `side` (the rule of
    `models.depth_head.DepthHead`). With `"beyond"`, a pixel nearer than the focus plane goes to its
    mirror unless its blur exceeds the far end's, which only a nearer depth explains; with
    `"before"`, every pixel beyond the plane goes to its mirror (clamped to the range); with
    `"both"` the depth is returned as is. Scored against the true depth, it is the error that
    no training can remove under that prior.

    Example:
        >>> d = torch.tensor([0.6, 1.5, 4.0])
        >>> tuple(round(float(v), 3) for v in fold_to_side(d, 2.0, (0.5, 10.0), "beyond"))
        (0.6, 3.0, 4.0)
        >>> tuple(round(float(v), 3) for v in fold_to_side(d, 2.0, (0.5, 10.0), "before"))
        (0.6, 1.5, 1.333)
    """
    if side == "both":
        return depth
    mirror = mirror_depth(depth, focus_distance, depth_range)
    if side == "before":
        return torch.where(depth > focus_distance, mirror, depth)
    explained = 2.0 / focus_distance - 1.0 / depth >= 1.0 / depth_range[1]
    return torch.where((depth < focus_distance) & explained, mirror, depth)


def off_side(depth: Tensor, focus_distance: float, depth_range: tuple[float, float],
             side: str) -> Tensor:
    """Where the photos contradict a statement of the scene's `side` of one focus plane: the
    pixels of `depth` whose blur no depth of `depth_range` on that side explains, so that they can
    only lie on the other side (with `"beyond"`, a blur above the far end's; with `"before"`, a
    blur above the near end's). All False for `"both"`.

    Example:
        >>> d = torch.tensor([0.6, 1.5, 4.0])  # focus 2 m, range 0.5-10 m
        >>> off_side(d, 2.0, (0.5, 10.0), "beyond").tolist()
        [True, False, False]
        >>> off_side(torch.tensor([1.0, 9.0]), 1.0, (0.6, 10.0), "before").tolist()
        [False, True]
    """
    mirror = 2.0 / focus_distance - 1.0 / depth  # inverse depth of the same blur across the plane
    if side == "beyond":
        return (depth < focus_distance) & (mirror < 1.0 / depth_range[1])
    if side == "before":
        return (depth > focus_distance) & (mirror > 1.0 / depth_range[0])
    return torch.zeros_like(depth, dtype=torch.bool)


@dataclasses.dataclass(frozen=True)
class SideStatement:
    """Where the scene lies about one focus plane: `side` (`"beyond"` or `"before"`) of
    `focus_distance` metres, within `depth_range` `(near, far)` metres (`estimate_depth`'s
    `side`).

    Example:
        >>> stated = SideStatement("beyond", 2.0, (0.5, 10.0))
        >>> d = torch.tensor([0.6, 1.5, 4.0], dtype=torch.float64)
        >>> stated.put(d).round(decimals=6).tolist(), stated.swept_range()
        ([0.6, 3.0, 4.0], (0.5, 10.0))
        >>> SideStatement("beyond", 2.0, (1.5, 8.0)).swept_range()  # 1.5 m blurs less than 8 m
        (2.0, 8.0)
    """

    side: str
    focus_distance: float
    depth_range: tuple[float, float]

    @classmethod
    def of(cls, settings: CameraSettings, depth_range: tuple[float, float], side: str
           ) -> SideStatement | None:
        """The statement about the shots' one focus plane; None for `"both"` (none)."""
        if side == "both":
            return None
        return cls(side, float(settings.focus_distance.reshape(-1)[0]), depth_range)

    def off_side(self, depth: Tensor) -> Tensor:
        """The pixels of `depth` whose blur contradicts the statement (`off_side`)."""
        return off_side(depth, self.focus_distance, self.depth_range, self.side)

    def put(self, depth: Tensor) -> Tensor:
        """`depth` with each blur that both sides explain put on the stated side
        (`fold_to_side`), the blurs that only the other side explains left where they are."""
        return torch.where(self.off_side(depth), depth, fold_to_side(
            depth, self.focus_distance, self.depth_range, self.side))

    def swept_range(self) -> tuple[float, float]:
        """The depths (metres) to sweep: the stated side alone where every blur of the other
        side has a depth on it (all the candidates then go where the scene is), else the whole
        range."""
        (near, far), focus = self.depth_range, self.focus_distance
        if not near < focus < far:
            return near, far
        # the blur at near and at far (per unit of the blur at infinity): f/near - 1, 1 - f/far
        if self.side == "beyond" and 1 / near <= 2 / focus - 1 / far:
            return focus, far
        if self.side == "before" and 2 / focus - 1 / far <= 1 / near:
            return near, focus
        return near, far

    def state(self, out: dict) -> None:
        """Apply the statement to the result `out` of `estimate_depth`: its `depth` put on the
        side, with `side`, `focus_plane` (metres) and `off_side` (the pixels that contradict
        it) added."""
        out["side"], out["focus_plane"] = self.side, self.focus_distance
        out["off_side"] = self.off_side(out["depth"])
        out["depth"] = self.put(out["depth"])


def focus_planes(settings: CameraSettings | None, image_settings: CameraSettings | None = None
                 ) -> list[float]:
    """The distinct focus distances (metres, sorted) of the shots and of `image_settings`.

    Example:
        >>> focus_planes(CameraSettings(0.05, 2.0, [2.0, 2.0], 1e-4))
        [2.0]
    """
    found: list[float] = []
    for shots in (settings, image_settings):
        for distance in [] if shots is None else shots.focus_distance.reshape(-1).tolist():
            if not any(math.isclose(distance, d, rel_tol=1e-6) for d in found):
                found.append(distance)
    return sorted(found)
