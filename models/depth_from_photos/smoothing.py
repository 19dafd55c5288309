"""Edge-aware smoothing of a map by its confidence: a weighted least-squares fit.

A depth read from defocus is noisy where the photo holds little texture and sharp where it holds
a lot, and a scene's depth changes little except where the image changes too. `edge_aware_smooth`
finds the map `x` that minimises

    sum_i w_i (x_i - y_i)^2 + strength * sum_{i~j} a_ij (x_i - x_j)^2

over 4-connected neighbours `i~j`: `y` the measured map, `w` its confidence, and
`a_ij = exp(-|g_i - g_j|^2 / (2 sigma^2))` the similarity of the guide image between them (in
display gamma, so that dark and bright edges count alike). Confident pixels keep their value; the
others take their similar neighbours', across no edge of the guide. The minimum solves a sparse,
symmetric positive definite linear system, here by conjugate gradients with a Jacobi
preconditioner (whole-image, no windows: memory grows with the pixels only), started from the
same problem solved on a half-size grid (and so on down), which fewer iterations then refine.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from optics.checks import check_shape, is_tracing

from .rules import refuse_broken

#: Display gamma the guide image is encoded with before comparing neighbours.
GUIDE_GAMMA = 2.2


def guide_affinities(guide: Tensor, sigma: float) -> tuple[Tensor, Tensor]:
    """Similarities in (0, 1] between vertical `(B,1,H-1,W)` and horizontal `(B,1,H,W-1)`
    neighbours of `guide` `(B,C,H,W)` (linear intensity), encoded with `GUIDE_GAMMA`.

    Example:
        >>> guide = torch.zeros(1, 1, 2, 3)
        >>> guide[..., 2:] = 1.0  # an edge between the second and third columns
        >>> vertical, horizontal = guide_affinities(guide, 0.1)
        >>> vertical.flatten().tolist(), (horizontal > 1e-6).flatten().tolist()
        ([1.0, 1.0, 1.0], [True, False, True, False])
    """
    check_shape("guide", guide, ["B", "C", "H", "W"])
    refuse_broken([(not sigma > 0, lambda: f"sigma must be > 0, got {sigma!r}")])
    g = guide.clamp_min(0) ** (1 / GUIDE_GAMMA)
    vertical = ((g[..., 1:, :] - g[..., :-1, :]) ** 2).sum(1, keepdim=True)
    horizontal = ((g[..., :, 1:] - g[..., :, :-1]) ** 2).sum(1, keepdim=True)
    return torch.exp(-vertical / (2 * sigma**2)), torch.exp(-horizontal / (2 * sigma**2))


#: Smallest side (pixels) of a map that `edge_aware_smooth` warm-starts from a half-size one.
COARSE_MIN_PX = 64
#: Relative residual the half-size solves of the warm start stop at: a starting point only.
COARSE_TOLERANCE = 1e-6


def _system(x: Tensor, diagonal: Tensor, vertical: Tensor, horizontal: Tensor) -> Tensor:
    """The system matrix applied to `x`: `w x + strength * L x`, `L` the guide's graph
    Laplacian, as its `diagonal` (`w + strength * degree`) less the `strength`-scaled
    affinities to the 4 neighbours (`vertical`, `horizontal`, already times `strength`)."""
    out = diagonal * x
    out[..., 1:, :].addcmul_(vertical, x[..., :-1, :], value=-1)
    out[..., :-1, :].addcmul_(vertical, x[..., 1:, :], value=-1)
    out[..., :, 1:].addcmul_(horizontal, x[..., :, :-1], value=-1)
    out[..., :, :-1].addcmul_(horizontal, x[..., :, 1:], value=-1)
    return out


def _solve(values: Tensor, weight: Tensor, guide: Tensor, strength: float, sigma: float,
           iterations: int, tolerance: float) -> Tensor:
    """`edge_aware_smooth` past its checks: conjugate gradients with a Jacobi preconditioner,
    started from the solution of the half-size problem (`_coarse_start`) on maps of at least
    `COARSE_MIN_PX` a side. The start changes only how soon the residual reaches `tolerance`,
    not the minimiser."""
    vertical, horizontal = guide_affinities(guide, sigma)
    vertical, horizontal = strength * vertical, strength * horizontal
    # the system's diagonal: the Jacobi preconditioner
    diagonal = weight.clone()
    diagonal[..., 1:, :] += vertical
    diagonal[..., :-1, :] += vertical
    diagonal[..., :, 1:] += horizontal
    diagonal[..., :, :-1] += horizontal
    tiny = torch.finfo(values.dtype).tiny
    inverse_diagonal = 1 / diagonal.clamp_min(tiny)

    def dot(a: Tensor, b: Tensor) -> Tensor:  # per image, (B,1,1,1), in one pass
        return torch.bmm(a.flatten(1)[:, None], b.flatten(1)[..., None])[..., None]

    rhs = weight * values
    x = _coarse_start(values, weight, guide, strength, sigma, iterations) \
        if min(values.shape[-2:]) >= COARSE_MIN_PX else values
    residual = rhs - _system(x, diagonal, vertical, horizontal)
    z = inverse_diagonal * residual
    direction = z
    rz = dot(residual, z)
    limit = tolerance**2 * dot(rhs, rhs)
    for _ in range(iterations):
        if bool((dot(residual, residual) <= limit).all()):
            break
        product = _system(direction, diagonal, vertical, horizontal)
        step = rz / dot(direction, product).clamp_min(tiny)
        x = torch.addcmul(x, step, direction)
        residual = torch.addcmul(residual, step, product, value=-1)
        z = inverse_diagonal * residual
        rz_next = dot(residual, z)
        direction = torch.addcmul(z, rz_next / rz.clamp_min(tiny), direction)
        rz = rz_next
    return x


def _coarse_start(values: Tensor, weight: Tensor, guide: Tensor, strength: float, sigma: float,
                  iterations: int) -> Tensor:
    """A starting point for `_solve`: the same least squares on a half-size grid (confidence
    averaged, the map averaged by it, the guide area-averaged, the strength a quarter: a
    neighbour is twice as far), solved to `COARSE_TOLERANCE` and resized back (bilinear). Its
    smooth, far-reaching part is what the fine grid's conjugate gradients are slowest at."""
    size = [(n + 1) // 2 for n in values.shape[-2:]]
    small_weight = F.interpolate(weight, size=size, mode="area")
    small_values = F.interpolate(weight * values, size=size, mode="area") \
        / small_weight.clamp_min(torch.finfo(values.dtype).tiny)
    small_guide = F.interpolate(guide, size=size, mode="area")
    small = _solve(small_values, small_weight, small_guide, strength / 4, sigma, iterations,
                   COARSE_TOLERANCE)
    return F.interpolate(small, size=values.shape[-2:], mode="bilinear", align_corners=False)


def edge_aware_smooth(values: Tensor, weight: Tensor, guide: Tensor, strength: float = 10.0,
                      sigma: float = 0.1, iterations: int = 500,
                      tolerance: float = 1e-6) -> Tensor:
    """The weighted least-squares smoothing of the module docstring.

    Args:
        values: the measured map `y` `(B,1,H,W)` (e.g. inverse depth, 1/metres).
        weight: its confidence `w` `(B,1,H,W)`, >= 0 and positive somewhere in every image.
        guide: image `(B,C,H,W)`, linear intensity in [0, 1], whose edges the result keeps.
        strength: weight of the smoothness term (a confident pixel's value spreads over about
            `sqrt(strength / w)` pixels of similar guide). Zero returns `values`.
        sigma: guide difference (display gamma, per channel) at which neighbours stop being
            alike.
        iterations: most conjugate-gradient steps.
        tolerance: stop once the residual's norm is this fraction of the right-hand side's.

    Returns:
        The smoothed map `(B,1,H,W)`; differentiable in `values`, `weight` and `guide`.

    Example:
        >>> guide = torch.zeros(1, 1, 1, 6)
        >>> guide[..., 3:] = 1.0  # two regions
        >>> values = torch.tensor([[[[1.0, 0.0, 0.0, 5.0, 0.0, 0.0]]]])
        >>> weight = torch.tensor([[[[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]]]])
        >>> edge_aware_smooth(values, weight, guide, strength=1.0).round(decimals=3)
        tensor([[[[1., 1., 1., 5., 5., 5.]]]])
    """
    check_shape("values", values, ["B", "1", "H", "W"])
    check_shape("weight", weight, ["B", "1", "H", "W"])
    check_shape("guide", guide, ["B", "C", "H", "W"])
    shapes = weight.shape != values.shape or guide.shape[-2:] != values.shape[-2:] \
        or guide.shape[0] != values.shape[0]
    refuse_broken([
        (shapes, lambda: f"values {tuple(values.shape)}, weight {tuple(weight.shape)} and guide "
         f"{tuple(guide.shape)} must share batch and size"),
        (not strength >= 0, lambda: f"strength must be >= 0, got {strength!r}"),
        # a value check (it reads the tensor): off where the caller checked (`values_checked`)
        (not shapes and not is_tracing(weight) and (bool((weight < 0).any()) or not bool(
            (weight.flatten(1).amax(1) > 0).all())),
         lambda: "weight must be >= 0 and positive somewhere in every image")])
    if strength == 0:
        return values
    return _solve(values, weight, guide, strength, sigma, iterations, tolerance)
