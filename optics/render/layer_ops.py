"""The occlusion-aware layered mode as `torch.library` custom operators (`defocus::layered_render`
and its backward), on the compiled CPU kernels (`optics.render.cpp`); `optics.render.renderer` calls them.
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import cpp
from .taps import distinct, window


def _clamp_tables(dist: Tensor, half: Tensor, like: Tensor):
    table = window(dist, int(half)).to(like.dtype)
    return (table, *distinct(table))


def _need_library(x: Tensor) -> None:
    if not cpp.usable(x):
        raise RuntimeError("defocus layered operators need the compiled CPU kernels; "
                           "use render_defocus, which falls back to the PyTorch path")


@torch.library.custom_op("defocus::layered_render", mutates_args=())
def layered_render(
    x: Tensor, pos: Tensor, param: Tensor, dist: Tensor, half: Tensor, n_layers: int, kind: str
) -> tuple[Tensor, Tensor]:
    """`(out, spread)` of the layered mode; `kind` is "gaussian" (`param` = sigma, `dist` unused)
    or "clamp" (`param` = rho, `dist` the distance table).

    `spread` `(B, L, C + 1, H, W)` is for the backward pass only: a layer's rows are written only
    where a source within the window's half-width rows has the layer (elsewhere it is zero, left
    unwritten so that its memory is never touched).
    """
    _need_library(x)
    x, pos, param = x.contiguous(), pos.contiguous(), param.contiguous()
    clamp = _clamp_tables(dist, half, x) if kind == "clamp" else None
    return cpp.layered_render(x, pos, param, int(half), n_layers, clamp)


@torch.library.custom_op("defocus::layered_render_backward", mutates_args=())
def layered_render_backward(
    grad: Tensor, out: Tensor, spread: Tensor, x: Tensor, pos: Tensor, param: Tensor,
    dist: Tensor, half: Tensor, n_layers: int, kind: str,
) -> tuple[Tensor, Tensor, Tensor]:
    """`(dL/dx, dL/dpos, dL/dparam)` of `layered_render` from `dL/dout`."""
    _need_library(x)
    clamp = _clamp_tables(dist, half, x) if kind == "clamp" else None
    return cpp.layered_render_backward(
        grad.contiguous(), out.contiguous(), spread.contiguous(), x.contiguous(),
        pos.contiguous(), param.contiguous(), int(half), n_layers, clamp,
    )


@layered_render.register_fake
def _(x, pos, param, dist, half, n_layers, kind):
    b, c, h, w = x.shape
    return torch.empty_like(x), x.new_empty(b, n_layers, c + 1, h, w)


@layered_render_backward.register_fake
def _(grad, out, spread, x, pos, param, dist, half, n_layers, kind):
    return torch.empty_like(x), torch.empty_like(pos), torch.empty_like(pos)


def _save_layered(ctx, inputs, output) -> None:
    x, pos, param, dist, half, n_layers, kind = inputs
    ctx.save_for_backward(x, pos, param, dist, half, *output)
    ctx.n_layers, ctx.kind = n_layers, kind
    ctx.set_materialize_grads(False)  # no zero gradient for `spread`, L (C + 1) image planes


def _layered_vjp(ctx, grad_out, grad_spread):
    # `spread` is an auxiliary output for the backward pass; its gradient is not propagated.
    if grad_out is None:
        return None, None, None, None, None, None, None
    x, pos, param, dist, half, out, spread = ctx.saved_tensors
    grad_x, grad_pos, grad_param = layered_render_backward(
        grad_out, out, spread, x, pos, param, dist, half, ctx.n_layers, ctx.kind
    )
    return grad_x, grad_pos, grad_param, None, None, None, None


layered_render.register_autograd(_layered_vjp, setup_context=_save_layered)
