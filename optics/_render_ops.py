"""Memory-lean spatially varying filters behind :func:`optics.render_defocus`.

Both filters are *linear* in the image ``x`` ``(B,C,H,W)``; the renderer builds its normalised and
layered semantics on top of them with ordinary autograd. Neither stores per-offset weights: the
forward loops over the ``K*K`` window offsets accumulating in place, and a custom backward
recomputes the weights, so the extra memory is a few ``(B,C,H,W)`` maps whatever ``K`` is.

- :class:`GaussianScatter`: each *source* pixel ``q`` spreads ``norm_q * exp(-|p-q|^2 / (2
  sigma_q^2)) * x_q`` to every output ``p`` in its window. The weight factorises per source,
  ``t_q(dy) t_q(dx)``, so a per-source table of ``K/2 + 1`` values replaces an ``exp`` per tap.
  A compiled C++ kernel (:mod:`optics._render_cpp`) runs it on CPU when it builds; otherwise (and on
  other devices) the PyTorch loop below does.
- :class:`GaussianGather`: the same with the output pixel's Gaussian (its transpose).
- :class:`ProfileFilter`: any :class:`~optics.Aperture` through its ``profile``; weights indexed by
  the source pixel (scatter, each source normalised to unit energy over its discrete window) or by
  the output pixel (gather). Gradients reach the CoC map and the aperture's parameters.

Taps whose source or output falls outside the image are skipped.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from . import _render_cpp


def axis_slices(shift: int, size: int) -> tuple[slice, slice] | None:
    """Slices ``(source, output)`` along an axis of ``size`` pixels for ``output = source + shift``.

    ``None`` when no pixel pair is inside the image.
    """
    if abs(shift) >= size:
        return None
    if shift >= 0:
        return slice(0, size - shift), slice(shift, size)
    return slice(-shift, size), slice(0, size + shift)


def window_taps(half: int, height: int, width: int):
    """Yield ``(dy, dx, source_index, output_index)`` for every in-image offset of the window."""
    for dy in range(-half, half + 1):
        rows = axis_slices(dy, height)
        if rows is None:
            continue
        for dx in range(-half, half + 1):
            cols = axis_slices(dx, width)
            if cols is None:
                continue
            yield dy, dx, (..., rows[0], cols[0]), (..., rows[1], cols[1])


def gaussian_table(sigma: Tensor, half: int) -> Tensor:
    """``exp(-d^2 / (2 sigma^2))`` for ``d = 0..half``, stacked: ``(half+1, *sigma.shape)``."""
    d = torch.arange(half + 1, device=sigma.device, dtype=sigma.dtype)
    d = d.view(-1, *([1] * sigma.ndim))
    return torch.exp(-(d * d) / (2 * sigma * sigma))


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
    """``(sum_u t(u) g(q+u), sum_c x_c(q) sum_u t(u) |u|^2 g_c(q+u))`` with unit-norm weights."""
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


class GaussianScatter(torch.autograd.Function):
    """``y(p) = sum_q norm_q exp(-|p-q|^2 / (2 sigma_q^2)) x(q)`` over ``|p-q|_inf <= half``.

    Inputs: ``x`` ``(B,C,H,W)``, ``sigma`` and ``norm`` ``(B,1,H,W)`` (pixels, and any per-source
    factor), ``half`` (int). Differentiable in ``x``, ``sigma`` and ``norm``.
    """

    @staticmethod
    def forward(ctx, x: Tensor, sigma: Tensor, norm: Tensor, half: int) -> Tensor:
        x, sigma, norm = x.contiguous(), sigma.contiguous(), norm.contiguous()
        ctx.save_for_backward(x, sigma, norm)
        ctx.half = half
        return _scatter_forward(x, sigma, norm, half)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad: Tensor):
        x, sigma, norm = ctx.saved_tensors
        grad = grad.contiguous()
        dx_raw, m1 = _scatter_backward(grad, x, sigma, ctx.half)
        grad_x = dx_raw * norm if ctx.needs_input_grad[0] else None
        grad_sigma = norm * m1 / sigma**3 if ctx.needs_input_grad[1] else None
        grad_norm = (x * dx_raw).sum(1, keepdim=True) if ctx.needs_input_grad[2] else None
        return grad_x, grad_sigma, grad_norm, None


class GaussianGather(torch.autograd.Function):
    """``y(p) = sum_q exp(-|p-q|^2 / (2 sigma_p^2)) x(q)``: the Gaussian of the *output* pixel.

    The transpose of :class:`GaussianScatter`, so it reuses its two kernels: the forward is the
    scatter backward's ``dx_raw`` (with ``x`` as the gradient), the backward a scatter forward.
    """

    @staticmethod
    def forward(ctx, x: Tensor, sigma: Tensor, half: int) -> Tensor:
        x, sigma = x.contiguous(), sigma.contiguous()
        ctx.save_for_backward(x, sigma)
        ctx.half = half
        return _scatter_backward(x, x, sigma, half)[0]

    @staticmethod
    @once_differentiable
    def backward(ctx, grad: Tensor):
        x, sigma = ctx.saved_tensors
        grad = grad.contiguous()
        grad_x = grad_sigma = None
        if ctx.needs_input_grad[0]:
            grad_x = _scatter_forward(grad, sigma, torch.ones_like(sigma), ctx.half)
        if ctx.needs_input_grad[1]:
            # d y_c(p) / d sigma_p = sum_q |p-q|^2 / sigma_p^3 t_p(p-q) x_c(q)
            grad_sigma = _scatter_backward(x, grad, sigma, ctx.half)[1] / sigma**3
        return grad_x, grad_sigma, None


def _scatter_forward(x: Tensor, sigma: Tensor, norm: Tensor, half: int) -> Tensor:
    if _render_cpp.usable(x):
        return _render_cpp.gaussian_scatter_forward(x, sigma, norm, half)
    return _gaussian_scatter_forward_torch(x, sigma, norm, half)


def _scatter_backward(grad: Tensor, x: Tensor, sigma: Tensor, half: int) -> tuple[Tensor, Tensor]:
    if _render_cpp.usable(x):
        return _render_cpp.gaussian_scatter_backward(grad, x, sigma, half)
    return _gaussian_scatter_backward_torch(grad, x, sigma, half)


class InverseWindowSum(torch.autograd.Function):
    """``1 / Z`` with ``Z = (sum_{d=-half..half} exp(-d^2 / (2 sigma^2)))^2`` per pixel.

    The discrete total of a separable Gaussian window: dividing by it makes each source spread
    unit energy over its window. A custom backward keeps the memory at one map whatever ``half``.
    """

    @staticmethod
    def forward(ctx, sigma: Tensor, half: int) -> Tensor:
        ctx.save_for_backward(sigma)
        ctx.half = half
        line, _ = _window_line_sums(sigma, half)
        return line.pow_(-2)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad: Tensor):
        (sigma,) = ctx.saved_tensors
        line, moment = _window_line_sums(sigma, ctx.half)
        # d(S^-2)/d sigma = -2 S^-3 dS/d sigma, dS/d sigma = sum_d t(d) d^2 / sigma^3
        return grad * (-2) * moment / (sigma**3 * line**3), None


def _window_line_sums(sigma: Tensor, half: int) -> tuple[Tensor, Tensor]:
    """``sum_d t(d)`` and ``sum_d t(d) d^2`` over ``d = -half..half``, in place (no autograd)."""
    sigma = sigma.contiguous()
    if _render_cpp.usable(sigma):
        return _render_cpp.window_sums(sigma, half)
    line = torch.ones_like(sigma)
    moment = torch.zeros_like(sigma)
    scale = -0.5 / (sigma * sigma)
    term = torch.empty_like(sigma)
    for d in range(1, half + 1):
        torch.mul(scale, float(d * d), out=term).exp_().mul_(2)
        line += term
        moment.add_(term, alpha=float(d * d))
    return line, moment


def _profile_normaliser(psf, coc: Tensor, half: int) -> Tensor:
    """Discrete sum of a source's profile over its whole ``(2 half + 1)^2`` window."""
    total = torch.zeros_like(coc)
    for dy in range(-half, half + 1):
        for dx in range(-half, half + 1):
            total = total + psf.profile(_scalar(dy, coc), _scalar(dx, coc), coc)
    return total


def _scalar(value: int, like: Tensor) -> Tensor:
    return torch.tensor(float(value), dtype=like.dtype, device=like.device)


class ProfileFilter(torch.autograd.Function):
    """Linear filter with per-pixel weights ``psf.profile(u; coc)``.

    ``scatter=True``: ``y(p) = sum_q x(q) P(p-q; coc_q) / Z_q``, ``Z_q`` the profile's sum over the
    source's full window (each source spreads unit energy). ``scatter=False`` (gather):
    ``y(p) = sum_q x(q) P(p-q; coc_p)``, unnormalised. Extra inputs ``params`` are the aperture's
    trainable parameters, so that gradients reach them.
    """

    @staticmethod
    def forward(ctx, x, coc, psf, scatter: bool, half: int, *params):
        x, coc = x.contiguous(), coc.contiguous()
        _, _, h, w = x.shape
        out = torch.zeros_like(x)
        norm = _profile_normaliser(psf, coc, half) if scatter else None
        xs = x / norm if scatter else x
        for dy, dx, src, dst in window_taps(half, h, w):
            if scatter:  # the source's PSF at offset output - source
                weight = psf.profile(_scalar(dy, coc), _scalar(dx, coc), coc[src])
            else:  # the output's PSF, also at offset output - source (a convolution)
                weight = psf.profile(_scalar(dy, coc), _scalar(dx, coc), coc[dst])
            out[dst].addcmul_(weight, xs[src])
        ctx.save_for_backward(x, coc, *((norm,) if scatter else ()))
        ctx.psf, ctx.scatter, ctx.half, ctx.n_params = psf, scatter, half, len(params)
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx, grad):
        x, coc, *rest = ctx.saved_tensors
        psf, scatter, half = ctx.psf, ctx.scatter, ctx.half
        norm = rest[0] if scatter else None
        params = [p for p in psf.parameters() if p.requires_grad]
        if len(params) != ctx.n_params:
            raise RuntimeError("the aperture's trainable parameters changed during backward")
        grad = grad.contiguous()
        _, _, h, w = x.shape
        grad_x = torch.zeros_like(x)
        grad_coc = torch.zeros_like(coc)
        grad_params = [torch.zeros_like(p) for p in params]
        # a_u at the weight's pixel: d loss / d weight_u = sum_c x_c(source) g_c(output).
        if scatter:
            mean_a = torch.zeros_like(coc)  # sum_u a_u W_u, for the derivative of 1/Z
            with torch.no_grad():
                for dy, dx, src, dst in window_taps(half, h, w):
                    weight = psf.profile(_scalar(dy, coc), _scalar(dx, coc), coc[src]) / norm[src]
                    grad_x[src].addcmul_(weight, grad[dst])
                    a = (x[src] * grad[dst]).sum(1, keepdim=True)
                    mean_a[src].addcmul_(a, weight)
        if scatter:
            # d/dcoc of W_u = P_u / Z: sum_{u in image} P'_u a_u / Z - (S / Z) sum_{all u} P'_u,
            # so every window offset is visited on the whole map (Z counts taps off the image).
            minus_s_over_z = -mean_a / norm
            for dy in range(-half, half + 1):
                for dx in range(-half, half + 1):
                    upstream = minus_s_over_z.clone()
                    rows, cols = axis_slices(dy, h), axis_slices(dx, w)
                    if rows is not None and cols is not None:
                        src, dst = (..., rows[0], cols[0]), (..., rows[1], cols[1])
                        a = (x[src] * grad[dst]).sum(1, keepdim=True)
                        upstream[src] += a / norm[src]
                    _accumulate_vjp(psf, dy, dx, coc, upstream, grad_coc, params, grad_params)
        else:
            for dy, dx, src, dst in window_taps(half, h, w):
                with torch.no_grad():
                    weight = psf.profile(_scalar(dy, coc), _scalar(dx, coc), coc[dst])
                    grad_x[src].addcmul_(weight, grad[dst])
                    upstream = torch.zeros_like(coc)
                    upstream[dst] = (x[src] * grad[dst]).sum(1, keepdim=True)
                _accumulate_vjp(psf, dy, dx, coc, upstream, grad_coc, params, grad_params)
        return (grad_x, grad_coc, None, None, None, *grad_params)


def _accumulate_vjp(psf, dy, dx, coc, upstream, grad_coc, params, grad_params) -> None:
    """Add ``upstream * d profile(dy, dx; coc) / d(coc, params)`` to the gradient accumulators."""
    with torch.enable_grad():
        leaf = coc.detach().requires_grad_(True)
        weight = psf.profile(_scalar(dy, coc), _scalar(dx, coc), leaf)
        grads = torch.autograd.grad(weight, [leaf, *params], upstream, allow_unused=True)
    if grads[0] is not None:
        grad_coc += grads[0]
    for acc, g in zip(grad_params, grads[1:], strict=True):
        if g is not None:
            acc += g
