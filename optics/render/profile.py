"""Apertures without a compiled kernel (`Mask`, any `Aperture.profile`): a linear filter with
per-pixel weights in pure PyTorch (`ProfileFilter`), its backward recomputing the weights.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from .taps import axis_slices, window_taps


def _profile_normaliser(psf, coc: Tensor, half: int) -> Tensor:
    """Discrete sum of a source's profile over its whole `(2 half + 1)^2` window."""
    total = torch.zeros_like(coc)
    for dy in range(-half, half + 1):
        for dx in range(-half, half + 1):
            total = total + psf.profile(_scalar(dy, coc), _scalar(dx, coc), coc)
    return total


def _scalar(value: int, like: Tensor) -> Tensor:
    return torch.tensor(float(value), dtype=like.dtype, device=like.device)


class ProfileFilter(torch.autograd.Function):
    """Linear filter with per-pixel weights `psf.profile(u; coc)`.

    `scatter=True`: `y(p) = sum_q x(q) P(p-q; coc_q) / Z_q`, `Z_q` the profile's sum over the
    source's full window (each source spreads unit energy). `scatter=False` (gather):
    `y(p) = sum_q x(q) P(p-q; coc_p)`, unnormalised. Extra inputs `params` are the aperture's
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
    """Add `upstream * d profile(dy, dx; coc) / d(coc, params)` to the gradient accumulators."""
    with torch.enable_grad():
        leaf = coc.detach().requires_grad_(True)
        weight = psf.profile(_scalar(dy, coc), _scalar(dx, coc), leaf)
        grads = torch.autograd.grad(weight, [leaf, *params], upstream, allow_unused=True)
    if grads[0] is not None:
        grad_coc += grads[0]
    for acc, g in zip(grad_params, grads[1:], strict=True):
        if g is not None:
            acc += g
