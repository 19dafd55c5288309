"""The renderer's custom operators (optics.render.ops): compiled kernels against the PyTorch loops,
the disk and polygons against brute force, gradients (aperture parameters included), opcheck."""


import pytest
import torch
from torch.autograd import gradcheck

from optics import Disk, Gaussian, Polygon, render_defocus
from optics.render import cpp as _render_cpp
from optics.render import ops as _render_ops

needs_library = pytest.mark.skipif(
    _render_cpp.library() is None, reason="no C++ compiler (or DEFOCUS_NO_CPP set)"
)
SHAPES = [((2, 3, 19, 23), 4), ((1, 6, 11, 40), 7), ((1, 1, 3, 2), 5), ((1, 2, 9, 17), 0)]


def _distance(psf, half, dtype):
    d = torch.arange(-half, half + 1, dtype=dtype)
    return psf.distance(d.view(-1, 1), d.view(1, -1))


def _close(got, want, dtype):
    scale = float(want.abs().max()) if want.numel() else 1.0
    torch.testing.assert_close(got, want, rtol=0, atol=max(scale, 1.0) * (
        2e-6 if dtype == torch.float32 else 1e-12))


@pytest.fixture
def pure(monkeypatch):
    """Run a function on the PyTorch loops (the compiled kernels switched off)."""

    def run(fn, *args):
        with monkeypatch.context() as patch:
            patch.setattr(_render_cpp, "usable", lambda x: False)
            return fn(*args)

    return run


@needs_library
@pytest.mark.parametrize("shape,half", SHAPES)
@pytest.mark.parametrize("psf", [Disk(), Polygon(5, rotation=0.3)], ids=["disk", "pentagon"])
def test_clamp_kernels_match_pytorch_loops(shape, half, psf, dtype, pure):
    torch.manual_seed(6)
    b, c, h, w = shape
    x, g = torch.rand(shape, dtype=dtype), torch.randn(shape, dtype=dtype)
    rho = torch.rand(b, 1, h, w, dtype=dtype) * (half + 1) + 0.5
    norm = torch.rand(b, 1, h, w, dtype=dtype)
    dist = _distance(psf, half, dtype)
    k = torch.tensor(half)
    ops = _render_ops
    for fn, args in [
        (ops.clamp_scatter, (x, rho, norm, dist, k)),
        (ops.clamp_scatter_backward, (g, x, rho, dist, k)),
        (ops.clamp_gather, (x, rho, dist, k)),
        (ops.clamp_window_sums, (rho, dist, k)),
        (ops.clamp_render, (x, rho, dist, k)),
    ]:
        got, want = fn(*args), pure(fn, *args)
        for a, b_ in zip(got if isinstance(got, tuple) else [got],
                         want if isinstance(want, tuple) else [want], strict=True):
            _close(a, b_, dtype)
    y, den = ops.clamp_render(x, rho, dist, k)
    _close(ops.clamp_render_backward(g, y, den, x, rho, dist, k)[0],
           pure(ops.clamp_render_backward, g, y, den, x, rho, dist, k)[0], dtype)
    _close(ops.clamp_render_backward(g, y, den, x, rho, dist, k)[1],
           pure(ops.clamp_render_backward, g, y, den, x, rho, dist, k)[1], dtype)


@needs_library
@pytest.mark.parametrize("shape,half", SHAPES)
def test_fused_gaussian_kernels_match_pytorch_loops(shape, half, dtype, pure):
    torch.manual_seed(7)
    b, c, h, w = shape
    x, g = torch.rand(shape, dtype=dtype), torch.randn(shape, dtype=dtype)
    sigma = torch.rand(b, 1, h, w, dtype=dtype) * 3 + 0.01
    k = torch.tensor(half)
    y, den = _render_ops.gaussian_render(x, sigma, k)
    y_ref, den_ref = pure(_render_ops.gaussian_render, x, sigma, k)
    _close(y, y_ref, dtype)
    _close(den, den_ref, dtype)
    for got, want in zip(_render_ops.gaussian_render_backward(g, y, den, x, sigma, k),
                         pure(_render_ops.gaussian_render_backward, g, y, den, x, sigma, k),
                         strict=True):
        _close(got, want, dtype)


@pytest.mark.parametrize("mode", ["scatter", "gather"])
@pytest.mark.parametrize("psf", [Disk(), Polygon(6), Polygon(5, rotation=0.3)],
                         ids=["disk", "hexagon", "pentagon"])
def test_disk_and_polygons_match_brute_force(psf, mode, brute_force_render):
    torch.manual_seed(1)
    image = torch.rand(1, 2, 8, 9, dtype=torch.float64)
    coc = torch.rand(1, 1, 8, 9, dtype=torch.float64) * 6
    out = render_defocus(image, coc, psf.double(), mode)
    torch.testing.assert_close(out, brute_force_render(image, coc, psf.double(), mode == "scatter"))


class ScaledDisk(Disk):
    """A disk whose edge radius has a trainable gain: gradients must reach it."""

    def __init__(self, gain: float):
        super().__init__()
        self.gain = torch.nn.Parameter(torch.tensor(gain, dtype=torch.float64))

    def edge_radius(self, coc_px):
        return coc_px / 2 * self.gain


class _Gain(Disk):
    """`inner` with its edge radius times `gain`, a plain tensor (so gradcheck can vary it)."""

    def __init__(self, inner, gain):
        super().__init__()
        self.inner, self._gain = inner, gain

    def distance(self, dy, dx):
        return self.inner.distance(dy, dx)

    def edge_radius(self, coc_px):
        return self.inner.edge_radius(coc_px) * self._gain


@pytest.mark.parametrize("mode", ["scatter", "gather", "layered"])
@pytest.mark.parametrize("make", [Disk, lambda: Polygon(6, rotation=0.2)], ids=["disk", "hexagon"])
def test_gradcheck_image_coc_and_aperture_parameter(make, mode):
    torch.manual_seed(3)
    image = torch.rand(1, 2, 6, 7, dtype=torch.float64, requires_grad=True)
    coc = (torch.rand(1, 1, 6, 7, dtype=torch.float64) * 4 + 0.3).requires_grad_()
    depth = torch.rand(1, 1, 6, 7, dtype=torch.float64) + 1
    gain = torch.tensor(0.9, dtype=torch.float64, requires_grad=True)

    def render(i, c, g):
        return render_defocus(i, c, _Gain(make().double(), g), mode, depth=depth, n_layers=3)

    assert gradcheck(render, (image, coc, gain), fast_mode=True)


def test_aperture_parameter_gradient_matches_finite_difference(check_param_grad):
    torch.manual_seed(5)
    image = torch.rand(1, 3, 9, 10, dtype=torch.float64)
    coc = torch.rand(1, 1, 9, 10, dtype=torch.float64) * 4 + 0.3
    psf = ScaledDisk(0.8)
    weights = torch.randn_like(image)

    def loss():
        return (render_defocus(image, coc, psf) * weights).sum()

    check_param_grad(loss, psf.gain)


@pytest.mark.parametrize("psf", [Gaussian(), Disk(), Polygon(6)], ids=["gaussian", "disk", "hex"])
def test_custom_ops_pass_opcheck(psf):
    torch.manual_seed(9)
    x = torch.rand(1, 2, 6, 7, dtype=torch.float64, requires_grad=True)
    a = (torch.rand(1, 1, 6, 7, dtype=torch.float64) * 2 + 0.6).requires_grad_()
    half = torch.tensor(2)
    ops = _render_ops
    if isinstance(psf, Gaussian):
        cases = [(ops.gaussian_render, (x, a, half)), (ops.gaussian_gather, (x, a, half)),
                 (ops.gaussian_norm, (a, half)),
                 (ops.gaussian_scatter, (x, a, torch.rand_like(a), half))]
    else:
        dist = _distance(psf, 3, torch.float64)  # wider than the window: its centre is used
        cases = [(ops.clamp_render, (x, a, dist, half)), (ops.clamp_gather, (x, a, dist, half)),
                 (ops.clamp_norm, (a, dist, half)),
                 (ops.clamp_scatter, (x, a, torch.rand_like(a), dist, half))]
    for op, args in cases:
        torch.library.opcheck(op, args, test_utils=("test_schema", "test_autograd_registration",
                                                    "test_faketensor"))
