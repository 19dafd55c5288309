"""From a cost volume to a depth map: what every sweep over candidate depths shares.

A method that scores `K` candidate depths per pixel (the sweep with an all-in-focus photo, the
relative blur between shots) hands `CostVolumeDepth.depth_map` a function that computes the cost
volume `(B,K,H,W)` of a crop of its photos. `depth_map` then combines the costs of neighbouring
pixels (semi-globally along scan lines, or over square windows), picks the cheapest candidate
(`select_depth`), removes isolated wrong picks with a median filter and smooths the inverse depth
edge-aware where there is little texture. Photos larger than a tile with its context are
aggregated in tiles, each with that context, so the aggregation's memory stays bounded; their cost
volume is computed once for the whole photo where it takes at most `MAX_VOLUME_BYTES` (each
cost computed once, not again in the context of every tile), else tile by tile as well.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from torch import Tensor, nn

from optics.progress import progress_bar

from .confidence import texture_confidence
from .fourier_blur import FLOOR_SIGMA_PX
from .rules import refuse_broken
from .semi_global import (
    JUMP_PENALTY,
    SCALE_STRIDE,
    SMOOTH_PENALTY,
    cost_scale,
    semi_global_cost,
)
from .smoothing import edge_aware_smooth
from .thin_lens import ERROR_WINDOW_PX, WINDOWS, aggregate_cost, median_filter, select_depth
from .tiling import apply_in_tiles, check_tiling

#: Side (pixels) of the median filter the depth map goes through: it removes isolated wrong
#: picks (dark or textureless pixels whose costs are nearly flat) and keeps depth edges.
MEDIAN_PX = 9
#: `edge_aware_smooth` of the inverse depth afterwards: its strength, guide sigma, and the
#: confidence every pixel keeps (where the photo has no texture at all).
SMOOTHING_STRENGTH = 10.0
SMOOTHING_SIGMA = 0.1
CONFIDENCE_FLOOR = 0.01
#: Context (pixels) a tile sees beyond its centre under semi-global aggregation, whose scan lines
#: cross the whole tile: past this distance a pixel's costs rarely change another's pick.
SEMI_GLOBAL_CONTEXT_PX = 128
#: The largest cost volume (bytes) `depth_map` computes for a whole photo at once; a larger one
#: (more pixels or candidates, float64) is computed tile by tile, each tile with its context.
MAX_VOLUME_BYTES = 768 * 2**20
#: How the costs of neighbouring pixels are aggregated.
AGGREGATIONS = ("semi-global", "windows")

#: `cost(guide, *photos, every=1) -> (B,K,H,W)` for crops of the photos (see `depth_map`).
CostFunction = Callable[..., Tensor]


class CostVolumeDepth(nn.Module):
    """Base of the methods that sweep over candidate depths (`SweepDepth`,
    `RelativeBlurDepth`): their options and the way from costs to depth (`depth_map`).

    Args:
        n_candidates: candidate depths, evenly spaced in inverse depth.
        tile: largest tile side in pixels.
        progress: show a progress bar over the tiles of a large photo.
        smoothing: strength of the edge-aware smoothing of the inverse depth by the texture
            confidence (`edge_aware_smooth`, whole image, after the tiles): depth read on
            textured pixels spreads to their untextured neighbours of similar colour. Zero
            turns it off.
        aggregation: how the costs of neighbouring pixels are combined before each pixel picks
            its depth: `"semi-global"` (`semi_global_cost`: along scan lines, depth edges kept
            where the photo has edges) or `"windows"` (sums over square windows,
            `aggregate_cost`; tiles then give exactly the untiled result, while semi-global
            tiles see `SEMI_GLOBAL_CONTEXT_PX` of context and agree with the untiled result at
            nearly every pixel).
        smooth_penalty: semi-global penalty for a change of one candidate between neighbours
            (`semi_global_cost`).
        jump_penalty: semi-global penalty for a larger jump away from the photo's edges.
    """

    #: Largest blur (pixels) at the working resolution that `estimate_depth` lets it read: the
    #: upper end the thin-lens design covers (larger blurs cost time and gain little).
    max_coc_px = 20.0

    def __init__(self, n_candidates: int = 96, tile: int = 768, progress: bool = False,
                 smoothing: float = SMOOTHING_STRENGTH, aggregation: str = "semi-global",
                 smooth_penalty: float = SMOOTH_PENALTY, jump_penalty: float = JUMP_PENALTY):
        super().__init__()
        refuse_broken([
            (not (smooth_penalty >= 0 and jump_penalty >= smooth_penalty), lambda: "need 0 <= "
             f"smooth_penalty <= jump_penalty, got {smooth_penalty!r} and {jump_penalty!r}"),
            (not n_candidates >= 3, lambda: f"n_candidates must be >= 3, got {n_candidates!r}"),
            (aggregation not in AGGREGATIONS,
             lambda: f"aggregation must be one of {AGGREGATIONS}, got {aggregation!r}"),
            (not smoothing >= 0, lambda: f"smoothing must be >= 0, got {smoothing!r}")])
        self.smooth_penalty, self.jump_penalty = float(smooth_penalty), float(jump_penalty)
        self.aggregation = aggregation
        check_tiling(tile, 0)
        self.n_candidates, self.tile, self.progress = int(n_candidates), int(tile), progress
        self.smoothing = float(smoothing)

    def context_px(self, psf_half_px: int) -> int:
        """Context (pixels) around a tile for PSFs of `psf_half_px` half-width: the PSF, the
        floor and error window, the aggregation (exact for windows) and the median filter."""
        spread = (SEMI_GLOBAL_CONTEXT_PX if self.aggregation == "semi-global"
                  else max(WINDOWS) // 2)
        return psf_half_px + math.ceil(4 * FLOOR_SIGMA_PX) + ERROR_WINDOW_PX // 2 + spread \
            + MEDIAN_PX // 2 + 2

    def depth_map(self, cost: CostFunction, guide: Tensor, photos: Sequence[Tensor],
                  near: float, far: float, reach: int, desc: str = "depth sweep") -> Tensor:
        """Depth `(B,1,H,W)` metres in `[near, far]` from the costs of its candidates.

        Args:
            cost: `cost(guide, *photos, every=1)` -> `(B,K,H,W)` for crops of `guide` and
                `photos` (every `every`-th candidate only when asked: the semi-global
                aggregation's cost scale is measured on a few).
            guide: `(B,3,H,W)` the photo whose edges guide the aggregation and the smoothing and
                whose texture weighs it, linear.
            photos: the other inputs of `cost`, each `(..., H, W)` (cropped alike for tiles).
            near: nearest depth, metres.
            far: farthest depth, metres.
            reach: context (pixels) a tile needs around it (`context_px`).
            desc: the progress bar's label.
        """
        def pick(volume: Tensor, guide: Tensor, scale: Tensor | None = None,
                 workspace: Tensor | None = None) -> Tensor:
            if self.aggregation == "semi-global":
                volume = semi_global_cost(volume, guide, self.smooth_penalty, self.jump_penalty,
                                          scale=scale, workspace=workspace)
            else:
                volume = aggregate_cost(volume)
            return median_filter(select_depth(volume, near, far), MEDIAN_PX)

        # a photo no larger than one tile with its context is done whole
        if guide.shape[-2] * guide.shape[-1] <= (self.tile + 2 * reach) ** 2:
            return self._smoothed(pick(cost(guide, *photos), guide), guide, near, far)
        h, w = guide.shape[-2:]
        # tiles of at most `tile` pixels, as few and as even as that allows (less context to
        # compute twice than full tiles and a thin last one)
        side = max(math.ceil(n / math.ceil(n / self.tile)) for n in (h, w))
        tiles = math.ceil(h / side) * math.ceil(w / side)
        bar = progress_bar(total=tiles, desc=f"{desc} (tiles)", disable=not self.progress)
        semi_global = self.aggregation == "semi-global"
        # the semi-global aggregation's intermediates, for the largest tile, reused by every tile
        largest = math.prod(max(min(start + side + reach, n) - max(start - reach, 0)
                                for start in range(0, n, side)) for n in (h, w))
        workspace = guide.new_empty(3 * guide.shape[0] * self.n_candidates * largest) \
            if semi_global else None
        if guide.shape[0] * self.n_candidates * h * w * guide.element_size() \
                <= MAX_VOLUME_BYTES:
            # the whole photo's volume at once (each cost computed once, not again in every
            # tile's context); the aggregation then goes tile by tile over it
            volume = cost(guide, *photos)
            scale = cost_scale(volume) if semi_global else None

            def volume_tile(volume: Tensor, guide: Tensor) -> Tensor:
                out = pick(volume, guide, scale, workspace)
                bar.update()
                return out

            with bar:
                depth = apply_in_tiles(volume_tile, [volume, guide], side, reach)
            del volume
            return self._smoothed(depth, guide, near, far)
        # the whole photo's cost scale, from a few candidates
        scale = cost_scale(cost(guide, *photos, every=SCALE_STRIDE), stride=1) \
            if semi_global else None

        def tile_depth(guide: Tensor, *photos: Tensor) -> Tensor:
            out = pick(cost(guide, *photos), guide, scale, workspace)
            bar.update()
            return out

        with bar:
            depth = apply_in_tiles(tile_depth, [guide, *photos], side, reach)
        return self._smoothed(depth, guide, near, far)

    def _smoothed(self, depth: Tensor, guide: Tensor, near: float, far: float) -> Tensor:
        """`depth` `(B,1,H,W)` after the edge-aware smoothing of its inverse (`smoothing`)."""
        if self.smoothing > 0:
            texture = texture_confidence(guide)
            weight = median_filter(texture, MEDIAN_PX) + CONFIDENCE_FLOOR
            inverse = edge_aware_smooth(1 / depth, weight, guide, self.smoothing, SMOOTHING_SIGMA)
            depth = 1 / inverse.clamp(1 / far, 1 / near)
        return depth
