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
preconditioner (whole-image, no windows: memory grows with the pixels only).
"""

from __future__ import annotations

import torch
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


def _system(x: Tensor, weight: Tensor, strength: float, vertical: Tensor,
            horizontal: Tensor) -> Tensor:
    """The system matrix applied to `x`: `w x + strength * L x`, `L` the guide's graph
    Laplacian."""
    dy = (x[..., 1:, :] - x[..., :-1, :]) * vertical
    dx = (x[..., :, 1:] - x[..., :, :-1]) * horizontal
    laplacian = torch.zeros_like(x)
    laplacian[..., 1:, :] += dy
    laplacian[..., :-1, :] -= dy
    laplacian[..., :, 1:] += dx
    laplacian[..., :, :-1] -= dx
    return weight * x + strength * laplacian


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
    vertical, horizontal = guide_affinities(guide, sigma)
    # Jacobi preconditioner: the system's diagonal
    degree = torch.zeros_like(values)
    degree[..., 1:, :] += vertical
    degree[..., :-1, :] += vertical
    degree[..., :, 1:] += horizontal
    degree[..., :, :-1] += horizontal
    inverse_diagonal = 1 / (weight + strength * degree).clamp_min(torch.finfo(values.dtype).tiny)

    def dot(a: Tensor, b: Tensor) -> Tensor:
        return (a * b).sum((1, 2, 3), keepdim=True)

    rhs = weight * values
    x = values
    residual = rhs - _system(x, weight, strength, vertical, horizontal)
    z = inverse_diagonal * residual
    direction = z
    rz = dot(residual, z)
    limit = tolerance**2 * dot(rhs, rhs)
    for _ in range(iterations):
        if bool((dot(residual, residual) <= limit).all()):
            break
        product = _system(direction, weight, strength, vertical, horizontal)
        step = rz / dot(direction, product).clamp_min(torch.finfo(values.dtype).tiny)
        x = x + step * direction
        residual = residual - step * product
        z = inverse_diagonal * residual
        rz_next = dot(residual, z)
        direction = z + rz_next / rz.clamp_min(torch.finfo(values.dtype).tiny) * direction
        rz = rz_next
    return x
