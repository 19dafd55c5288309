"""Apertures without a compiled kernel (`Mask`, any `Aperture.profile`): a linear filter with
per-pixel weights in pure PyTorch (`ProfileFilter`).

The profile is tabulated once per call: for every window offset `u`, its value at `N` CoC knots
evenly spaced over the map's range (`KNOTS_PER_PX` a pixel, at most `MAX_TABLE` entries), and each
pixel's weight is the linear interpolation of its offset's row at its CoC. One profile call
builds the table (one backward through it reaches the aperture's parameters), where evaluating
the profile on the whole map per offset took `K^2` calls each way (a learned mask's render was
about 6x slower than the disk's). The interpolation is exact at the knots; between them a
binary ring mask's render (1x3x512x512, CoCs up to 14 px) stays within 2e-4 of the exact one,
and a learned 16x16 code's within 1e-4. The renderer's derivatives are those of the interpolant.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from .taps import window_taps

#: CoC knots of the profile's table per pixel of the map's CoC range.
KNOTS_PER_PX = 256
#: The most entries of a table, offsets times knots (a wide window or CoC range is sampled more
#: coarsely: 16 MB in float32).
MAX_TABLE = 1 << 22


class _Table:
    """The profile of `psf` tabulated at the knots of a CoC map, and each pixel's place
    among them: `rows` `(K^2, N)` (offset `u = (dy + half) (2 half + 1) + dx + half`),
    `index` (the knot below each pixel, int64) and `frac` (its share of the knot above)."""

    def __init__(self, psf, coc: Tensor, half: int):
        low, high = (float(v) for v in torch.aminmax(coc.detach()))
        # knots on a fixed lattice (multiples of the step), so that a pixel's weight does not
        # move with the map's extremes: the interpolant is one function of the CoC
        most = max(64, MAX_TABLE // (2 * half + 1) ** 2)
        self.step = 2.0 ** max(0, math.ceil(math.log2(max(
            (high - low) * KNOTS_PER_PX / (most - 2), 1e-300)))) / KNOTS_PER_PX
        low = math.floor(low / self.step) * self.step
        n = max(2, math.floor((high - low) / self.step) + 2)
        self.knots = low + self.step * torch.arange(n, device=coc.device, dtype=coc.dtype)
        offsets = torch.arange(-half, half + 1, device=coc.device, dtype=coc.dtype)
        self.dy = offsets.repeat_interleave(2 * half + 1)[:, None]
        self.dx = offsets.repeat(2 * half + 1)[:, None]
        position = ((coc - low) / self.step).clamp(0, n - 1)
        self.index = position.floor().clamp(max=n - 2).long()
        self.frac = position - self.index
        self.psf, self.half = psf, half
        with torch.no_grad():
            self.rows = self.evaluate().contiguous()

    def evaluate(self) -> Tensor:
        """The table `(K^2, N)` (differentiable in the aperture's parameters when grad is on)."""
        return self.psf.profile(self.dy, self.dx, self.knots[None]).expand(
            self.dy.shape[0], self.knots.shape[0])

    def offset(self, dy: int, dx: int) -> int:
        return (dy + self.half) * (2 * self.half + 1) + dx + self.half

    def weight(self, row: Tensor, where: tuple = (...,)) -> Tensor:
        """The interpolated `row` (N,) at the pixels `where` of the map."""
        index, frac = self.index[where], self.frac[where]
        low = row.take(index)
        return low + (row.take(index + 1) - low) * frac

    def slope(self, row: Tensor, where: tuple = (...,)) -> Tensor:
        """d weight / d CoC of `row` at the pixels `where` (the interpolant's)."""
        index = self.index[where]
        return (row.take(index + 1) - row.take(index)) / self.step

    def add_to_row(self, grad_row: Tensor, upstream: Tensor, where: tuple = (...,)) -> None:
        """Add `upstream`'s share to each knot of `grad_row` (N,) (the interpolation's
        transpose) for the pixels `where`."""
        index, frac = self.index[where].reshape(-1), self.frac[where].reshape(-1)
        upstream = upstream.reshape(-1)
        grad_row.index_add_(0, index, upstream * (1 - frac))
        grad_row.index_add_(0, index + 1, upstream * frac)


class ProfileFilter(torch.autograd.Function):
    """Linear filter with per-pixel weights `psf.profile(u; coc)` (tabulated in the CoC).

    `scatter=True`: `y(p) = sum_q x(q) P(p-q; coc_q) / Z_q`, `Z_q` the profile's sum over the
    source's full window (each source spreads unit energy). `scatter=False` (gather):
    `y(p) = sum_q x(q) P(p-q; coc_p)`, unnormalised. Extra inputs `params` are the aperture's
    trainable parameters, so that gradients reach them.
    """

    @staticmethod
    def forward(ctx, x, coc, psf, scatter: bool, half: int, *params):
        x, coc = x.contiguous(), coc.contiguous()
        _, _, h, w = x.shape
        table = _Table(psf, coc, half)
        out = torch.zeros_like(x)
        norm = table.weight(table.rows.sum(0)) if scatter else None
        xs = x / norm if scatter else x
        for dy, dx, src, dst in window_taps(half, h, w):
            row = table.rows[table.offset(dy, dx)]
            weight = table.weight(row, src if scatter else dst)  # the source's PSF or the output's
            out[dst].addcmul_(weight, xs[src])
        ctx.save_for_backward(x, *((norm,) if scatter else ()))
        ctx.table, ctx.scatter, ctx.n_params = table, scatter, len(params)
        return out

    @staticmethod
    @once_differentiable
    def backward(ctx, grad):
        x, *rest = ctx.saved_tensors
        table, scatter = ctx.table, ctx.scatter
        params = [p for p in table.psf.parameters() if p.requires_grad]
        if len(params) != ctx.n_params:
            raise RuntimeError("the aperture's trainable parameters changed during backward")
        grad = grad.contiguous()
        _, _, h, w = x.shape
        grad_x = torch.zeros_like(x)
        grad_coc = torch.zeros_like(table.frac)
        grad_rows = torch.zeros_like(table.rows)
        if scatter:
            # W_u = P_u / Z: d loss / d P_u(q) = (a_u(q) - sum_v a_v(q) W_v(q)) / Z(q), with
            # a_u(q) = sum_c x_c(q) g_c(q + u) (0 for a tap off the image, which Z counts)
            norm = rest[0]
            mean_a = torch.zeros_like(norm)
            for dy, dx, src, dst in window_taps(table.half, h, w):
                u = table.offset(dy, dx)
                weight = table.weight(table.rows[u], src) / norm[src]
                grad_x[src].addcmul_(weight, grad[dst])
                a = (x[src] * grad[dst]).sum(1, keepdim=True)
                mean_a[src].addcmul_(a, weight)
                upstream = a / norm[src]
                grad_coc[src].addcmul_(upstream, table.slope(table.rows[u], src))
                table.add_to_row(grad_rows[u], upstream, src)
            shared = -mean_a / norm  # the same for every offset u
            grad_coc.addcmul_(shared, table.slope(table.rows.sum(0)))
            common = torch.zeros_like(grad_rows[0])
            table.add_to_row(common, shared)
            grad_rows += common
        else:
            for dy, dx, src, dst in window_taps(table.half, h, w):
                u = table.offset(dy, dx)
                grad_x[src].addcmul_(table.weight(table.rows[u], dst), grad[dst])
                upstream = (x[src] * grad[dst]).sum(1, keepdim=True)
                grad_coc[dst].addcmul_(upstream, table.slope(table.rows[u], dst))
                table.add_to_row(grad_rows[u], upstream, dst)
        grad_params = [torch.zeros_like(p) for p in params]
        if params:
            with torch.enable_grad():
                found = torch.autograd.grad(table.evaluate(), params, grad_rows,
                                            allow_unused=True)
            grad_params = [torch.zeros_like(p) if g is None else g
                           for p, g in zip(params, found, strict=True)]
        return (grad_x, grad_coc, None, None, None, *grad_params)
