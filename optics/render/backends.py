"""The renderer's backends, in one place: which kernels run its operators on which device.

| operators (`optics.render.ops`, `optics.render.layer_ops`) | CPU | CUDA |
|---|---|---|
| fused scatter (`gaussian_render`, `clamp_render`, backwards) | C++ | Triton |
| spreads (`gaussian_scatter`, `clamp_scatter`, backwards) | C++ | Triton |
| window sums (the spreads' unit-energy norms) | C++ | Triton |
| gather | C++ | Triton (the spreads' backward kernels) |
| layered (`layered_render`, backward) | C++ | (the renderer composes the spreads) |

- **CPU**: the compiled C++ kernels (`optics.render.cpp`) run where `compiled_cpu(x)` holds (a
  float32 or float64 CPU tensor and the library built and trusted); each operator's default
  implementation asks `cpp.usable` and otherwise runs its PyTorch loop (same results).
- **CUDA**: `register_triton` makes the Triton kernels (`optics.render.triton_kernels`) the CUDA
  implementations of the operators in `TRITON_KERNELS`. It runs once, below, when this module is
  imported (by `optics.render`); without Triton nothing is registered and the PyTorch loops run.
"""

from __future__ import annotations

from torch import Tensor

from . import cpp, ops, triton_kernels


def compiled_cpu(x: Tensor) -> bool:
    """Whether the compiled C++ kernels process `x` (CPU float32/float64, library loaded).

    Example:
        >>> compiled_cpu(torch.zeros(1, dtype=torch.int64))
        False
    """
    return cpp.usable(x)


def _cast(outputs: tuple[Tensor, Tensor], *like: Tensor) -> tuple[Tensor, Tensor]:
    return tuple(o.to(t.dtype) for o, t in zip(outputs, like, strict=True))


# The operators' signatures, adapted to the Triton launchers (looked up on `triton_kernels` at
# call time, so that they can be patched). The window half-width `half` and the distance table
# `dist` go to the kernels as they are, on the device: the host reads neither.


def _gaussian_render(x, sigma, half):
    return _cast(triton_kernels.render(x, sigma, half, None), x, sigma)


def _gaussian_render_backward(grad, y, den, x, sigma, half):
    return _cast(triton_kernels.render_backward(grad, y, den, x, sigma, half, None), x, sigma)


def _clamp_render(x, rho, dist, half):
    return _cast(triton_kernels.render(x, rho, half, dist), x, rho)


def _clamp_render_backward(grad, y, den, x, rho, dist, half):
    return _cast(triton_kernels.render_backward(grad, y, den, x, rho, half, dist), x, rho)


def _gaussian_scatter(x, sigma, norm, half):
    return triton_kernels.spread(x, sigma, norm, half, None).to(x.dtype)


def _gaussian_scatter_backward(grad, x, sigma, half):
    return _cast(triton_kernels.spread_backward(grad, x, sigma, half, None), x, sigma)


def _clamp_scatter(x, rho, norm, dist, half):
    return triton_kernels.spread(x, rho, norm, half, dist).to(x.dtype)


def _clamp_scatter_backward(grad, x, rho, dist, half):
    return _cast(triton_kernels.spread_backward(grad, x, rho, half, dist), x, rho)


def _gaussian_window_sums(sigma, half):
    return _cast(triton_kernels.window_sums(sigma, half, None), sigma, sigma)


def _clamp_window_sums(rho, dist, half):
    return _cast(triton_kernels.window_sums(rho, half, dist), rho, rho)


#: The operators with Triton kernels and those kernels' wrappers.
TRITON_KERNELS = (
    (ops.gaussian_render, _gaussian_render),
    (ops.gaussian_render_backward, _gaussian_render_backward),
    (ops.clamp_render, _clamp_render),
    (ops.clamp_render_backward, _clamp_render_backward),
    (ops.gaussian_scatter, _gaussian_scatter),
    (ops.gaussian_scatter_backward, _gaussian_scatter_backward),
    (ops.clamp_scatter, _clamp_scatter),
    (ops.clamp_scatter_backward, _clamp_scatter_backward),
    (ops.gaussian_window_sums, _gaussian_window_sums),
    (ops.clamp_window_sums, _clamp_window_sums),
)


def register_triton(device_type: str = "cuda") -> bool:
    """Make the Triton kernels the implementations of `TRITON_KERNELS`' operators on
    `device_type` (CUDA; the tests also use "cpu" under `TRITON_INTERPRET=1`).

    Returns whether they were registered (`False` without Triton).

    Example:
        >>> register_triton() == triton_kernels.available()
        True
    """
    if not triton_kernels.available():
        return False
    for op, fn in TRITON_KERNELS:
        op.register_kernel(device_type)(fn)
    return True


register_triton("cuda")
