"""Triton kernels for the fused, normalised scatter operators (`defocus::gaussian_render`,
`defocus::clamp_render` and their backward operators) and for the unnormalised spreads they are
built from (`defocus::gaussian_scatter`, `defocus::clamp_scatter` and their backward operators:
the gather and layered modes). `optics.render.backends` registers them as those operators' CUDA
implementations; without Triton nothing is registered (the PyTorch fallback runs on CUDA).

Each kernel is a *gather* over the window: one program owns a `BLOCK_H x BLOCK_W` tile of pixels
and loops over the `K x K` offsets, so no atomics are needed.

- Forward, per output `p`: `s_c(p) = sum_q w_q(p - q) xn_c(q)` over the sources `q` of its
  window, where `xn = (x * norm, norm)` is written by a first per-pixel pass (`norm` is the
  source's unit-energy factor over its *full* window). Then `y = s[:C] / s[C]`, `den = s[C]`.
- Backward, per source `q`: `sum_u w_q(u) G(q + u)` and `sum_u w'_q(u) G(q + u)` with `G` the
  gradient of the unnormalised spread `s` (`ops.grad_of_spread`), finished in the same
  program into `dL/dx` and `dL/dsigma` (or `dL/drho`), as `optics.render.ops` does in PyTorch.
- The window sums (`defocus::gaussian_window_sums`, `defocus::clamp_window_sums`: the unit-energy
  factor of the spreads and its derivative) in one per-pixel pass.
- The unnormalised spreads take any number of channels (the layered mode spreads `L (C + 1)`),
  `CHANNEL_GROUP` of them per program (axis 2 of the grid), with the per-source factor `norm`
  applied beforehand; their backward returns `sum_u w_q(u) g(q + u)` per channel and, summed over
  the groups afterwards, `sum_c x_c(q) sum_u w'_q(u) g_c(q + u)` (the operators' `(dx_raw, m)`).

The weight `w_q(u)` is `exp(-|u|^2 / (2 sigma_q^2))` (Gaussian) or `clamp(rho_q - D(u), 0, 1)`
(disk, polygons; `D` the `K x K` distance table). Skipped: taps outside the image and, for the
clamp, offsets beyond the largest rho (the image's forward, the tile's backward: zero weight and
slope). Float32 and float64 run natively; other floating dtypes are computed in float32.
"""

from __future__ import annotations

import contextlib

import torch
from torch import Tensor

from .ops import grad_of_spread

try:
    import triton
    import triton.language as tl
except ImportError:  # no Triton (CI): nothing to register
    triton = None

#: Pixels per program: a `BLOCK_H x BLOCK_W` tile (powers of two); with `BLOCK_W = 32 NUM_WARPS`
#: each thread holds one column of the tile, all its rows and channels.
BLOCK_H, BLOCK_W, NUM_WARPS = 4, 128, 4
#: Pixels per program of the per-pixel preparation pass; channels per program of the
#: unnormalised spreads (a power of two).
BLOCK_PREP, CHANNEL_GROUP = 256, 8


def available() -> bool:
    """Whether Triton imported (the kernels can be launched on CUDA, or interpreted)."""
    return triton is not None


def _jit(fn):
    return fn if triton is None else triton.jit(fn)


# ------------------------------------------------------------------ device functions


@_jit
def _tap_distance(dy, dx, table_ptr, T, tap, GAUSSIAN: tl.constexpr):
    """`D(dy, dx)` from the distance table of half-width `T` where `tap` (clamp); 0 for the
    Gaussian (no table)."""
    if GAUSSIAN:
        d = 0.0
    else:
        d = tl.load(table_ptr + (dy + T) * (2 * T + 1) + (dx + T), mask=tap, other=0.0)
    return d


@_jit
def _tap_weight(param, r2, d, GAUSSIAN: tl.constexpr):
    """`(w, dw)` at an offset `u` with `|u|^2 = r2` and distance `d = D(u)`: Gaussian
    `param = -1 / (2 sigma^2)`, `w = exp(param |u|^2)`, `dw = w |u|^2`; clamp `param = rho`,
    `w = clamp(rho - d, 0, 1)`, `dw = [0 <= rho - d <= 1]`."""
    if GAUSSIAN:
        w = tl.exp(param * r2)
        dw = w * r2
    else:
        t = param - d
        w = tl.minimum(tl.maximum(t, 0.0), 1.0)
        dw = tl.where((t >= 0.0) & (t <= 1.0), 1.0, 0.0).to(t.dtype)
    return w, dw


@_jit
def _within(d, tap, limit, GAUSSIAN: tl.constexpr):
    """Whether a tap of the rows lies within distance `limit` (clamp); always for the Gaussian."""
    if GAUSSIAN:
        hit = True
    else:
        hit = tl.min(tl.where(tap, d, limit + 1.0)) <= limit
    return hit


@_jit
def _window_sums(param, coef, table_ptr, half, T, GAUSSIAN: tl.constexpr):
    """`(Z, dZ)` over a source's full window: Gaussian (`param` = sigma, `coef = -1 / (2
    sigma^2)`) the line sums `sum_d t(d)` and `sum_d t(d) d^2`, `t(d) = exp(coef d^2)`,
    `d = -half..half` (the weight factorises, `Z` is the first squared); clamp (`param` = rho,
    `coef` unused) `sum_u clamp(rho - D(u), 0, 1)` and its slope in rho, `D` the distance
    table of half-width `T >= half`."""
    if GAUSSIAN:
        total = tl.zeros_like(param) + 1.0
        second = tl.zeros_like(param)
        for d in range(1, half + 1):
            term = 2.0 * tl.exp(coef * (d * d))
            total += term
            second += term * (d * d)
    else:
        total = tl.zeros_like(param)
        second = tl.zeros_like(param)
        for dy in range(-half, half + 1):
            for dx in range(-half, half + 1):
                t = param - tl.load(table_ptr + (dy + T) * (2 * T + 1) + (dx + T))
                total += tl.minimum(tl.maximum(t, 0.0), 1.0)
                second += tl.where((t >= 0.0) & (t <= 1.0), 1.0, 0.0).to(t.dtype)
    return total, second


@_jit
def _unit_energy(param, coef, table_ptr, half, T, GAUSSIAN: tl.constexpr):
    """`(norm, dnorm)`: `1 / Z` over the full window and its derivative in sigma (or rho).

    `param` is sigma (Gaussian, `coef = -1 / (2 sigma^2)`) or rho (clamp, `coef` unused).
    """
    total, second = _window_sums(param, coef, table_ptr, half, T, GAUSSIAN)
    if GAUSSIAN:
        norm = 1.0 / (total * total)
        dnorm = -2.0 * second / (param * param * param * total * total * total)
    else:
        norm = 1.0 / total
        dnorm = -second * norm * norm
    return norm, dnorm


@_jit
def _tile(W, BLOCK_H: tl.constexpr, BLOCK_W: tl.constexpr, CP: tl.constexpr):
    """This program's first row, its row offsets `(R,1,1)`, columns `(1,1,BW)` and channels
    `(1,CP,1)` (axis 0 of the grid enumerates the tiles)."""
    pid = tl.program_id(0)
    tiles_w = tl.cdiv(W, BLOCK_W)
    row0 = (pid // tiles_w) * BLOCK_H
    r = tl.arange(0, BLOCK_H)[:, None, None]
    col = (pid % tiles_w) * BLOCK_W + tl.arange(0, BLOCK_W)[None, None, :]
    return row0, r, col, tl.arange(0, CP)[None, :, None]


@_jit
def _spread_taps(acc, xn_base, param_base, table_ptr, limit, row0, r, col, used, H, W, half,
                 T, GAUSSIAN: tl.constexpr, BLOCK_H: tl.constexpr):
    """`acc + sum_q w_q(p - q) xn(q)` for the tile's outputs `p` (rows `row0 + r`, columns
    `col`): `xn_base` points at the channel planes, `used` masks the channels, `param_base` holds
    each source's `-1 / (2 sigma^2)` (Gaussian) or rho. Clamp: offsets farther than `limit` weigh
    nothing and are skipped."""
    for j in range(-half, BLOCK_H + half):  # sources on row row0 + j, at dy = r - j
        src_row = row0 + j
        if (src_row >= 0) & (src_row < H):
            dy = r - j
            tap = (dy >= -half) & (dy <= half)
            for dx in range(-half, half + 1):
                d = _tap_distance(dy, dx, table_ptr, T, tap, GAUSSIAN)
                if _within(d, tap, limit, GAUSSIAN):
                    src_col = col - dx
                    ok = (src_col >= 0) & (src_col < W)
                    src = src_row * W + src_col
                    param = tl.load(param_base + src, mask=ok, other=0.0)
                    xn = tl.load(xn_base + src, mask=ok & used, other=0.0)
                    w, _ = _tap_weight(param, dy * dy + dx * dx, d, GAUSSIAN)
                    acc += tl.where(tap, w, 0.0) * xn
    return acc


@_jit
def _adjoint_taps(acc, acc_slope, g_base, own, table_ptr, limit, row0, r, col, used, H, W, half,
                  T, GAUSSIAN: tl.constexpr, BLOCK_H: tl.constexpr):
    """For the tile's sources `q` (rows `row0 + r`, columns `col`), with `own` their
    `-1 / (2 sigma^2)` or rho: `acc + sum_u w_q(u) g(q + u)` and `acc_slope + sum_u w'_q(u)
    g(q + u)` (`_tap_weight`'s `dw`), `g_base` pointing at the gradient's channel planes and
    `used` masking the channels. Clamp: offsets farther than `limit` are skipped."""
    for j in range(-half, BLOCK_H + half):  # outputs on row row0 + j, at dy = j - r
        out_row = row0 + j
        if (out_row >= 0) & (out_row < H):
            dy = j - r
            tap = (dy >= -half) & (dy <= half)
            for dx in range(-half, half + 1):
                d = _tap_distance(dy, dx, table_ptr, T, tap, GAUSSIAN)
                if _within(d, tap, limit, GAUSSIAN):
                    out_col = col + dx
                    ok = (out_col >= 0) & (out_col < W)
                    g = tl.load(g_base + out_row * W + out_col, mask=ok & used, other=0.0)
                    w, dw = _tap_weight(own, dy * dy + dx * dx, d, GAUSSIAN)
                    acc += tl.where(tap, w, 0.0) * g
                    acc_slope += tl.where(tap, dw, 0.0) * g
    return acc, acc_slope


# ------------------------------------------------------------------ kernels
# The forward and backward kernels hold a tile of `BLOCK_H` rows per thread column: each row of
# sources (or gradients) they load serves every row of the tile it reaches, which divides the
# loads per tap by about `BLOCK_H`.


@_jit
def _prepare_kernel(x_ptr, param_ptr, table_ptr, xn_ptr, coef_ptr, HW, half_ptr, T,
                    C: tl.constexpr, CP: tl.constexpr, GAUSSIAN: tl.constexpr,
                    BLOCK: tl.constexpr):
    """Per pixel: `xn = (x * norm, norm)` and, for the Gaussian, `coef = -1 / (2 sigma^2)`."""
    b = tl.program_id(1).to(tl.int64)
    pix = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    inside = pix < HW
    ch = tl.arange(0, CP)[:, None]
    param = tl.load(param_ptr + b * HW + pix, mask=inside, other=1.0)
    coef = -0.5 / (param * param)
    norm, _ = _unit_energy(param, coef, table_ptr, tl.load(half_ptr), T, GAUSSIAN)
    x = tl.load(x_ptr + b * C * HW + ch * HW + pix[None, :], mask=(ch < C) & inside[None, :],
                other=1.0)
    xn = tl.where(ch < C, x, 1.0) * norm[None, :]
    tl.store(xn_ptr + b * (C + 1) * HW + ch * HW + pix[None, :], xn,
             mask=(ch <= C) & inside[None, :])
    if GAUSSIAN:
        tl.store(coef_ptr + b * HW + pix, coef, mask=inside)


@_jit
def _spread_tile(xn_ptr, param_ptr, table_ptr, limit_ptr, H, W, half_ptr, T,
                 PLANES: tl.constexpr,
                 CP: tl.constexpr, GAUSSIAN: tl.constexpr, BLOCK_H: tl.constexpr,
                 BLOCK_W: tl.constexpr):
    """This program's tile of `sum_q w_q(p - q) xn(q)` over its channels (group `program_id(2)`
    of `CP` of the `PLANES` channel planes; a lone group where the grid has no axis 2).

    Returns `(acc, b, HW, ch, pix, inside)`: the `(BLOCK_H, CP, BLOCK_W)` sums, the image, its
    plane size, the channels `(1,CP,1)`, the pixels' offsets in a plane and which lie on it.
    """
    b = tl.program_id(1).to(tl.int64)
    HW = H * W
    row0, r, col, ch = _tile(W, BLOCK_H, BLOCK_W, CP)
    ch = tl.program_id(2) * CP + ch
    limit = tl.load(limit_ptr)  # unused by the Gaussian
    acc = tl.zeros([BLOCK_H, CP, BLOCK_W], dtype=xn_ptr.dtype.element_ty)
    acc = _spread_taps(acc, xn_ptr + b * PLANES * HW + ch * HW, param_ptr + b * HW, table_ptr,
                       limit, row0, r, col, ch < PLANES, H, W, tl.load(half_ptr), T,
                       GAUSSIAN, BLOCK_H)
    row = row0 + r
    return acc, b, HW, ch, row * W + col, (row < H) & (col < W)


@_jit
def _window_sums_kernel(param_ptr, table_ptr, total_ptr, second_ptr, N, half_ptr, T,
                        GAUSSIAN: tl.constexpr, BLOCK: tl.constexpr):
    """Per pixel of a `param` map (`N` values): `_window_sums`, stored in two maps."""
    pix = tl.program_id(0).to(tl.int64) * BLOCK + tl.arange(0, BLOCK)
    inside = pix < N
    param = tl.load(param_ptr + pix, mask=inside, other=1.0)
    total, second = _window_sums(param, -0.5 / (param * param), table_ptr, tl.load(half_ptr),
                                 T, GAUSSIAN)
    tl.store(total_ptr + pix, total, mask=inside)
    tl.store(second_ptr + pix, second, mask=inside)


@_jit
def _forward_kernel(xn_ptr, param_ptr, table_ptr, limit_ptr, y_ptr, den_ptr, H, W, half_ptr,
                    T, C: tl.constexpr, CP: tl.constexpr, GAUSSIAN: tl.constexpr,
                    BLOCK_H: tl.constexpr, BLOCK_W: tl.constexpr):
    """`s(p) = sum_q w_q(p - q) xn(q)`; stores `y = s[:C] / s[C]` and `den = s[C]`.

    Clamp: offsets farther than the largest rho (`limit_ptr`) weigh nothing and are skipped.
    """
    acc, b, HW, ch, pix, inside = _spread_tile(xn_ptr, param_ptr, table_ptr, limit_ptr, H, W,
                                               half_ptr, T, C + 1, CP, GAUSSIAN, BLOCK_H,
                                               BLOCK_W)
    den = tl.sum(tl.where(ch == C, acc, 0.0), axis=1)[:, None, :]
    safe = tl.where(inside, den, 1.0)  # pixels off the image are not stored
    tl.store(y_ptr + b * C * HW + ch * HW + pix, acc / safe, mask=inside & (ch < C))
    tl.store(den_ptr + b * HW + pix, den, mask=inside)


@_jit
def _backward_kernel(g_ptr, x_ptr, param_ptr, table_ptr, grad_x_ptr, grad_param_ptr, H, W,
                     half_ptr, T, C: tl.constexpr, CP: tl.constexpr, GAUSSIAN: tl.constexpr,
                     BLOCK_H: tl.constexpr, BLOCK_W: tl.constexpr):
    """Per source `q`: `dL/dx(q)` and `dL/dparam(q)` from `G`, the gradient of the spread.

    Clamp: offsets farther than the tile's largest rho weigh nothing and are skipped.
    """
    b = tl.program_id(1).to(tl.int64)
    HW = H * W
    half = tl.load(half_ptr)
    row0, r, col, ch = _tile(W, BLOCK_H, BLOCK_W, CP)
    row = row0 + r
    inside = (row < H) & (col < W)
    pix = row * W + col
    param = tl.load(param_ptr + b * HW + pix, mask=inside, other=1.0)
    coef = -0.5 / (param * param)
    own = coef if GAUSSIAN else param
    limit = tl.max(tl.where(inside, param, 0.0))  # unused by the Gaussian
    g_base = g_ptr + b * (C + 1) * HW + ch * HW
    acc = tl.zeros([BLOCK_H, CP, BLOCK_W], dtype=g_ptr.dtype.element_ty)
    acc_slope = tl.zeros([BLOCK_H, CP, BLOCK_W], dtype=g_ptr.dtype.element_ty)
    acc, acc_slope = _adjoint_taps(acc, acc_slope, g_base, own, table_ptr, limit, row0, r, col,
                                   ch <= C, H, W, half, T, GAUSSIAN, BLOCK_H)
    norm, dnorm = _unit_energy(param, coef, table_ptr, half, T, GAUSSIAN)
    # (x, 1): the spread's input, whose last channel carries the normalisation
    x = tl.load(x_ptr + b * C * HW + ch * HW + pix, mask=inside & (ch < C), other=0.0)
    ones = tl.where(ch == C, 1.0, x)
    raw = tl.sum(ones * acc, axis=1)[:, None, :]
    moment = tl.sum(ones * acc_slope, axis=1)[:, None, :]
    if GAUSSIAN:  # dw/dsigma = w |u|^2 / sigma^3
        moment = moment / (param * param * param)
    tl.store(grad_x_ptr + b * C * HW + ch * HW + pix, acc * norm, mask=inside & (ch < C))
    tl.store(grad_param_ptr + b * HW + pix, norm * moment + raw * dnorm, mask=inside)


@_jit
def _spread_kernel(xn_ptr, param_ptr, table_ptr, limit_ptr, y_ptr, H, W, half_ptr, T,
                   C: tl.constexpr, CG: tl.constexpr, GAUSSIAN: tl.constexpr,
                   BLOCK_H: tl.constexpr, BLOCK_W: tl.constexpr):
    """`y(p) = sum_q w_q(p - q) xn(q)` for the channels of this program's group (grid axis 2).

    Clamp: offsets farther than the largest rho (`limit_ptr`) weigh nothing and are skipped.
    """
    acc, b, HW, ch, pix, inside = _spread_tile(xn_ptr, param_ptr, table_ptr, limit_ptr, H, W,
                                               half_ptr, T, C, CG, GAUSSIAN, BLOCK_H, BLOCK_W)
    tl.store(y_ptr + b * C * HW + ch * HW + pix, acc, mask=inside & (ch < C))


@_jit
def _spread_backward_kernel(g_ptr, x_ptr, param_ptr, table_ptr, dx_ptr, m_ptr, H, W, half_ptr,
                            T, C: tl.constexpr, CG: tl.constexpr, GAUSSIAN: tl.constexpr,
                            BLOCK_H: tl.constexpr, BLOCK_W: tl.constexpr):
    """Per source `q`, for this program's channels: `dx_raw(q) = sum_u w_q(u) g(q + u)` and its
    group's share `sum_c x_c(q) sum_u w'_q(u) g_c(q + u)` of `m` (row `group` of `m_ptr`).

    Clamp: offsets farther than the tile's largest rho weigh nothing and are skipped.
    """
    b = tl.program_id(1).to(tl.int64)
    group = tl.program_id(2)
    HW = H * W
    half = tl.load(half_ptr)
    row0, r, col, ch = _tile(W, BLOCK_H, BLOCK_W, CG)
    ch = group * CG + ch
    used = ch < C
    row = row0 + r
    inside = (row < H) & (col < W)
    pix = row * W + col
    param = tl.load(param_ptr + b * HW + pix, mask=inside, other=1.0)
    if GAUSSIAN:
        own = -0.5 / (param * param)
    else:
        own = param
    limit = tl.max(tl.where(inside, param, 0.0))  # unused by the Gaussian
    g_base = g_ptr + b * C * HW + ch * HW
    acc = tl.zeros([BLOCK_H, CG, BLOCK_W], dtype=g_ptr.dtype.element_ty)
    acc_slope = tl.zeros([BLOCK_H, CG, BLOCK_W], dtype=g_ptr.dtype.element_ty)
    acc, acc_slope = _adjoint_taps(acc, acc_slope, g_base, own, table_ptr, limit, row0, r, col,
                                   used, H, W, half, T, GAUSSIAN, BLOCK_H)
    x = tl.load(x_ptr + b * C * HW + ch * HW + pix, mask=inside & used, other=0.0)
    tl.store(dx_ptr + b * C * HW + ch * HW + pix, acc, mask=inside & used)
    share = tl.sum(x * acc_slope, axis=1)[:, None, :]
    groups = tl.num_programs(2)
    tl.store(m_ptr + (b * groups + group) * HW + pix, share, mask=inside)


# ------------------------------------------------------------------ launchers


def _device_of(x: Tensor):
    """Launch on `x`'s GPU, whichever is current (a no-op for the interpreter's CPU tensors)."""
    return torch.cuda.device(x.device) if x.is_cuda else contextlib.nullcontext()


def _grid(x: Tensor) -> tuple[int, int]:
    b, _, h, w = x.shape
    return triton.cdiv(h, BLOCK_H) * triton.cdiv(w, BLOCK_W), b


def _operands(x: Tensor, param: Tensor, half: int | Tensor, table: Tensor | None):
    """`(x, param, table, gaussian, half, T)` ready for the kernels: float32 or float64,
    contiguous, the table on the device (the Gaussian has none: `param` stands in for the unused
    pointer), the window half-width in a one-element device tensor (read by the kernels, never
    by the host: a 0-d tensor computed on the GPU stays there) and the table's half-width `T`
    (at least the window's)."""
    dtype = x.dtype if x.dtype in (torch.float32, torch.float64) else torch.float32
    x, param = x.to(dtype).contiguous(), param.to(dtype).contiguous()
    if isinstance(half, Tensor) and half.device == x.device:
        half = half.reshape(1)
    else:  # a Python int or a CPU tensor: its value is on the host already
        half = torch.full((1,), int(half), dtype=torch.int64, device=x.device)
    if table is None:
        return x, param, param, True, half, 0
    return x, param, table.to(x.device, dtype).contiguous(), False, half, table.shape[-1] // 2


def _channels(x: Tensor) -> dict:
    c = x.shape[1]
    return {"C": c, "CP": triton.next_power_of_2(c + 1)}


def render(x: Tensor, param: Tensor, half: int | Tensor,
           table: Tensor | None) -> tuple[Tensor, Tensor]:
    """`(y, den)` of the normalised scatter: Gaussian (`param` = sigma, `table` None) or clamp
    (`param` = rho, `table` a square distance table at least `2 half + 1` wide, centred)."""
    x, param, table, gaussian, half, T = _operands(x, param, half, table)
    b, c, h, w = x.shape
    xn = x.new_empty(b, c + 1, h, w)
    coef = torch.empty_like(param) if gaussian else param
    y, den = torch.empty_like(x), torch.empty_like(param)
    meta = {**_channels(x), "GAUSSIAN": gaussian, "num_warps": NUM_WARPS}
    with _device_of(x):
        _prepare_kernel[(triton.cdiv(h * w, BLOCK_PREP), b)](
            x, param, table, xn, coef, h * w, half, T, BLOCK=BLOCK_PREP, **meta
        )
        limit = param if gaussian else param.amax()  # the Gaussian ignores it
        _forward_kernel[_grid(x)](
            xn, coef, table, limit, y, den, h, w, half, T, BLOCK_H=BLOCK_H, BLOCK_W=BLOCK_W,
            **meta
        )
    return y, den


def render_backward(grad: Tensor, y: Tensor, den: Tensor, x: Tensor, param: Tensor,
                    half: int | Tensor, table: Tensor | None) -> tuple[Tensor, Tensor]:
    """`(dL/dx, dL/dparam)` of `render` from `dL/dy`."""
    x, param, table, gaussian, half, T = _operands(x, param, half, table)
    g = grad_of_spread(*(t.to(x.dtype) for t in (grad, y, den)))
    grad_x, grad_param = torch.empty_like(x), torch.empty_like(param)
    _, _, h, w = x.shape
    with _device_of(x):
        _backward_kernel[_grid(x)](
            g, x, param, table, grad_x, grad_param, h, w, half, T, GAUSSIAN=gaussian,
            BLOCK_H=BLOCK_H, BLOCK_W=BLOCK_W, num_warps=NUM_WARPS, **_channels(x),
        )
    return grad_x, grad_param


def _spread_grid(x: Tensor) -> tuple[int, int, int]:
    return (*_grid(x), triton.cdiv(x.shape[1], CHANNEL_GROUP))


def spread(x: Tensor, param: Tensor, norm: Tensor, half: int | Tensor,
           table: Tensor | None) -> Tensor:
    """The unnormalised spread `y(p) = sum_q norm_q w_q(p - q) x(q)` of any number of channels:
    Gaussian (`param` = sigma, `table` None) or clamp (`param` = rho, `table` the distance
    table)."""
    x, param, table, gaussian, half, T = _operands(x, param, half, table)
    b, c, h, w = x.shape
    xn = (x * norm.to(x.dtype)).contiguous()
    source = -0.5 / (param * param) if gaussian else param
    limit = param if gaussian else param.amax()  # the Gaussian ignores it
    y = torch.empty_like(x)
    with _device_of(x):
        _spread_kernel[_spread_grid(x)](
            xn, source, table, limit, y, h, w, half, T, C=c, CG=CHANNEL_GROUP, GAUSSIAN=gaussian,
            BLOCK_H=BLOCK_H, BLOCK_W=BLOCK_W, num_warps=NUM_WARPS,
        )
    return y


def spread_backward(grad: Tensor, x: Tensor, param: Tensor, half: int | Tensor,
                    table: Tensor | None) -> tuple[Tensor, Tensor]:
    """`(dx_raw, m)` of `spread` (see `ops.gaussian_scatter_backward` and
    `clamp_scatter_backward`): `sum_u w_q(u) g(q + u)` per channel and
    `sum_c x_c(q) sum_u w'_q(u) g_c(q + u)`, `w'` the weight's derivative without its
    `1 / sigma^3` (Gaussian: `w |u|^2`) or the clamp's slope."""
    x, param, table, gaussian, half, T = _operands(x, param, half, table)
    g = grad.to(x.dtype).contiguous()
    b, c, h, w = x.shape
    grid = _spread_grid(x)
    dx_raw, shares = torch.empty_like(x), x.new_empty(b, grid[2], h, w)
    with _device_of(x):
        _spread_backward_kernel[grid](
            g, x, param, table, dx_raw, shares, h, w, half, T, C=c, CG=CHANNEL_GROUP,
            GAUSSIAN=gaussian, BLOCK_H=BLOCK_H, BLOCK_W=BLOCK_W, num_warps=NUM_WARPS,
        )
    return dx_raw, shares.sum(1, keepdim=True)


def window_sums(param: Tensor, half: int | Tensor,
                table: Tensor | None) -> tuple[Tensor, Tensor]:
    """The window sums of `ops.gaussian_window_sums` (`param` = sigma, `table` None: `sum_d t(d)`
    and `sum_d t(d) d^2`) or `ops.clamp_window_sums` (`param` = rho, `table` the distance
    table: `Z` and `dZ/drho`), per pixel of `param`, in one pass."""
    param, _, table, gaussian, half, T = _operands(param, param, half, table)
    total, second = torch.empty_like(param), torch.empty_like(param)
    with _device_of(param):
        _window_sums_kernel[(triton.cdiv(param.numel(), BLOCK_PREP),)](
            param, table, total, second, param.numel(), half, T, GAUSSIAN=gaussian,
            BLOCK=BLOCK_PREP, num_warps=NUM_WARPS,
        )
    return total, second
