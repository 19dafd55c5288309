r"""Does a lens tell near from far? Cues to the side of the focus plane in photos with depth.

With one focus plane, the thin lens blurs a depth `D` and its mirror `D'` (`1/D' = 2/D_f - 1/D`)
alike: a pair of photos at one focus setting cannot say on which side a blur lies. A real lens
can break the tie in two ways, both measurable on pairs with depth maps:

- **axial chromatic aberration**: each colour focuses at its own distance, so the difference of
  the red and the blue blur changes sign across the focus plane;
- **an asymmetric PSF** (spherical aberration): the blur spot is shaped differently in front of
  the plane (e.g. soft-edged, Gaussian-like) than behind it (e.g. hard-edged, disk-like).

`side_cues` measures both per pair and per depth bin with `measure_blur_curve`: the Gaussian
blur of each colour channel alone, and the residual of the disk over that of the Gaussian at
each one's best blur. The bins are even in inverse depth and mirrored about the focus plane
(`mirror_bin_edges`): each bin in front has a bin behind with the same thin-lens blur, so that
a PSF's shape, which changes with its size, is compared at one size. `SideCues.contrast`
compares, pair by pair, each bin in front with its mirror bin, and gives the mean and standard
error of that difference over the pairs. A cue a model could use has a contrast many standard
errors from zero; a contrast within a few standard errors means the photos do not carry it (or
too weakly for their noise and resolution), and the side stays a prior. Pixels next to a depth
edge mix the blurs of both depths: scenes with smooth depth measure best.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from ..progress import progress_bar
from .blur_curve import measure_blur_curve
from .pair import CalibrationPair
from .problem import pair_list


def mirror_bin_edges(focus_distance: float, bins_per_side: int = 8, nearest: float = 0.5) -> Tensor:
    """Depth bin edges (metres, increasing) even in inverse depth and symmetric about the focus
    plane: each bin in front of it has a mirror bin behind it with the same thin-lens blur. They
    reach from `nearest` (or less far, where its mirror would lie beyond infinity).

    Example:
        >>> edges = mirror_bin_edges(2.0, bins_per_side=2, nearest=1.0)
        >>> tuple(round(float(e), 3) for e in edges)
        (1.0, 1.333, 2.0, 4.0, inf)
    """
    if bins_per_side < 1:
        raise ValueError(f"bins_per_side must be >= 1, got {bins_per_side!r}")
    if not 0 < nearest < focus_distance:
        raise ValueError(f"nearest must lie between 0 and the focus distance {focus_distance} m, "
                         f"got {nearest!r}")
    reach = min(1 / nearest - 1 / focus_distance, 1 / focus_distance)
    defocus = torch.linspace(reach, -reach, 2 * bins_per_side + 1, dtype=torch.float64)
    return 1 / (defocus + 1 / focus_distance)


@dataclass
class SideCues:
    """What `side_cues` measured: per pair and depth bin, NaN where a bin has too few pixels.

    Attributes:
        edges: `(K+1,)` depth bin edges, metres, increasing.
        focus_distance: the focus plane, metres.
        channel_px: `(P, C, K)` the Gaussian blur (CoC diameter, pixels) of each colour channel.
        shape_log_ratio: `(P, K)` log of the disk's residual over the Gaussian's, each at its
            best blur: above 0 the Gaussian fits better, below 0 the disk.
        pixels: `(P, K)` pixels per pair and bin.
        names: the pairs' names.
    """

    edges: Tensor
    focus_distance: float
    channel_px: Tensor
    shape_log_ratio: Tensor
    pixels: Tensor
    names: list[str]

    @property
    def centres(self) -> Tensor:
        """`(K,)` the middle of each bin in inverse depth, metres."""
        return 2 / (1 / self.edges[:-1] + 1 / self.edges[1:])

    def colour_spread_px(self) -> Tensor:
        """`(P, K)` the first channel's blur minus the last's (red minus blue for RGB), pixels."""
        return self.channel_px[:, 0] - self.channel_px[:, -1]

    def sides(self) -> tuple[Tensor, Tensor]:
        """`(K,)` masks of the bins in front of the focus plane and of those behind it."""
        return self.centres < self.focus_distance, self.centres > self.focus_distance

    def contrast(self) -> dict[str, dict[str, float]]:
        """Front minus behind, bin by bin against its mirror bin (the same thin-lens blur), per
        pair, over the pairs that measured both: `{"colour spread px": ..., "shape log ratio":
        ...}`, each with `mean`, `standard_error` (NaN for fewer than two pairs), `pairs` and
        `z` (the mean over its standard error). A pair's difference is the mean over its bin
        pairs, weighted by the fewer pixels of the two bins."""
        near, far = self.sides()
        front, back = near.nonzero().flatten(), far.nonzero().flatten().flip(0)
        pairs = min(len(front), len(back))  # the bins next to the plane pair up first
        front, back = front[len(front) - pairs:], back[len(back) - pairs:]
        out = {}
        for name, values in (("colour spread px", self.colour_spread_px()),
                             ("shape log ratio", self.shape_log_ratio)):
            diff = values[:, front] - values[:, back]
            weight = torch.minimum(self.pixels[:, front], self.pixels[:, back])
            weight = torch.where(diff.isnan(), torch.zeros_like(weight), weight)
            measured = weight.sum(1) > 0
            d = ((diff.nan_to_num() * weight).sum(1)[measured] / weight.sum(1)[measured])
            mean, se = _mean_and_error(d)
            out[name] = {"mean": mean, "standard_error": se, "pairs": float(len(d)),
                         "z": mean / se if se > 0 else float("nan")}
        return out

    def by_bin(self) -> list[dict[str, float]]:
        """One row per bin measured by at least one pair: its depth, side (`-1` in front of
        the plane, `1` behind it), the pairs, the mean blur per channel, and the colour spread
        and shape ratio with their standard errors."""
        near = self.sides()[0]
        rows = []
        for k in range(len(self.centres)):
            ok = ~self.shape_log_ratio[:, k].isnan()
            if not bool(ok.any()):
                continue
            spread, shape = self.colour_spread_px()[ok, k], self.shape_log_ratio[ok, k]
            row = {"depth_m": float(self.centres[k]),
                   "side": -1.0 if bool(near[k]) else 1.0,
                   "pairs": float(ok.sum())}
            for c in range(self.channel_px.shape[1]):
                row[f"channel {c} px"] = float(self.channel_px[ok, c, k].mean())
            for name, v in (("colour spread px", spread), ("shape log ratio", shape)):
                row[name], row[f"{name} se"] = _mean_and_error(v)
            rows.append(row)
        return rows


def _mean_and_error(values: Tensor) -> tuple[float, float]:
    """The mean of `values` and its standard error (NaN where there are too few values)."""
    mean = float(values.mean()) if len(values) else float("nan")
    error = float(values.std() / math.sqrt(len(values))) if len(values) > 1 else float("nan")
    return mean, error


def side_cues(pairs: Sequence[CalibrationPair], focus_distance: float, bins_per_side: int = 8,
              nearest: float = 0.5, max_coc_px: float = 8.0, step_px: float = 0.25,
              min_pixels: int = 500, progress: bool = False) -> SideCues:
    """Measure the cues to the side of the focus plane in photo pairs with depth maps.

    Args:
        pairs: `CalibrationPair`s with depth maps, their photos aligned (`optics.align_shots`)
            and linear, several scenes (the spread over them gives the standard errors).
        focus_distance: the focus plane of the defocused photos, metres (e.g. fitted by
            `calibrate_from_depth`).
        bins_per_side: depth bins on each side of the plane (`mirror_bin_edges`).
        nearest: the nearest depth binned, metres.
        max_coc_px: the largest CoC diameter tried, pixels.
        step_px: the grid step of the CoC diameters, pixels.
        min_pixels: a pair's bins with fewer pixels are NaN.
        progress: show a progress bar over the pairs.

    Returns:
        the `SideCues`.

    Raises:
        ValueError: no pairs, a focus distance that is not a positive number of metres, a bad
            `bins_per_side` or `nearest`, or a pair without a depth map (`measure_blur_curve`).

    Example:
        >>> from optics import Camera, ThinLens, Sensor, Gaussian
        >>> camera = Camera(ThinLens(0.035, 2.8, 1.5), Sensor(5.6e-5), Gaussian(0.5))
        >>> g = torch.Generator().manual_seed(0)
        >>> depth = torch.full((1, 1, 64, 64), 1.1, dtype=torch.float64)
        >>> depth[..., 32:] = 1 / (2 / 1.5 - 1 / 1.1)  # its mirror: the same blur behind
        >>> pairs = []
        >>> for _ in range(3):
        ...     sharp = torch.rand(1, 3, 64, 64, generator=g, dtype=torch.float64)
        ...     pairs.append(CalibrationPair(sharp, camera.render(sharp, depth), depth))
        >>> cues = side_cues(pairs, 1.5, min_pixels=100)
        >>> colour = cues.contrast()["colour spread px"]
        >>> colour["pairs"], abs(colour["mean"]) < 0.05  # one focus for every colour: no cue
        (3.0, True)
    """
    pairs = pair_list(pairs)
    if not (isinstance(focus_distance, (int, float)) and math.isfinite(focus_distance)
            and focus_distance > 0):
        raise ValueError(f"focus_distance must be a positive number of metres, got "
                         f"{focus_distance!r}")
    edges = mirror_bin_edges(float(focus_distance), bins_per_side, nearest)
    grid = {"edges": edges, "max_coc_px": max_coc_px, "step_px": step_px,
            "min_pixels": min_pixels}
    channel_px, shape, pixels = [], [], []
    for pair in progress_bar(pairs, desc="side cues", disable=not progress):
        channels = [measure_blur_curve([_channel(pair, c)], "gaussian:0.5", **grid)
                    for c in range(pair.sharp.shape[1])]
        disk = measure_blur_curve([pair], "disk", **grid)
        gaussian_error = torch.stack([c.errors for c in channels]).sum(0).min(1).values
        ratio = (disk.errors.min(1).values / gaussian_error.clamp_min(1e-30)).log()
        ratio[disk.pixels < min_pixels] = float("nan")
        channel_px.append(torch.stack([c.best_px() for c in channels]))
        shape.append(ratio)
        pixels.append(disk.pixels)
    return SideCues(edges, float(focus_distance), torch.stack(channel_px), torch.stack(shape),
                    torch.stack(pixels), [p.name for p in pairs])


def _channel(pair: CalibrationPair, c: int) -> CalibrationPair:
    return CalibrationPair(pair.sharp[:, c:c + 1], pair.blurred[:, c:c + 1], pair.depth,
                           f"{pair.name} channel {c}")
