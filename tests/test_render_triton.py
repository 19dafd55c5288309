"""The Triton kernels (`optics.render.triton_kernels`: the fused scatter and the unnormalised spreads of
the gather and layered modes) against the PyTorch path.

They run on CUDA when a GPU is present, else on the CPU in Triton's interpreter when the suite
is started with `TRITON_INTERPRET=1` (the kernels are then also registered for the CPU, enabled
only inside `kernels(triton=True)`); otherwise the module is skipped. The reference is the same
operator with the Triton kernel disabled and the compiled CPU kernels turned off: the PyTorch
loops of `optics.render.ops`.
"""

from __future__ import annotations

import contextlib
import os
from unittest import mock

import pytest
import torch
from torch.autograd import gradcheck

from optics import Disk, Gaussian, Polygon, render_defocus
from optics.render import backends
from optics.render import cpp as _render_cpp
from optics.render import ops as _render_ops
from optics.render import triton_kernels as _render_triton

INTERPRET = os.environ.get("TRITON_INTERPRET") == "1"

if not _render_triton.available():
    pytest.skip("Triton is not installed", allow_module_level=True)
if INTERPRET:
    DEVICE = "cpu"
elif torch.cuda.is_available():
    DEVICE = "cuda"
else:
    pytest.skip("the Triton kernels need a CUDA GPU, or TRITON_INTERPRET=1 for the interpreter",
                allow_module_level=True)

OPS = tuple(op for op, _ in backends.TRITON_KERNELS)

if DEVICE == "cpu":
    # Registered for the CPU too, but disabled so that the rest of the session keeps the compiled
    # CPU kernels; `kernels(True)` enables them. The contexts are entered and never left (kept
    # here: a collected one would restore the kernels).
    _DISABLED = [op.set_kernel_enabled("cpu", False) for op in OPS]
    for _context in _DISABLED:
        _context.__enter__()
    backends.register_triton("cpu")


def _not_triton(*args, **kwargs):
    raise AssertionError("the reference path reached the Triton kernels")

APERTURES = {"gaussian": Gaussian, "disk": Disk, "hexagon": lambda: Polygon(6)}


@contextlib.contextmanager
def kernels(triton: bool):
    """Route the scatter operators to the Triton kernels, or to the PyTorch loops (the compiled
    CPU kernels off either way, so that the interpreter's modes also reach the operators)."""
    with contextlib.ExitStack() as stack:
        if triton != (DEVICE == "cuda"):  # the registration's state differs from the wanted one
            for op in OPS:
                stack.enter_context(op.set_kernel_enabled(DEVICE, triton))
        stack.enter_context(mock.patch.object(_render_cpp, "usable", lambda x: False))
        if not triton:
            for name in ("render", "render_backward", "spread", "spread_backward", "window_sums"):
                stack.enter_context(mock.patch.object(_render_triton, name, _not_triton))
        yield


def coc_max(name: str, k: int) -> float:
    """Largest CoC whose window is exactly `k` pixels wide."""
    return 2 * (k // 2) / 3 if name == "gaussian" else k - 0.01


def make_inputs(name: str, shape, k: int, dtype, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    b, _, h, w = shape
    image = torch.rand(shape, generator=gen, dtype=torch.float64)
    coc = torch.rand(b, 1, h, w, generator=gen, dtype=torch.float64) * coc_max(name, k)
    coc[:, :, h // 2, w // 3] = coc_max(name, k)
    weights = torch.randn(shape, generator=gen, dtype=torch.float64)  # dL/dy
    return (t.to(DEVICE, dtype) for t in (image, coc, weights))


def render(name: str, image, coc, weights, triton: bool, mode: str = "scatter", depth=None):
    """`(y, dL/dimage, dL/dcoc[, dL/ddepth])` of `render_defocus` on one path."""
    image = image.detach().clone().requires_grad_(True)
    coc = coc.detach().clone().requires_grad_(True)
    if depth is not None:
        depth = depth.detach().clone().requires_grad_(True)
    with kernels(triton):
        out = render_defocus(image, coc, APERTURES[name]().to(DEVICE, image.dtype), mode,
                             depth=depth, n_layers=4)
        out.backward(weights)
    return (out.detach(), image.grad, coc.grad) + (() if depth is None else (depth.grad,))


def assert_paths_agree(name, image, coc, weights, mode="scatter", depth=None):
    tol = {"rtol": 1e-4, "atol": 1e-5} if image.dtype == torch.float32 else {"rtol": 1e-9,
                                                                              "atol": 1e-11}
    expected = render(name, image, coc, weights, False, mode, depth)
    got = render(name, image, coc, weights, True, mode, depth)
    for what, a, e in zip(("output", "image gradient", "CoC gradient", "depth gradient"), got,
                          expected, strict=False):
        scale = float(e.abs().max()) or 1.0
        torch.testing.assert_close(a / scale, e / scale, **tol, msg=lambda m, w=what: f"{w}: {m}")


@pytest.mark.parametrize("shape", [(2, 3, 9, 13), (1, 1, 20, 137)], ids=["b2c3", "c1-tiles"])
@pytest.mark.parametrize("k", [3, 7, 11])
@pytest.mark.parametrize("name", list(APERTURES))
def test_kernels_match_pytorch_path(name, k, shape, dtype):
    """Forward and both gradients; the 11-wide window is wider than the 9-row image."""
    assert_paths_agree(name, *make_inputs(name, shape, k, dtype))


@pytest.mark.parametrize("shape", [(2, 3, 9, 13), (1, 1, 11, 21)], ids=["b2c3", "c1"])
@pytest.mark.parametrize("name", list(APERTURES))
def test_many_small_tiles(name, shape):
    """Tiles of 2 x 8 pixels: every tile border and partial tile of the images above."""
    with mock.patch.multiple(_render_triton, BLOCK_H=2, BLOCK_W=8, NUM_WARPS=1):
        assert_paths_agree(name, *make_inputs(name, shape, 7, torch.float64))


@pytest.mark.parametrize("name", ["disk", "hexagon"])
def test_smooth_coc_skips_only_empty_taps(name):
    """A CoC ramp: the tiles' largest radii differ, so the kernels skip different offsets."""
    image, _, weights = make_inputs(name, (1, 3, 33, 12), 9, torch.float64)
    ramp = torch.linspace(0, coc_max(name, 9), 33, dtype=torch.float64, device=DEVICE)
    assert_paths_agree(name, image, ramp.view(1, 1, 33, 1).expand(1, 1, 33, 12), weights)


@pytest.mark.parametrize("name", list(APERTURES))
def test_zero_coc_single_tap_window(name):
    image, coc, weights = make_inputs(name, (1, 3, 6, 7), 3, torch.float64)
    assert_paths_agree(name, image, coc * 0, weights)


def test_render_defocus_reaches_the_triton_kernels():
    image, coc, weights = make_inputs("disk", (1, 3, 8, 8), 5, torch.float32)
    with mock.patch.object(_render_triton, "render", wraps=_render_triton.render) as fwd, \
            mock.patch.object(_render_triton, "render_backward",
                              wraps=_render_triton.render_backward) as bwd:
        render("disk", image, coc, weights, triton=True)
    assert fwd.call_count == 1 and bwd.call_count == 1


@pytest.mark.parametrize("name", ["gaussian", "disk"])
def test_gradcheck(name):
    image, coc, _ = make_inputs(name, (1, 2, 5, 6), 5, torch.float64, seed=1)
    coc = coc * 0.9  # clear of the largest CoC that still fits the window (a jump in K)
    psf = APERTURES[name]().to(DEVICE, torch.float64)
    with kernels(triton=True):
        assert gradcheck(lambda i, c: render_defocus(i, c, psf, "scatter"),
                         (image.requires_grad_(), coc.requires_grad_()), fast_mode=True)


# ------------------------------------------------------------------ unnormalised spreads


def _spread_inputs(kind: str, channels: int, dtype, half: int = 3, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    shape = (2, channels, 11, 19)
    x = torch.rand(shape, generator=gen, dtype=torch.float64)
    grad = torch.randn(shape, generator=gen, dtype=torch.float64)
    norm = 0.5 + torch.rand(2, 1, 11, 19, generator=gen, dtype=torch.float64)
    size = torch.rand(2, 1, 11, 19, generator=gen, dtype=torch.float64)
    # Gaussian sigma in [0.3, 1.3] px; clamp rho within the window's largest distance
    param = 0.3 + size if kind == "gaussian" else 0.5 + size * half
    offsets = torch.arange(-half, half + 1, dtype=torch.float64)
    dist = torch.sqrt(offsets[:, None] ** 2 + offsets[None, :] ** 2)
    return [t.to(DEVICE, dtype) for t in (x, grad, norm, param, dist)]


@pytest.mark.parametrize("channels", [1, 5, 12, 16])
@pytest.mark.parametrize("kind", ["gaussian", "clamp"])
def test_spread_operators_match_pytorch_path(kind, channels, dtype):
    """`gaussian_scatter` / `clamp_scatter` and their backward operators, for channel counts
    that fill `CHANNEL_GROUP` channels per program partly, in one group or two, and fully."""
    x, grad, norm, param, dist = _spread_inputs(kind, channels, dtype)
    half = torch.tensor(3)
    if kind == "gaussian":
        calls = (lambda: _render_ops.gaussian_scatter(x, param, norm, half),
                 lambda: _render_ops.gaussian_scatter_backward(grad, x, param, half))
    else:
        calls = (lambda: _render_ops.clamp_scatter(x, param, norm, dist, half),
                 lambda: _render_ops.clamp_scatter_backward(grad, x, param, dist, half))
    tol = {"rtol": 1e-4, "atol": 1e-5} if dtype == torch.float32 else {"rtol": 1e-9,
                                                                        "atol": 1e-11}
    for call in calls:
        with kernels(False):
            expected = call()
        with kernels(True):
            got = call()
        for a, e in zip(torch.utils._pytree.tree_leaves(got),
                        torch.utils._pytree.tree_leaves(expected), strict=True):
            scale = float(e.abs().max()) or 1.0
            torch.testing.assert_close(a / scale, e / scale, **tol)


@pytest.mark.parametrize("half", [0, 1, 4])
@pytest.mark.parametrize("kind", ["gaussian", "clamp"])
def test_window_sums_match_pytorch_path(kind, half, dtype):
    """The unit-energy sums of the spreads (`gaussian_window_sums`, `clamp_window_sums`), over
    more pixels than one program holds; the clamp's window is cut from a wider table."""
    _, _, _, param, dist = _spread_inputs(kind, 1, dtype, half=4, seed=6)
    param = param.repeat(1, 1, 2, 1)  # 2 x 22 x 19 values: two programs and a partial one
    half_t = torch.tensor(half)
    if kind == "gaussian":
        def call():
            return _render_ops.gaussian_window_sums(param, half_t)
    else:
        def call():
            return _render_ops.clamp_window_sums(param, dist, half_t)
    with kernels(False):
        expected = call()
    with kernels(True):
        got = call()
    tol = {"rtol": 1e-5, "atol": 1e-5} if dtype == torch.float32 else {"rtol": 1e-12,
                                                                        "atol": 1e-12}
    for a, e in zip(got, expected, strict=True):
        assert a.dtype == e.dtype == dtype
        torch.testing.assert_close(a, e, **tol)


def test_layered_mode_needs_no_host_read_of_the_window_sums():
    """The disk's window sums on the Triton path read nothing back to the host (the PyTorch
    loop lists the window's distinct distances)."""
    _, _, _, rho, dist = _spread_inputs("clamp", 1, torch.float32, half=3)
    with kernels(True), mock.patch.object(torch.Tensor, "tolist",
                                          side_effect=AssertionError("host read")):
        _render_ops.clamp_window_sums(rho, dist, torch.tensor(3))


@pytest.mark.parametrize("name", list(APERTURES))
def test_gather_mode_matches_pytorch_path(name, dtype):
    assert_paths_agree(name, *make_inputs(name, (2, 3, 9, 13), 7, dtype), mode="gather")


@pytest.mark.parametrize("scene", [False, True], ids=["random-depth", "two-planes"])
@pytest.mark.parametrize("name", list(APERTURES))
def test_layered_mode_matches_pytorch_path(name, scene, dtype):
    """Four layers (16 channels: four groups); depth per pixel, or two planes (layers absent
    from most windows)."""
    image, coc, weights = make_inputs(name, (1, 3, 12, 17), 7, dtype, seed=2)
    gen = torch.Generator().manual_seed(5)
    depth = 1.0 + 4.0 * torch.rand(1, 1, 12, 17, generator=gen, dtype=torch.float64)
    if scene:
        depth = torch.where(torch.arange(17) < 8, 1.5, 4.0).to(torch.float64).expand(1, 1, 12, 17)
    assert_paths_agree(name, image, coc, weights, "layered", depth.to(DEVICE, dtype))


def test_layered_mode_reaches_the_spread_kernels():
    image, coc, weights = make_inputs("disk", (1, 3, 8, 8), 5, torch.float32)
    depth = (1.0 + coc).detach()
    with mock.patch.object(_render_triton, "spread", wraps=_render_triton.spread) as fwd, \
            mock.patch.object(_render_triton, "spread_backward",
                              wraps=_render_triton.spread_backward) as bwd:
        render("disk", image, coc, weights, True, "layered", depth)
    assert fwd.call_count >= 1 and bwd.call_count >= 1


@pytest.mark.parametrize("kind", ["gaussian", "clamp"])
def test_spread_gradcheck(kind):
    x, _, norm, param, dist = _spread_inputs(kind, 5, torch.float64, half=2, seed=3)
    x, norm, param = (t[:1, :, :5, :6].clone().requires_grad_() for t in (x, norm, param))
    half = torch.tensor(2)
    if kind == "gaussian":
        def fn(x, p, n):
            return _render_ops.gaussian_scatter(x, p, n, half)
    else:
        param = param.detach().add(0.013).requires_grad_()  # clear of the clamp's kinks

        def fn(x, p, n):
            return _render_ops.clamp_scatter(x, p, n, dist, half)
    with kernels(triton=True):
        assert gradcheck(fn, (x, param, norm), fast_mode=True)


@pytest.mark.parametrize("mode", ["scatter", "gather", "layered"])
@pytest.mark.parametrize("name", ["gaussian", "disk"])
def test_window_on_the_device_gives_the_host_window_render(name, mode, monkeypatch):
    """In a training step on a GPU (`values_checked`) the window's half-width is computed on the
    device and read by the kernels alone, from a distance table as wide as `max_kernel_size`:
    the same values and gradients as the window the host reads."""
    from optics.checks import values_checked
    from optics.render import renderer

    image, coc, weights = make_inputs(name, (1, 3, 10, 13), 7, torch.float64, seed=4)
    depth = (1.0 + coc).detach() if mode == "layered" else None
    expected = render(name, image, coc, weights, True, mode, depth)
    monkeypatch.setattr(renderer, "_window_on_device", lambda psf, image: True)
    halves = []

    def spy(fn):
        def wrapped(*args):
            halves.append(args[-2])
            return fn(*args)
        return wrapped

    for launcher in ("render", "render_backward", "spread", "spread_backward", "window_sums"):
        monkeypatch.setattr(_render_triton, launcher, spy(getattr(_render_triton, launcher)))
    with values_checked(), mock.patch.object(torch.Tensor, "tolist",
                                             side_effect=AssertionError("host read")):
        got = render(name, image, coc, weights, True, mode, depth)
    assert halves and all(isinstance(h, torch.Tensor) for h in halves)
    for a, e in zip(got, expected, strict=True):
        torch.testing.assert_close(a, e, rtol=1e-9, atol=1e-11)
