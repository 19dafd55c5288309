"""The layered mode's fused kernels against a slow reference of its semantics (values and gradients)."""

import pytest
import torch

from optics import Disk, Gaussian, Polygon, render_defocus
from optics.render import composite_layers, split_layers
from optics.render import cpp as _render_cpp

needs_library = pytest.mark.skipif(
    _render_cpp.library() is None, reason="no C++ compiler (or DEFOCUS_NO_CPP set)"
)


def _shift(t, dy, dx):
    """`out[..., y, x] = t[..., y - dy, x - dx]`, zero where that falls outside."""
    h, w = t.shape[-2:]
    out = torch.zeros_like(t)
    if abs(dy) >= h or abs(dx) >= w:
        return out
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
    out[..., yd, xd] = t[..., ys, xs]
    return out


def reference_layered(image, coc, psf, depth, n_layers):
    """The layered semantics with plain autograd: per-source normalised profiles, front-to-back."""
    half = psf.half_width(float(coc.detach().max()))
    offsets = [(dy, dx) for dy in range(-half, half + 1) for dx in range(-half, half + 1)]

    def prof(dy, dx):
        return psf.profile(torch.tensor(float(dy), dtype=coc.dtype),
                           torch.tensor(float(dx), dtype=coc.dtype), coc)

    total = sum(prof(dy, dx) for dy, dx in offsets)
    layers = split_layers(image, depth, n_layers)
    spread = sum(_shift(layers * (prof(dy, dx) / total), dy, dx) for dy, dx in offsets)
    return composite_layers(spread, n_layers)


def _scene(h, w, dtype, seed, smooth):
    gen = torch.Generator().manual_seed(seed)
    image = torch.rand(2, 3, h, w, generator=gen, dtype=dtype)
    if smooth:  # a slanted plane with a disc in front: few layers per neighbourhood
        yy, xx = torch.meshgrid(torch.linspace(0, 1, h, dtype=dtype),
                                torch.linspace(0, 1, w, dtype=dtype), indexing="ij")
        depth = 2 + 5 * yy
        depth = torch.where((yy - 0.4) ** 2 + (xx - 0.5) ** 2 < 0.06, torch.ones_like(depth), depth)
        depth = depth.expand(2, 1, h, w).clone()
    else:
        depth = torch.rand(2, 1, h, w, generator=gen, dtype=dtype) * 4 + 1
    coc = torch.rand(2, 1, h, w, generator=gen, dtype=dtype) * 3.5 + 0.2
    return image, coc, depth


PSFS = {"gaussian": Gaussian, "disk": Disk, "hexagon": lambda: Polygon(6, rotation=0.1)}


@needs_library
@pytest.mark.parametrize("smooth", [False, True], ids=["random-depth", "scene"])
@pytest.mark.parametrize("name", list(PSFS))
@pytest.mark.parametrize("n_layers", [1, 8])
def test_fused_layered_matches_reference(name, smooth, n_layers, dtype):
    image, coc, depth = _scene(17, 21, dtype, seed=4, smooth=smooth)
    psf = PSFS[name]().to(dtype)
    inputs = [t.clone().requires_grad_() for t in (image, coc, depth)]
    weights = torch.randn(image.shape, generator=torch.Generator().manual_seed(5), dtype=dtype)
    outs = []
    for fn in (render_defocus, reference_layered):
        i, c, d = (t.detach().clone().requires_grad_() for t in inputs)
        if fn is render_defocus:
            out = render_defocus(i, c, psf, "layered", depth=d, n_layers=n_layers)
        else:
            out = reference_layered(i, c, psf, d, n_layers)
        outs.append((out, *torch.autograd.grad((out * weights).sum(), (i, c, d))))
    tol = 2e-5 if dtype == torch.float32 else 1e-10
    for got, want in zip(*outs, strict=True):
        scale = max(float(want.detach().abs().max()), 1.0)
        torch.testing.assert_close(got, want, rtol=0, atol=tol * scale)


@needs_library
def test_fused_layered_equals_pytorch_path_at_layer_centres(monkeypatch):
    """Pixels exactly on a layer centre (the kinks of the layer weights) get the same gradients."""
    image, coc, _ = _scene(17, 19, torch.float64, seed=6, smooth=False)
    depth = 1.0 / torch.tensor([1.0, 0.75, 0.5, 0.25], dtype=torch.float64)[
        torch.randint(0, 4, (2, 1, 17, 19), generator=torch.Generator().manual_seed(7))]
    results = []
    for usable in (True, False):
        with monkeypatch.context() as patch:
            if not usable:
                patch.setattr(_render_cpp, "usable", lambda x: False)
            i, c, d = (t.clone().requires_grad_() for t in (image, coc, depth))
            out = render_defocus(i, c, Disk().double(), "layered", depth=d, n_layers=4)
            results.append((out, *torch.autograd.grad(out.square().sum(), (i, c, d))))
    for got, want in zip(*results, strict=True):
        torch.testing.assert_close(got, want)


@needs_library
@pytest.mark.parametrize("threads", [1, 2])
def test_fused_layered_with_layers_absent_from_row_bands(monkeypatch, threads):
    """Depth bands taller than the window: most spread rows of most layers are never written."""
    gen = torch.Generator().manual_seed(8)
    image = torch.rand(2, 3, 70, 23, generator=gen, dtype=torch.float64)
    rows = torch.arange(70, dtype=torch.float64).view(1, 1, -1, 1)
    depth = (1.0 + (rows // 12) + 0.3 * torch.rand(2, 1, 70, 23, generator=gen,
                                                    dtype=torch.float64)).contiguous()
    coc = torch.rand(2, 1, 70, 23, generator=gen, dtype=torch.float64) * 2.5
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        results = []
        for usable in (True, False):
            with monkeypatch.context() as patch:
                if not usable:
                    patch.setattr(_render_cpp, "usable", lambda x: False)
                for psf in (Gaussian().double(), Disk().double()):
                    i, c, d = (t.clone().requires_grad_() for t in (image, coc, depth))
                    out = render_defocus(i, c, psf, "layered", depth=d, n_layers=8)
                    results.append((out, *torch.autograd.grad(out.square().sum(), (i, c, d))))
    finally:
        torch.set_num_threads(previous)
    for got, want in zip(results[:2], results[2:], strict=True):
        for a, b in zip(got, want, strict=True):
            torch.testing.assert_close(a, b, rtol=0, atol=1e-10)


def _composite_by_autograd(spread, n_layers):
    """Front-to-back compositing as a plain product over layers, differentiated by autograd."""
    b, _, h, w = spread.shape
    layers = spread.view(b, n_layers, -1, h, w)
    total, seen = 0, torch.ones_like(layers[:, 0, -1:])
    for layer in range(n_layers):
        total = total + seen * layers[:, layer]
        seen = seen * (1 - layers[:, layer, -1:].clamp(max=1.0))
    return total[:, :-1] / total[:, -1:].clamp_min(torch.finfo(spread.dtype).tiny)


@pytest.mark.parametrize("n_layers", [1, 2, 5, 8])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_composite_layers_gradient_matches_autograd(n_layers, dtype):
    gen = torch.Generator().manual_seed(n_layers)
    layers = torch.rand(2, n_layers, 4, 6, 7, generator=gen, dtype=dtype) * 1.3
    layers[:, :, 3, :2] = 1.0  # layers that cover fully: nothing behind them is seen
    layers[:, :, 3, 2] = 0.0  # and pixels that no layer covers
    layers[:, :, :3] *= layers[:, :, 3:]  # colour premultiplied by coverage
    spread = layers.reshape(2, -1, 6, 7).requires_grad_()
    weights = torch.randn(2, 3, 6, 7, generator=gen, dtype=dtype)
    got = composite_layers(spread, n_layers)
    want = _composite_by_autograd(spread, n_layers)
    torch.testing.assert_close(got, want)
    grad = torch.autograd.grad((got * weights).sum(), spread)[0]
    torch.testing.assert_close(grad, torch.autograd.grad((want * weights).sum(), spread)[0])
    assert torch.isfinite(grad).all()


def test_composite_layers_gradcheck():
    spread = (torch.rand(1, 12, 4, 5, dtype=torch.float64) * 1.3).requires_grad_()
    assert torch.autograd.gradcheck(lambda s: composite_layers(s, 3), (spread,))


def test_composite_layers_refuses_a_channel_count_not_a_multiple_of_layers():
    with pytest.raises(ValueError, match="n_layers=3"):
        composite_layers(torch.rand(1, 8, 2, 2), 3)
