"""Semi-global aggregation of a cost volume: per-pixel costs made robust, depth edges kept.

A depth sweep gives every pixel a cost per candidate depth. Picking each pixel's cheapest
candidate alone is noisy; summing the costs over square windows (`thin_lens.aggregate_cost`)
is robust but smooths across depth edges, which costs most where a scene is only a few hundred
pixels wide. Semi-global matching (Hirschmueller, *Stereo Processing by Semiglobal Matching and
Mutual Information*, PAMI 2008) instead solves, along each of four scan lines through every
pixel (left, right, up, down), the one-dimensional problem "costs plus a penalty for changing
candidate" exactly by dynamic programming, and sums the four answers:

    L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d +- 1) + P1, min_k L_r(p-r, k) + P2)
                - min_k L_r(p-r, k)

`P1` lets the depth drift by one candidate (slanted surfaces), `P2` lets it jump (depth edges),
and `P2` is lowered where the all-in-focus photo changes between neighbours, where depth edges
usually are. The subtracted minimum only keeps the sums bounded: it shifts every candidate of a
pixel alike. The result is piecewise linear in the costs; it is meant for choosing candidates,
not for back-propagation.
"""

from __future__ import annotations

import torch
from torch import Tensor

from optics.checks import check_shape

from .rules import refuse_broken

#: Penalty (in units of the volume's typical cost spread, see `semi_global_cost`) for a change
#: of one candidate between neighbours, and for a larger jump away from the photo's edges; the
#: photo contrast (linear intensity) that halves the jump penalty. Chosen on procedural scenes
#: under random cameras (never the evaluation's motorcycle).
SMOOTH_PENALTY = 0.1
JUMP_PENALTY = 3.0
EDGE_CONTRAST = 0.05


def semi_global_paths(cost: Tensor, smooth_penalty: float, jump_penalty: Tensor,
                      workspace: Tensor | None = None) -> Tensor:
    """Sum over the four scan directions of the path costs `L_r` (module docstring).

    Args:
        cost: `(B,K,H,W)` costs of `K` candidates (ordered: candidate `k` neighbours `k +- 1`).
        smooth_penalty: `P1`, added for a change of one candidate between neighbours.
        jump_penalty: `(B,4,H,W)` `P2` per pixel and direction (left-to-right, right-to-left,
            top-to-bottom, bottom-to-top), for a larger change into that pixel from its
            predecessor along the direction; at least `smooth_penalty`.
        workspace: memory for the two volume-sized intermediates, a flat tensor of at least
            `2 * cost.numel()` elements of `cost`'s dtype (see `semi_global_cost`; by default
            new); the result lives in it.

    Returns:
        `(B,K,H,W)`, lower is better.

    Example:
        >>> cost = torch.rand(1, 5, 6, 7)
        >>> free = semi_global_paths(cost, 0.0, torch.zeros(1, 4, 6, 7))
        >>> torch.allclose(free, 4 * cost)  # no penalty: each path is the pixel's own cost
        True
    """
    check_shape("cost", cost, ["B", "K", "H", "W"])
    b, k, h, w = cost.shape
    check_shape("jump_penalty", jump_penalty, [str(b), "4", str(h), str(w)])
    # the scans along W (left-right, right-left) run over a transposed copy, so that each step
    # reads and writes contiguous memory (several times faster than strided columns); the sums
    # keep the order of the four directions
    n = cost.numel()
    workspace = cost.new_empty(2 * n) if workspace is None else workspace
    across = workspace[:n].view(b, k, w, h).copy_(cost.transpose(2, 3))
    sums = workspace[n:2 * n].view(b, k, w, h).zero_()
    for direction, reverse in ((0, False), (1, True)):
        _scan(across, jump_penalty[:, direction:direction + 1].transpose(2, 3), smooth_penalty,
              reverse, sums)
    total = workspace[:n].view(cost.shape).copy_(sums.transpose(2, 3))  # over `across`
    for direction, reverse in ((2, False), (3, True)):
        _scan(cost, jump_penalty[:, direction:direction + 1], smooth_penalty, reverse, total)
    return total


def _scan(cost: Tensor, jumps: Tensor, smooth_penalty: float, reverse: bool, sums: Tensor
          ) -> None:
    """Add the path costs `L_r` of `cost` `(B,K,N,X)` along dimension 2 (from its end where
    `reverse`), with `jumps` `(B,1,N,X)` the jump penalty into each pixel, to `sums`."""
    k, n = cost.shape[1], cost.shape[2]
    previous = None
    for i in range(n - 1, -1, -1) if reverse else range(n):
        if previous is None:
            current = cost[:, :, i]
        else:
            floor = previous.amin(1, keepdim=True)
            best = torch.minimum(previous, floor + jumps[:, :, i])
            if k > 1:
                step = previous + smooth_penalty
                torch.minimum(best[:, 1:], step[:, :-1], out=best[:, 1:])
                torch.minimum(best[:, :-1], step[:, 1:], out=best[:, :-1])
            current = best.add_(cost[:, :, i]).sub_(floor)
        sums[:, :, i] += current
        previous = current


#: `cost_scale` reads every this many candidates (the same ones in a tile and in a whole image).
SCALE_STRIDE = 4


def cost_scale(cost: Tensor, stride: int = SCALE_STRIDE) -> Tensor:
    """The typical spread of a cost volume `(B,K,H,W)`: per image `(B,)`, the median over pixels
    of the gap between a pixel's mean and lowest cost, over every `stride`-th candidate (1 for
    a volume that holds only those already).

    `semi_global_cost` divides the costs by it so that its penalties mean the same for any
    photo. A photo swept in tiles must use the whole photo's value (each tile's own would give
    each tile different penalties).

    Example:
        >>> cost = torch.arange(8.0).view(1, 8, 1, 1).expand(1, 8, 4, 4)  # candidates 0, 4 read
        >>> cost_scale(cost)
        tensor([2.])
    """
    check_shape("cost", cost, ["B", "K", "H", "W"])
    read = cost[:, ::stride]
    spread = (read.mean(1) - read.amin(1)).flatten(1)
    return spread.median(1).values


def semi_global_cost(cost: Tensor, image: Tensor, smooth_penalty: float = SMOOTH_PENALTY,
                     jump_penalty: float = JUMP_PENALTY,
                     edge_contrast: float = EDGE_CONTRAST, scale: Tensor | None = None,
                     workspace: Tensor | None = None) -> Tensor:
    """Aggregate a cost volume `(B,K,H,W)` semi-globally, guided by the photo `image` `(B,C,H,W)`.

    The costs are first made scale-free: each pixel's minimum is subtracted (it shifts all its
    candidates alike) and the volume is divided by `cost_scale` (the median over pixels of the
    gap between a pixel's mean and lowest cost), so the penalties mean the same for dark and
    bright, noisy and clean photos. A pixel without texture keeps nearly flat costs, and its
    neighbours decide.

    Args:
        cost: `(B,K,H,W)` costs, candidate `k` next to `k +- 1` (e.g. `sweep.sweep_cost`).
        image: `(B,C,H,W)` the all-in-focus photo, linear; its mean over channels guides the
            jump penalty.
        smooth_penalty: penalty for a change of one candidate between neighbours.
        jump_penalty: penalty for a larger change where the photo is flat; it falls as
            `jump_penalty / (1 + contrast / edge_contrast)` across a photo edge of `contrast`
            (never below `smooth_penalty`).
        edge_contrast: photo contrast (linear intensity) that halves the jump penalty.
        scale: `(B,)` the costs' typical spread; by default `cost_scale(cost)`. Give the whole
            photo's value when `cost` is a tile of it.
        workspace: memory for the three volume-sized intermediates, a flat tensor of at least
            `3 * cost.numel()` elements of `cost`'s dtype and device (by default new), to reuse
            tile after tile: a fresh volume per tile is fresh pages the system zeroes (a
            second of a 12-megapixel photo's depth). The result lives in it, until its next
            use.

    Returns:
        `(B,K,H,W)` aggregated costs, lower is better (`thin_lens.select_depth` picks from
        them).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> truth = torch.zeros(1, 1, 16, 16, dtype=torch.long)
        >>> truth[..., 8:] = 4  # two flat regions, at candidates 0 and 4
        >>> wrong = (torch.arange(6).view(1, 6, 1, 1) != truth).float()
        >>> cost = wrong + 1.5 * torch.rand(1, 6, 16, 16, generator=g)  # noisy costs
        >>> image = (truth > 0).float().expand(1, 3, 16, 16)  # the photo has the same edge
        >>> picked = semi_global_cost(cost, image).argmin(1, keepdim=True)
        >>> int((cost.argmin(1, keepdim=True) != truth).sum()), int((picked != truth).sum())
        (42, 14)
    """
    check_shape("cost", cost, ["B", "K", "H", "W"])
    check_shape("image", image, [str(cost.shape[0]), "C", str(cost.shape[2]), str(cost.shape[3])])
    refuse_broken([*((not (isinstance(value, (int, float)) and 0 <= value < float("inf")),
                      lambda name=name, value=value: f"{name} must be a finite number >= 0, "
                      f"got {value!r}")
                     for name, value in (("smooth_penalty", smooth_penalty),
                                         ("jump_penalty", jump_penalty),
                                         ("edge_contrast", edge_contrast))),
                   (edge_contrast == 0, lambda: "edge_contrast must be > 0, got 0"),
                   (scale is not None and scale.numel() != cost.shape[0], lambda: "scale must "
                    f"hold one value per image ({cost.shape[0]}), got {tuple(scale.shape)}"),
                   (workspace is not None and (workspace.numel() < 3 * cost.numel()
                                               or workspace.dtype != cost.dtype
                                               or workspace.device != cost.device),
                    lambda: f"workspace must be a {cost.dtype} tensor on {cost.device} of at "
                    f"least {3 * cost.numel()} elements, got {workspace.dtype} on "
                    f"{workspace.device}, {workspace.numel()}")])
    typical = cost_scale(cost) if scale is None else scale.to(cost.dtype).flatten()
    typical = typical.clamp_min(torch.finfo(cost.dtype).tiny)
    n = cost.numel()
    workspace = cost.new_empty(3 * n) if workspace is None else workspace
    scaled = torch.sub(cost, cost.amin(1, keepdim=True), out=workspace[2 * n:3 * n].view(
        cost.shape)).div_(typical.view(-1, 1, 1, 1))
    grey = image.to(cost.dtype).mean(1, keepdim=True)
    # contrast into each pixel from its predecessor along each direction (none at the start)
    step_x = (grey[..., 1:] - grey[..., :-1]).abs()
    step_y = (grey[..., 1:, :] - grey[..., :-1, :]).abs()
    zero_x, zero_y = torch.zeros_like(grey[..., :1]), torch.zeros_like(grey[..., :1, :])
    contrast = torch.cat([torch.cat([zero_x, step_x], -1), torch.cat([step_x, zero_x], -1),
                          torch.cat([zero_y, step_y], -2), torch.cat([step_y, zero_y], -2)], 1)
    jumps = (jump_penalty / (1 + contrast / edge_contrast)).clamp_min(smooth_penalty)
    return semi_global_paths(scaled, float(smooth_penalty), jumps, workspace[:2 * n])
