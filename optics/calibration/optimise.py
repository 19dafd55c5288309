"""The fit (Adam, then L-BFGS) and its uncertainty (Gauss-Newton), over log-space parameters."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from .model import ResidualModel

#: Adam's learning rate in log space.
ADAM_LR = 0.05
#: Central-difference step of the Jacobian, in log space.
JACOBIAN_STEP = 1e-4


class _Closure:
    """L-BFGS's closure: the loss at the current `theta`, with its gradient."""

    def __init__(self, optimiser: torch.optim.Optimizer, loss: Callable[[Tensor], Tensor],
                 theta: Tensor):
        self.optimiser, self.loss, self.theta = optimiser, loss, theta

    def __call__(self) -> Tensor:
        self.optimiser.zero_grad()
        value = self.loss(self.theta)
        value.backward()
        return value


def optimise(loss: Callable[[Tensor], Tensor], theta0: Tensor, adam_steps: int,
             lbfgs_steps: int, progress: bool = False) -> Tensor:
    """Minimise `loss` from `theta0`: `adam_steps` of Adam, then up to `lbfgs_steps` L-BFGS
    iterations (strong Wolfe line search). Returns the detached minimiser."""
    from ..progress import progress_bar

    theta = theta0.clone().requires_grad_(True)
    bar = progress_bar(total=adam_steps + lbfgs_steps, desc="calibrating", disable=not progress)
    adam = torch.optim.Adam([theta], lr=ADAM_LR)
    for _ in range(adam_steps):
        adam.zero_grad()
        value = loss(theta)
        value.backward()
        adam.step()
        bar.update(1)
        bar.set_postfix(loss=f"{value.item():.3g}", refresh=False)
    if lbfgs_steps > 0:
        lbfgs = torch.optim.LBFGS(
            [theta], lr=1, max_iter=lbfgs_steps, line_search_fn="strong_wolfe",
            tolerance_grad=1e-12, tolerance_change=1e-15,
        )
        lbfgs.step(_Closure(lbfgs, loss, theta))
        bar.update(lbfgs_steps)
    bar.close()
    return theta.detach()


@dataclass
class Fit:
    """The residuals at the optimum and the covariance of `theta`.

    Attributes:
        residuals: each pair's interior residual.
        gains: each pair's exposure gain.
        flat: every residual in one vector.
        covariance: `(k, k)` covariance of `theta` (inf where singular).
        singular: whether the fit leaves some fitted parameter undetermined.
    """

    residuals: list[Tensor]
    gains: list[Tensor]
    flat: Tensor
    covariance: Tensor
    singular: bool

    @property
    def rmse(self) -> float:
        return float(self.flat.pow(2).mean().sqrt())


def jacobian(model: ResidualModel, theta: Tensor, step: float = JACOBIAN_STEP) -> Tensor:
    """`(n_residuals, k)` Jacobian of the residuals by central differences in `theta`."""
    columns = []
    for i in range(theta.numel()):
        delta = torch.zeros_like(theta)
        delta[i] = step
        columns.append((model.flat(theta + delta) - model.flat(theta - delta)) / (2 * step))
    return torch.stack(columns, 1)


@torch.no_grad()
def gauss_newton(model: ResidualModel, theta: Tensor) -> Fit:
    """Residuals at `theta` and the Gauss-Newton covariance `sigma^2 (J^T J)^{-1}`, `sigma^2`
    the residual variance over the degrees of freedom (pixels less parameters and gains)."""
    res, gains = model.residuals(theta)
    flat = torch.cat([r.reshape(-1) for r in res])
    k = theta.numel()
    n_gains = len(res) if model.problem.fit_gain else 0
    dof = max(flat.numel() - k - n_gains, 1)
    variance = flat.pow(2).sum() / dof
    j = jacobian(model, theta)
    normal = j.T @ j
    singular = bool(torch.linalg.matrix_rank(normal) < k)
    covariance = (torch.full_like(normal, float("inf")) if singular
                  else variance * torch.linalg.inv(normal))
    return Fit(res, gains, flat, covariance, singular)
