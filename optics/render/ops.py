"""Memory-lean spatially varying filters behind `optics.render_defocus`, as PyTorch operators.

The filters are *linear* in the image `x` `(B,C,H,W)`; the renderer builds its normalised and
layered semantics on top of them with ordinary autograd. None stores per-offset weights: the
forward loops over the `K*K` window offsets accumulating in place, and the backward recomputes
the weights, so the extra memory is a few `(B,C,H,W)` maps whatever `K` is.

- Gaussian (`gaussian_scatter`, `gaussian_gather`, `gaussian_norm`): each *source* pixel `q`
  spreads `norm_q * exp(-|p-q|^2 / (2 sigma_q^2)) * x_q` to every output `p` in its window. The
  weight factorises per source, `t_q(dy) t_q(dx)`, so a per-source table of `K/2 + 1` values
  replaces an `exp` per tap.
- Clamped distance (`clamp_scatter`, `clamp_gather`, `clamp_norm`): the disk and the polygons,
  `w_q(u) = clamp(rho_q - D(u), 0, 1)` with `rho_q = edge_radius(c_q) + 1/2` and `D` the
  aperture's distance function tabulated once per call on the window (it does not depend on the
  CoC). This is exactly `Disk.profile`; the gradient reaches the CoC and the aperture's
  parameters through `rho` with ordinary autograd.
- `ProfileFilter`: any other `Aperture` (e.g. `Mask`) through its `profile`, tabulated once per
  call in the CoC and interpolated per pixel, window offset by window offset in PyTorch
  (`optics.render.profile`); not a custom operator, so `torch.compile` breaks the graph there.

The Gaussian and clamped-distance filters are `torch.library` custom operators in the `defocus`
namespace, with fake (meta) implementations and registered autograd, so `torch.compile` traces
them, forward and backward, without graph breaks. Each runs the compiled C++ kernel
(`optics.render.cpp`) on CPU when it is available, Triton kernels on CUDA for the fused scatter
and the unnormalised spreads (`optics.render.triton_kernels`, registered by
`optics.render.backends` where Triton is installed), and the PyTorch loop below otherwise. The
window half-width is passed as a 0-d integer tensor: under `torch.compile` it is computed from
the CoC map inside the graph.

Taps whose source or output falls outside the image are skipped.
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import cpp
from .taps import distinct, gaussian_table, window, window_taps


def _gaussian_scatter_forward_torch(x: Tensor, sigma: Tensor, norm: Tensor, half: int) -> Tensor:
    table = gaussian_table(sigma, half)
    xn = x * norm
    out = torch.zeros_like(x)
    weight = torch.empty_like(sigma)
    _, _, h, w = x.shape
    for dy, dx, src, dst in window_taps(half, h, w):
        torch.mul(table[abs(dy)], table[abs(dx)], out=weight)
        out[dst].addcmul_(weight[src], xn[src])
    return out


def _gaussian_scatter_backward_torch(
    grad: Tensor, x: Tensor, sigma: Tensor, half: int
) -> tuple[Tensor, Tensor]:
    """`(sum_u t(u) g(q+u), sum_c x_c(q) sum_u t(u) |u|^2 g_c(q+u))` with unit-norm weights."""
    table = gaussian_table(sigma, half)
    dx_raw = torch.zeros_like(x)
    f_raw = torch.zeros_like(x)
    weight = torch.empty_like(sigma)
    _, _, h, w = x.shape
    for dy, dx, src, dst in window_taps(half, h, w):
        torch.mul(table[abs(dy)], table[abs(dx)], out=weight)
        dx_raw[src].addcmul_(weight[src], grad[dst])
        f_raw[src].addcmul_(weight[src], grad[dst], value=float(dy * dy + dx * dx))
    return dx_raw, (f_raw * x).sum(1, keepdim=True)


def _clamp_scatter_forward_torch(
    x: Tensor, rho: Tensor, norm: Tensor, dist: Tensor, half: int
) -> Tensor:
    """`y(p) = sum_q norm_q clamp(rho_q - D(p-q), 0, 1) x(q)`; `dist` is the `K x K` table of D."""
    table = dist.tolist()
    xn = x * norm
    out = torch.zeros_like(x)
    weight = torch.empty_like(rho)
    _, _, h, w = x.shape
    for dy, dx, src, dst in window_taps(half, h, w):
        torch.sub(rho, table[dy + half][dx + half], out=weight).clamp_(0.0, 1.0)
        out[dst].addcmul_(weight[src], xn[src])
    return out


def _clamp_scatter_backward_torch(
    grad: Tensor, x: Tensor, rho: Tensor, dist: Tensor, half: int
) -> tuple[Tensor, Tensor]:
    """`(sum_u w(u) g(q+u), sum_c x_c(q) sum_u [0 <= rho_q - D(u) <= 1] g_c(q+u))`."""
    table = dist.tolist()
    dx_raw = torch.zeros_like(x)
    f_raw = torch.zeros_like(x)
    t = torch.empty_like(rho)
    _, _, h, w = x.shape
    for dy, dx, src, dst in window_taps(half, h, w):
        torch.sub(rho, table[dy + half][dx + half], out=t)
        inside = ((t >= 0) & (t <= 1)).to(t.dtype)
        dx_raw[src].addcmul_(t.clamp(0.0, 1.0)[src], grad[dst])
        f_raw[src].addcmul_(inside[src], grad[dst])
    return dx_raw, (f_raw * x).sum(1, keepdim=True)


def _clamp_window_sums_torch(rho: Tensor, dists: Tensor, counts: Tensor) -> tuple[Tensor, Tensor]:
    """`Z = sum_j n_j clamp(rho - d_j, 0, 1)` and `dZ/drho` over distinct window distances `d_j`."""
    total = torch.zeros_like(rho)
    slope = torch.zeros_like(rho)
    for d, n in zip(dists.tolist(), counts.tolist(), strict=True):
        t = rho - d
        total.add_(t.clamp(0.0, 1.0), alpha=n)
        slope.add_(((t >= 0) & (t <= 1)).to(t.dtype), alpha=n)
    return total, slope


def _dispatch(compiled, pure, args: tuple[Tensor, ...], half: Tensor, image: int = 0,
              dist: Tensor | None = None):
    """`compiled(*args, [table], k)` where the compiled kernels take the image `args[image]`, else
    its PyTorch twin `pure` on the same arguments: `args` made contiguous, `k = int(half)`, and
    `dist` (if given) cut to the window `table` (cast to the image's dtype for the kernel)."""
    k = int(half)
    args = tuple(a.contiguous() for a in args)
    tables = () if dist is None else (window(dist, k),)
    x = args[image]
    if cpp.usable(x):
        return compiled(*args, *(t.to(x.dtype) for t in tables), k)
    return pure(*args, *tables, k)


# ------------------------------------------------------------------ custom operators
# Every operator takes the window half-width as a 0-d integer tensor `half`.


@torch.library.custom_op("defocus::gaussian_scatter", mutates_args=())
def gaussian_scatter(x: Tensor, sigma: Tensor, norm: Tensor, half: Tensor) -> Tensor:
    """`y(p) = sum_q norm_q exp(-|p-q|^2 / (2 sigma_q^2)) x(q)` over `|p-q|_inf <= half`.

    Inputs: `x` `(B,C,H,W)`, `sigma` and `norm` `(B,1,H,W)` (pixels, and any per-source
    factor). Differentiable in `x`, `sigma` and `norm`.
    """
    return _dispatch(cpp.gaussian_scatter_forward, _gaussian_scatter_forward_torch,
                     (x, sigma, norm), half)


@torch.library.custom_op("defocus::gaussian_scatter_backward", mutates_args=())
def gaussian_scatter_backward(
    grad: Tensor, x: Tensor, sigma: Tensor, half: Tensor
) -> tuple[Tensor, Tensor]:
    """`(dx_raw, m1)`: `sum_u t(u) g(q+u)` and `sum_c x_c(q) sum_u t(u) |u|^2 g_c(q+u)`."""
    return _dispatch(cpp.gaussian_scatter_backward, _gaussian_scatter_backward_torch,
                     (grad, x, sigma), half, image=1)


@torch.library.custom_op("defocus::gaussian_gather", mutates_args=())
def gaussian_gather(x: Tensor, sigma: Tensor, half: Tensor) -> Tensor:
    """`y(p) = sum_q exp(-|p-q|^2 / (2 sigma_p^2)) x(q)`: the Gaussian of the *output* pixel."""
    return gaussian_scatter_backward(x, x, sigma, half)[0].clone()


@torch.library.custom_op("defocus::gaussian_window_sums", mutates_args=())
def gaussian_window_sums(sigma: Tensor, half: Tensor) -> tuple[Tensor, Tensor]:
    """`sum_d t(d)` and `sum_d t(d) d^2` over `d = -half..half` per pixel."""
    sigma, k = sigma.contiguous(), int(half)
    if cpp.usable(sigma):
        return cpp.window_sums(sigma, k)
    line = torch.ones_like(sigma)
    moment = torch.zeros_like(sigma)
    scale = -0.5 / (sigma * sigma)
    term = torch.empty_like(sigma)
    for d in range(1, k + 1):
        torch.mul(scale, float(d * d), out=term).exp_().mul_(2)
        line += term
        moment.add_(term, alpha=float(d * d))
    return line, moment


@torch.library.custom_op("defocus::gaussian_norm", mutates_args=())
def gaussian_norm(sigma: Tensor, half: Tensor) -> Tensor:
    """`1 / Z`, `Z = (sum_{d=-half..half} exp(-d^2 / (2 sigma^2)))^2`: unit energy per source."""
    return gaussian_window_sums(sigma, half)[0].pow(-2)


@torch.library.custom_op("defocus::clamp_scatter", mutates_args=())
def clamp_scatter(x: Tensor, rho: Tensor, norm: Tensor, dist: Tensor, half: Tensor) -> Tensor:
    """`y(p) = sum_q norm_q clamp(rho_q - D(p-q), 0, 1) x(q)` over `|p-q|_inf <= half`.

    `dist` is D on a square window at least as wide as `2 half + 1` (its centre is used).
    Differentiable in `x`, `rho` and `norm`.
    """
    return _dispatch(cpp.clamp_scatter_forward, _clamp_scatter_forward_torch,
                     (x, rho, norm), half, dist=dist)


@torch.library.custom_op("defocus::clamp_scatter_backward", mutates_args=())
def clamp_scatter_backward(
    grad: Tensor, x: Tensor, rho: Tensor, dist: Tensor, half: Tensor
) -> tuple[Tensor, Tensor]:
    """`(dx_raw, m)`: the image and `rho` parts of the clamp scatter's vector-Jacobian product."""
    return _dispatch(cpp.clamp_scatter_backward, _clamp_scatter_backward_torch,
                     (grad, x, rho), half, image=1, dist=dist)


@torch.library.custom_op("defocus::clamp_gather", mutates_args=())
def clamp_gather(x: Tensor, rho: Tensor, dist: Tensor, half: Tensor) -> Tensor:
    """`y(p) = sum_q clamp(rho_p - D(p-q), 0, 1) x(q)`: the profile of the *output* pixel."""
    return clamp_scatter_backward(x, x, rho, dist.flip(-2, -1), half)[0].clone()


@torch.library.custom_op("defocus::clamp_window_sums", mutates_args=())
def clamp_window_sums(rho: Tensor, dist: Tensor, half: Tensor) -> tuple[Tensor, Tensor]:
    """`Z = sum_u clamp(rho - D(u), 0, 1)` over the window and `dZ/drho`, per pixel."""
    rho = rho.contiguous()
    dists, counts = torch.unique(window(dist, int(half)), return_counts=True)
    if cpp.usable(rho):
        dists = dists.to(rho.dtype).contiguous()
        return cpp.clamp_window_sums(rho, dists, counts.to(rho.dtype).contiguous())
    return _clamp_window_sums_torch(rho, dists, counts)


@torch.library.custom_op("defocus::clamp_norm", mutates_args=())
def clamp_norm(rho: Tensor, dist: Tensor, half: Tensor) -> Tensor:
    """`1 / Z`, `Z` the clamped profile's sum over the source's whole window."""
    return clamp_window_sums(rho, dist, half)[0].reciprocal()


# Fused, normalised scatter: `y = s[:C] / s[C]` with `s` the scatter of `(x, 1)` at unit energy per
# source, and `den = s[C]`, in one kernel each way (the renderer's "scatter" mode).


def _ones_channel(x: Tensor) -> Tensor:
    return torch.cat([x, torch.ones_like(x[:, :1])], 1)


def _normalised(spread: Tensor) -> tuple[Tensor, Tensor]:
    den = spread[:, -1:].clone()
    return (spread[:, :-1] / den).contiguous(), den


def grad_of_spread(grad: Tensor, y: Tensor, den: Tensor) -> Tensor:
    """`dL/ds` from `dL/dy` for `y = s[:C] / s[C]` (`den = s[C]`).

    Example:
        >>> y, den = torch.ones(1, 1, 1, 1), torch.full((1, 1, 1, 1), 2.0)
        >>> grad_of_spread(torch.ones(1, 1, 1, 1), y, den).flatten()
        tensor([ 0.5000, -0.5000])
    """
    return torch.cat([grad / den, -(grad * y).sum(1, keepdim=True) / den], 1).contiguous()


@torch.library.custom_op("defocus::gaussian_render", mutates_args=())
def gaussian_render(x: Tensor, sigma: Tensor, half: Tensor) -> tuple[Tensor, Tensor]:
    """`(y, den)`: the normalised Gaussian scatter of `x` and the weight each output receives."""
    x, sigma, k = x.contiguous(), sigma.contiguous(), int(half)
    if cpp.usable(x):
        return cpp.gaussian_render(x, sigma, k)
    norm = gaussian_window_sums(sigma, half)[0].pow(-2)
    return _normalised(_gaussian_scatter_forward_torch(_ones_channel(x), sigma, norm, k))


@torch.library.custom_op("defocus::gaussian_render_backward", mutates_args=())
def gaussian_render_backward(
    grad: Tensor, y: Tensor, den: Tensor, x: Tensor, sigma: Tensor, half: Tensor
) -> tuple[Tensor, Tensor]:
    """`(dL/dx, dL/dsigma)` of `gaussian_render` from `dL/dy`."""
    grad, x, sigma, k = grad.contiguous(), x.contiguous(), sigma.contiguous(), int(half)
    if cpp.usable(x):
        return cpp.gaussian_render_backward(grad, y.contiguous(), den.contiguous(), x, sigma, k)
    ones = _ones_channel(x)
    dx_raw, m1 = _gaussian_scatter_backward_torch(grad_of_spread(grad, y, den), ones, sigma, k)
    line, moment = gaussian_window_sums(sigma, half)
    norm = line.pow(-2)
    dnorm = -2 * moment / (sigma**3 * line**3)
    grad_sigma = norm * m1 / sigma**3 + (ones * dx_raw).sum(1, keepdim=True) * dnorm
    return (dx_raw[:, :-1] * norm).contiguous(), grad_sigma


@torch.library.custom_op("defocus::clamp_render", mutates_args=())
def clamp_render(x: Tensor, rho: Tensor, dist: Tensor, half: Tensor) -> tuple[Tensor, Tensor]:
    """`(y, den)`: the normalised clamped-distance scatter of `x` (disk, polygons)."""
    k = int(half)
    x, rho, table = x.contiguous(), rho.contiguous(), window(dist, k).to(x.dtype)
    if cpp.usable(x):
        return cpp.clamp_render(x, rho, table, *distinct(table), k)
    norm = clamp_window_sums(rho, dist, half)[0].reciprocal()
    return _normalised(_clamp_scatter_forward_torch(_ones_channel(x), rho, norm, table, k))


@torch.library.custom_op("defocus::clamp_render_backward", mutates_args=())
def clamp_render_backward(
    grad: Tensor, y: Tensor, den: Tensor, x: Tensor, rho: Tensor, dist: Tensor, half: Tensor
) -> tuple[Tensor, Tensor]:
    """`(dL/dx, dL/drho)` of `clamp_render` from `dL/dy`."""
    k = int(half)
    grad, x, rho, table = grad.contiguous(), x.contiguous(), rho.contiguous(), window(dist, k)
    table = table.to(x.dtype)
    if cpp.usable(x):
        return cpp.clamp_render_backward(grad, y.contiguous(), den.contiguous(), x, rho, table,
                                         *distinct(table), k)
    ones = _ones_channel(x)
    dx_raw, m = _clamp_scatter_backward_torch(grad_of_spread(grad, y, den), ones, rho, table, k)
    total, slope = clamp_window_sums(rho, dist, half)
    norm = total.reciprocal()
    grad_rho = norm * m - (ones * dx_raw).sum(1, keepdim=True) * slope / (total * total)
    return (dx_raw[:, :-1] * norm).contiguous(), grad_rho


# ------------------------------------------------------------------ fake implementations


@gaussian_scatter.register_fake
def _(x, sigma, norm, half):
    return torch.empty_like(x)


@gaussian_scatter_backward.register_fake
def _(grad, x, sigma, half):
    return torch.empty_like(x), torch.empty_like(sigma)


@gaussian_gather.register_fake
def _(x, sigma, half):
    return torch.empty_like(x)


@gaussian_window_sums.register_fake
def _(sigma, half):
    return torch.empty_like(sigma), torch.empty_like(sigma)


@gaussian_norm.register_fake
def _(sigma, half):
    return torch.empty_like(sigma)


@clamp_scatter.register_fake
def _(x, rho, norm, dist, half):
    return torch.empty_like(x)


@clamp_scatter_backward.register_fake
def _(grad, x, rho, dist, half):
    return torch.empty_like(x), torch.empty_like(rho)


@clamp_gather.register_fake
def _(x, rho, dist, half):
    return torch.empty_like(x)


@clamp_window_sums.register_fake
def _(rho, dist, half):
    return torch.empty_like(rho), torch.empty_like(rho)


@clamp_norm.register_fake
def _(rho, dist, half):
    return torch.empty_like(rho)


@gaussian_render.register_fake
def _(x, sigma, half):
    return torch.empty_like(x), torch.empty_like(sigma)


@gaussian_render_backward.register_fake
def _(grad, y, den, x, sigma, half):
    return torch.empty_like(x), torch.empty_like(sigma)


@clamp_render.register_fake
def _(x, rho, dist, half):
    return torch.empty_like(x), torch.empty_like(rho)


@clamp_render_backward.register_fake
def _(grad, y, den, x, rho, dist, half):
    return torch.empty_like(x), torch.empty_like(rho)


# ------------------------------------------------------------------ autograd


def _save_all(ctx, inputs, output) -> None:
    ctx.save_for_backward(*inputs)


def _gaussian_scatter_vjp(ctx, grad):
    x, sigma, norm, half = ctx.saved_tensors
    dx_raw, m1 = gaussian_scatter_backward(grad, x, sigma, half)
    return dx_raw * norm, norm * m1 / sigma**3, (x * dx_raw).sum(1, keepdim=True), None


def _gaussian_gather_vjp(ctx, grad):
    x, sigma, half = ctx.saved_tensors
    grad_x = gaussian_scatter(grad, sigma, torch.ones_like(sigma), half)
    # d y_c(p) / d sigma_p = sum_q |p-q|^2 / sigma_p^3 t_p(p-q) x_c(q)
    grad_sigma = gaussian_scatter_backward(x, grad, sigma, half)[1] / sigma**3
    return grad_x, grad_sigma, None


def _gaussian_norm_vjp(ctx, grad):
    sigma, half = ctx.saved_tensors
    line, moment = gaussian_window_sums(sigma, half)
    # d(S^-2)/d sigma = -2 S^-3 dS/d sigma, dS/d sigma = sum_d t(d) d^2 / sigma^3
    return grad * (-2) * moment / (sigma**3 * line**3), None


def _clamp_scatter_vjp(ctx, grad):
    x, rho, norm, dist, half = ctx.saved_tensors
    dx_raw, m = clamp_scatter_backward(grad, x, rho, dist, half)
    return dx_raw * norm, norm * m, (x * dx_raw).sum(1, keepdim=True), None, None


def _clamp_gather_vjp(ctx, grad):
    x, rho, dist, half = ctx.saved_tensors
    flipped = dist.flip(-2, -1)
    grad_x = clamp_scatter(grad, rho, torch.ones_like(rho), flipped, half)
    grad_rho = clamp_scatter_backward(x, grad, rho, flipped, half)[1]
    return grad_x, grad_rho, None, None


def _clamp_norm_vjp(ctx, grad):
    rho, dist, half = ctx.saved_tensors
    total, slope = clamp_window_sums(rho, dist, half)
    return -grad * slope / (total * total), None, None


gaussian_scatter.register_autograd(_gaussian_scatter_vjp, setup_context=_save_all)
gaussian_gather.register_autograd(_gaussian_gather_vjp, setup_context=_save_all)
gaussian_norm.register_autograd(_gaussian_norm_vjp, setup_context=_save_all)
clamp_scatter.register_autograd(_clamp_scatter_vjp, setup_context=_save_all)
clamp_gather.register_autograd(_clamp_gather_vjp, setup_context=_save_all)
clamp_norm.register_autograd(_clamp_norm_vjp, setup_context=_save_all)


def _save_render(ctx, inputs, output) -> None:
    ctx.save_for_backward(*inputs, *output)


def _gaussian_render_vjp(ctx, grad_y, grad_den):
    # `den` is an auxiliary output for the backward pass; its gradient is not propagated.
    x, sigma, half, y, den = ctx.saved_tensors
    grad_x, grad_sigma = gaussian_render_backward(grad_y, y, den, x, sigma, half)
    return grad_x, grad_sigma, None


def _clamp_render_vjp(ctx, grad_y, grad_den):
    x, rho, dist, half, y, den = ctx.saved_tensors
    grad_x, grad_rho = clamp_render_backward(grad_y, y, den, x, rho, dist, half)
    return grad_x, grad_rho, None, None


gaussian_render.register_autograd(_gaussian_render_vjp, setup_context=_save_render)
clamp_render.register_autograd(_clamp_render_vjp, setup_context=_save_render)
