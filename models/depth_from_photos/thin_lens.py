"""The thin-lens cost machinery every method of depth from photos shares.

For a thin lens the signed CoC diameter in pixels is linear in inverse depth,
`c_i(D) = A_i (1 - D_f,i / D)`, with `A_i` the CoC of a point at infinity (see
`CameraSettings.coc_at_infinity_px`). Every method here tries `K` candidate depths evenly spaced
in inverse depth (`candidate_inverse_depths`), predicts each shot's blur there
(`thin_lens_blur`), scores the candidates per pixel in a cost volume `(B,K,H,W)`, combines the
costs of neighbouring pixels (`aggregate_cost`, or `semi_global.semi_global_cost`) and keeps the
cheapest candidate, refined to a fraction of a candidate (`select_depth`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor

import kornia
import numpy as np
import torch
from scipy import ndimage
from torch import Tensor

from optics import CameraSettings
from optics.fourier import runs_in_scipy

from .rules import refuse_broken
from .side import focus_planes

#: Side (pixels) of the window local errors between photos are first summed over.
ERROR_WINDOW_PX = 5
#: Candidates whose errors the sweeps average over `ERROR_WINDOW_PX` windows in one call (one
#: call on many pixels is several times faster on a CPU than one per candidate).
WINDOW_CHUNK = 16
#: Default windows (pixels) -> weights of `aggregate_cost`: fine windows dominate where there is
#: texture, coarse ones fill in where there is none.
WINDOWS = {5: 1.0, 17: 0.3, 49: 0.1}


def box_filter(x: Tensor, size: int) -> Tensor:
    """Mean of `x` `(B,C,H,W)` over `size x size` windows, borders replicated (unlike reflect,
    valid for windows larger than the image): `kornia.filters.box_blur`, which it runs on a GPU,
    where gradients are asked for or for even sizes. On a CPU it runs scipy's running sums
    (`_on_cpu`): 2-3x faster at 5-9 px on volumes of 1.5-megapixel planes, and no slower at 49.

    Example:
        >>> box_filter(torch.ones(1, 1, 4, 4), 9).unique()
        tensor([1.])
    """
    if not size % 2 or not _on_cpu(x):
        return kornia.filters.box_blur(x, (size, size), border_type="replicate")
    return _filter_planes(x, size, lambda rows: ndimage.uniform_filter(rows, size,
                                                                       mode="nearest"))


def windowed_errors(error: Callable[[int], Tensor], count: int, like: Tensor,
                    out: Tensor | None = None,
                    finish: Callable[[Tensor, int, int], Tensor] | None = None) -> Tensor:
    """The window means (`box_filter` over `ERROR_WINDOW_PX`) of `count` candidates' local
    errors `error(k)` `(B,H,W)`, as a volume `(B,count,H,W)` (the dtype, device, batch and size
    of `like`), `finish(means, start, stop)` applied to the means of candidates `start:stop`:
    added into `out` (returned) where given, else into a new volume. The means are taken for
    `WINDOW_CHUNK` candidates at once (one call on many pixels) and written straight into the
    volume (no second copy of it): the loop of every sweep over candidate blurs.

    Example:
        >>> x = torch.rand(1, 8, 8)
        >>> v = windowed_errors(lambda k: k * x, 3, x[None])
        >>> v.shape, torch.allclose(v[:, 2], 2 * box_filter(x[None], ERROR_WINDOW_PX)[:, 0])
        (torch.Size([1, 3, 8, 8]), True)
    """
    b, (h, w) = like.shape[0], like.shape[-2:]
    errors = like.new_zeros(b, count, h, w) if out is None else out
    buffer = like.new_empty(b, min(WINDOW_CHUNK, count), h, w)
    for start in range(0, count, WINDOW_CHUNK):
        stop = min(start + WINDOW_CHUNK, count)
        for k in range(start, stop):
            buffer[:, k - start] = error(k)
        means = box_filter(buffer[:, :stop - start], ERROR_WINDOW_PX)
        errors[:, start:stop] += means if finish is None else finish(means, start, stop)
    return errors


def median_filter(x: Tensor, size: int) -> Tensor:
    """Median of `x` `(B,C,H,W)` over `size x size` windows (odd), borders mirrored: the values
    of `kornia.filters.median_blur`, which it runs on a GPU or where gradients are asked for.
    On a CPU it runs `scipy.ndimage.median_filter` (about 2x faster on one thread, `_on_cpu`).

    Example:
        >>> x = torch.rand(1, 2, 16, 20, dtype=torch.float64)
        >>> torch.equal(median_filter(x, 9), kornia.filters.median_blur(x, 9))
        True
    """
    if not _on_cpu(x):
        return kornia.filters.median_blur(x, size)
    return _filter_planes(x, size, lambda rows: ndimage.median_filter(rows, size=size,
                                                                      mode="mirror"))


def _on_cpu(x: Tensor) -> bool:
    """Whether the filters here run scipy's on `x`: a float32/64 CPU tensor that no gradient is
    asked of."""
    return x.dtype in (torch.float32, torch.float64) and runs_in_scipy(x)


def _filter_planes(x: Tensor, size: int, filter_rows: Callable[[np.ndarray], np.ndarray]
                   ) -> Tensor:
    """`filter_rows` (a numpy filter over `size x size` windows) on every plane of `x`
    `(B,C,H,W)`, on bands of rows (each with the `size // 2` rows around it it needs) in
    `torch.get_num_threads()` threads (scipy releases the GIL)."""
    planes = x.detach().reshape(-1, *x.shape[-2:]).contiguous().numpy()
    out = np.empty_like(planes)
    half, rows = size // 2, planes.shape[1]
    edges = np.linspace(0, rows, min(torch.get_num_threads(), max(1, rows // size)) + 1)
    edges = edges.round().astype(int)

    def band(plane: int, start: int, stop: int) -> None:
        lo, hi = max(0, start - half), min(rows, stop + half)
        out[plane, start:stop] = filter_rows(planes[plane, lo:hi])[start - lo:stop - lo]

    with ThreadPoolExecutor(len(edges) - 1) as pool:
        list(pool.map(lambda job: band(*job), [(p, int(a), int(b)) for p in range(len(planes))
                                               for a, b in zip(edges[:-1], edges[1:], strict=True)]))
    return torch.from_numpy(out).reshape(x.shape)


def candidate_inverse_depths(near: float, far: float, n_candidates: int, like: Tensor) -> Tensor:
    """The `n_candidates` inverse depths (1/metres) of `select_depth`, evenly spaced in
    `[1/far, 1/near]`, with the dtype and device of `like`.

    Example:
        >>> candidate_inverse_depths(1.0, 4.0, 4, torch.zeros(1))
        tensor([0.2500, 0.5000, 0.7500, 1.0000])
    """
    if not 0 < near < far:
        raise ValueError(f"need 0 < near < far metres, got near={near!r}, far={far!r}")
    return torch.linspace(1 / far, 1 / near, n_candidates, dtype=like.dtype, device=like.device)


def thin_lens_blur(settings: CameraSettings, inverse_depth: Tensor, signed: bool = False
                   ) -> Tensor:
    """The blur `|c_i| = |A_i (1 - D_f,i x)|` pixels that the thin lens gives each shot of
    `settings` `(B,F)` at inverse depths `x` (1/metres) shaped `(B or 1, F or 1, ...)`:
    `(B,F,...)`; `signed`: `c_i` itself, positive beyond the focus plane (what an `oriented`
    aperture is rendered with).

    Example:
        >>> s = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4).batched(1)  # sharp at 2 m and 6 m
        >>> thin_lens_blur(s, torch.tensor([[[1 / 2.0, 1 / 6.0]]])).round(decimals=2)
        tensor([[[0.0000, 4.2700],
                 [4.2000, 0.0000]]], dtype=torch.float64)
    """
    trailing = (1,) * (inverse_depth.dim() - 2)
    a = settings.coc_at_infinity_px().reshape(*settings.shape, *trailing)
    focus = settings.focus_distance.reshape(*settings.shape, *trailing)
    blur = a * (1 - focus * inverse_depth)
    return blur if signed else blur.abs()


def mirrored_depths(settings: CameraSettings, near: float, far: float
                    ) -> tuple[float, float] | None:
    """The depths (metres) of `[near, far]` that the shots cannot place on either side of their
    focus plane: `(nearest, farthest)`, or None where there are none.

    Every shot's blur is `|A_i| D_f |1/D_f - 1/D|`: where all shots share one focus distance
    `D_f` (an aperture pair, or a single focused shot beside an all-in-focus photo), a depth
    and its mirror image in inverse depth, `1/D' = 2/D_f - 1/D`, blur every shot alike. The
    span returned holds the depths whose mirror image is in the range too. Shots focused at
    two or more distances have no such span.

    Example:
        >>> s = CameraSettings(0.035, 2.8, [1.7], 5.6e-5)  # one shot beside an all-in-focus photo
        >>> tuple(round(d, 2) for d in mirrored_depths(s, 1.0, 8.0))
        (1.0, 5.67)
        >>> mirrored_depths(CameraSettings(0.05, 2.0, [1.5, 4.0], 1e-4), 1.0, 8.0) is None
        True
    """
    planes = focus_planes(settings)
    if len(planes) != 1:
        return None
    x0 = 1.0 / planes[0]
    lo = max(1.0 / far, 2 * x0 - 1.0 / near)
    hi = min(1.0 / near, 2 * x0 - 1.0 / far)
    if not hi > lo:
        return None
    return 1.0 / hi, 1.0 / lo


def candidate_blurs(settings: CameraSettings, near: float, far: float, n_candidates: int,
                    like: Tensor, n_shots: int, every: int = 1, signed: bool = False) -> Tensor:
    """The blur `(B,F,K)` pixels the thin lens gives each of the `n_shots` shots of `settings`
    (`(B,F)` or `(F,)`, moved to `like`'s device and dtype, batched to `like`'s first dimension)
    at every `every`-th of the `n_candidates` depths of `candidate_inverse_depths` (`signed`:
    see `thin_lens_blur`).

    Example:
        >>> s = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
        >>> candidate_blurs(s, 1.0, 10.0, 8, torch.zeros(1, 1), 2).shape
        torch.Size([1, 2, 8])
    """
    refuse_broken([
        (isinstance(every, bool) or not isinstance(every, int) or every < 1,
         lambda: f"every must be a positive integer, got {every!r}"),
        (settings.n_shots != n_shots,
         lambda: f"the photos hold {n_shots} shots but settings {settings.n_shots}")])
    x = candidate_inverse_depths(near, far, n_candidates, like)[::every]
    settings = settings.batched(like.shape[0]).to(device=like.device, dtype=like.dtype)
    return thin_lens_blur(settings, x[None, None], signed)


def aggregate_cost(cost: Tensor, windows: Mapping[int, float] | None = None) -> Tensor:
    """`cost` `(B,K,H,W)` summed over square windows of each size with its weight (`WINDOWS` by
    default).

    Example:
        >>> cost = torch.rand(1, 3, 8, 8)
        >>> aggregate_cost(cost, {1: 1.0}).equal(cost)
        True
    """
    return sum(s * box_filter(cost, k) for k, s in (windows or WINDOWS).items())


def select_depth(cost: Tensor, near: float, far: float) -> Tensor:
    """Depth `(B,1,H,W)` metres of the cheapest of the `K` candidates of `cost` `(B,K,H,W)`,
    candidate `k` at inverse depth `1/far + k (1/near - 1/far) / (K - 1)`, refined by a parabola
    through the neighbouring costs.

    Example:
        >>> cost = torch.tensor([3.0, 1.0, 0.0, 1.0, 3.0]).reshape(1, 5, 1, 1)
        >>> round(select_depth(cost, 1.0, 4.0).item(), 4)  # candidate 2: inverse depth 0.625
        1.6
    """
    n_candidates = cost.shape[1]
    best = cost.argmin(1, keepdim=True)
    lo = cost.gather(1, (best - 1).clamp(0, n_candidates - 1))
    mid = cost.gather(1, best)
    hi = cost.gather(1, (best + 1).clamp(0, n_candidates - 1))
    curvature = (lo + hi - 2 * mid).clamp_min(torch.finfo(cost.dtype).tiny)
    offset = (0.5 * (lo - hi) / curvature).clamp(-0.5, 0.5)
    inside = (best > 0) & (best < n_candidates - 1)
    index = best.to(cost.dtype) + torch.where(inside, offset, torch.zeros_like(offset))
    inverse = 1 / far + index * (1 / near - 1 / far) / (n_candidates - 1)
    return (1 / inverse).clamp(near, far)
