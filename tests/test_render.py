"""Tests of the per-pixel PSF renderer (optics/render/renderer.py, optics/render/ops.py, the C++
kernel)."""

import math

import kornia
import pytest
import torch
from torch.autograd import gradcheck

from optics import (
    Camera,
    DefocusRenderer,
    Disk,
    Gaussian,
    Mask,
    Polygon,
    Sensor,
    ThinLens,
    render_defocus,
)
from optics.render import cpp as _render_cpp
from optics.render import layer_weights
from optics.render import ops as _render_ops

MODES = ["scatter", "gather", "layered"]


def _ring_mask():
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, 21), torch.linspace(-1, 1, 21), indexing="ij")
    r = (xx**2 + yy**2).sqrt()
    return Mask(((r < 1) & (r > 0.3)).double() + 0.5 * (r < 0.3).double())


PSFS = {
    "gaussian": Gaussian,
    "disk": Disk,
    "pentagon": lambda: Polygon(5, rotation=0.3),
    "mask": _ring_mask,
}


def _render(image, coc, psf, mode, depth=None, **kwargs):
    if mode == "layered" and depth is None:
        depth = torch.full_like(coc, 3.0)
    return render_defocus(image, coc, psf, mode, depth=depth, **kwargs)


def _tol(dtype):
    return 1e-5 if dtype == torch.float32 else 1e-10


# ------------------------------------------------------------------ exactness anchors


@pytest.mark.parametrize("mode", MODES)
def test_constant_coc_equals_kornia_gaussian_blur(mode, dtype):
    image = torch.rand(2, 3, 32, 30, dtype=dtype)
    coc = torch.full((2, 1, 32, 30), 3.0, dtype=dtype)  # sigma 1.5 px, window 2*ceil(4.5)+1 = 11
    out = _render(image, coc, Gaussian(), mode)
    ref = kornia.filters.gaussian_blur2d(image, (11, 11), (1.5, 1.5))
    torch.testing.assert_close(out[..., 5:-5, 5:-5], ref[..., 5:-5, 5:-5], atol=1e-5, rtol=0)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", ["disk", "pentagon", "mask"])
def test_constant_coc_equals_convolution_with_aperture_kernel(name, mode, dtype):
    psf = PSFS[name]().to(dtype)
    image = torch.rand(1, 2, 27, 25, dtype=dtype)
    coc = torch.full((1, 1, 27, 25), 5.5, dtype=dtype)
    kernel = psf.kernel(torch.tensor(5.5, dtype=dtype))  # (1, K, K), sums to 1
    half = kernel.shape[-1] // 2
    # Convolution: the PSF of a source at offset u lands at +u, so correlate with the flipped kernel.
    ref = kornia.filters.filter2d(image, kernel.flip(-1, -2))
    out = _render(image, coc, psf, mode)
    inner = (..., slice(half, -half), slice(half, -half))
    torch.testing.assert_close(out[inner], ref[inner], atol=1e-5, rtol=0)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", list(PSFS))
def test_zero_coc_is_identity(name, mode, dtype):
    image = torch.rand(2, 3, 9, 11, dtype=dtype)
    out = _render(image, torch.zeros(2, 1, 9, 11, dtype=dtype), PSFS[name]().to(dtype), mode,
                  depth=torch.rand(2, 1, 9, 11, dtype=dtype) + 1)
    torch.testing.assert_close(out, image, atol=_tol(dtype), rtol=0)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", list(PSFS))
def test_constant_image_stays_constant_borders_included(name, mode, dtype):
    torch.manual_seed(0)
    image = torch.full((2, 3, 13, 12), 0.37, dtype=dtype)
    coc = torch.rand(2, 1, 13, 12, dtype=dtype) * 6
    depth = torch.rand(2, 1, 13, 12, dtype=dtype) * 4 + 1
    out = _render(image, coc, PSFS[name]().to(dtype), mode, depth=depth)
    torch.testing.assert_close(out, image, atol=_tol(dtype), rtol=0)


@pytest.mark.parametrize("mode", ["scatter", "gather"])
@pytest.mark.parametrize("name", ["gaussian", "pentagon"])
def test_spatially_varying_matches_brute_force(name, mode, brute_force_render):
    torch.manual_seed(1)
    image = torch.rand(1, 2, 7, 8, dtype=torch.float64)
    coc = torch.rand(1, 1, 7, 8, dtype=torch.float64) * 4
    psf = PSFS[name]().double()
    out = render_defocus(image, coc, psf, mode)
    torch.testing.assert_close(out, brute_force_render(image, coc, psf, mode == "scatter"))


@pytest.mark.parametrize("mode", ["scatter", "gather"])
def test_mask_with_a_signed_coc_matches_brute_force(mode, brute_force_render):
    """A code without point symmetry and CoCs on both sides of the focus plane: the tabulated
    profile (`optics.render.profile`) against the exact kernels of every pixel, to the
    interpolation's error (256 knots a pixel)."""
    gen = torch.Generator().manual_seed(4)
    psf = Mask(torch.rand(5, 5, generator=gen, dtype=torch.float64))
    image = torch.rand(1, 2, 9, 8, generator=gen, dtype=torch.float64)
    coc = torch.rand(1, 1, 9, 8, generator=gen, dtype=torch.float64) * 9 - 4.5
    out = render_defocus(image, coc, psf, mode)
    torch.testing.assert_close(out, brute_force_render(image, coc, psf, mode == "scatter"),
                               atol=5e-5, rtol=0)


def test_paper_preset_matches_brute_force_double_loop(dtype):
    torch.manual_seed(2)
    h, w = 9, 10
    image = torch.rand(2, 3, h, w, dtype=dtype)
    coc = torch.rand(2, 1, h, w, dtype=dtype) * 9  # spans <= 1 (copied), 1..7 and > 7 (clamped)
    out = render_defocus(image, coc, preset="gur_wolf_2019")
    expected = torch.empty_like(image)
    for b in range(2):
        for py in range(h):
            for px in range(w):
                if coc[b, 0, py, px] <= 1:
                    expected[b, :, py, px] = image[b, :, py, px]
                    continue
                num, den = 0.0, 0.0
                for qy in range(max(0, py - 3), min(h, py + 4)):
                    for qx in range(max(0, px - 3), min(w, px + 4)):
                        c = float(coc[b, 0, qy, qx])
                        if c <= 1:
                            continue
                        c = min(c, 7.0)
                        wgt = c**-2 * math.exp(-2 * ((py - qy) ** 2 + (px - qx) ** 2) / c**2)
                        num = num + wgt * image[b, :, qy, qx].double()
                        den += wgt
                expected[b, :, py, px] = (num / den).to(dtype)
    torch.testing.assert_close(out, expected, atol=_tol(dtype), rtol=0)


# ------------------------------------------------------------------ occlusion


def _depth_edge_scene():
    """Red sharp foreground (left half, in focus) in front of a blurred blue background."""
    h, w = 16, 24
    image = torch.zeros(1, 3, h, w, dtype=torch.float64)
    image[:, 0, :, : w // 2] = 1.0
    image[:, 2, :, w // 2 :] = 1.0
    depth = torch.full((1, 1, h, w), 10.0, dtype=torch.float64)
    depth[..., : w // 2] = 2.0
    camera = Camera(ThinLens(0.05, 1.4, 2.0), Sensor(6e-5))
    return image, depth, camera, w // 2


def test_layered_keeps_sharp_foreground_free_of_background():
    image, depth, camera, edge = _depth_edge_scene()
    assert float(camera.coc_px(depth)[..., edge:].min()) > 6  # background strongly blurred
    layered = camera.render(image, depth, mode="layered")
    scatter = camera.render(image, depth, mode="scatter")
    gather = camera.render(image, depth, mode="gather")
    blue_on_foreground = (..., 2, slice(None), slice(0, edge))
    assert float(layered[blue_on_foreground].max()) < 1e-9
    assert float(scatter[blue_on_foreground].max()) > 0.1  # the blurred background bleeds over
    # Both uniform regions stay uniform: nothing sharp leaks into the blurred background either,
    # which gather mode does (the background pixels gather the red foreground).
    torch.testing.assert_close(layered, image)
    assert float(gather[:, 0, :, edge:].max()) > 0.1


def test_layer_weights_partition_of_unity_and_order():
    depth = torch.tensor([1.0, 1.5, 2.0, 4.0, 8.0], dtype=torch.float64).view(1, 1, 1, 5)
    alpha = layer_weights(depth, 3)
    torch.testing.assert_close(alpha.sum(1), torch.ones(1, 1, 5, dtype=torch.float64))
    assert alpha[0, 0, 0, 0] == 1 and alpha[0, 2, 0, 4] == 1  # nearest first, farthest last
    # 1/depth = 1, 2/3, 1/2, 1/4, 1/8: layer centres at 1, 9/16, 1/8; 1/2 is 1/7 of the way on.
    torch.testing.assert_close(alpha[0, :, 0, 2], torch.tensor([0.0, 6 / 7, 1 / 7]).double())


# ------------------------------------------------------------------ gradients


def _small_inputs(seed=3):
    torch.manual_seed(seed)
    image = torch.rand(1, 2, 5, 6, dtype=torch.float64, requires_grad=True)
    coc = (torch.rand(1, 1, 5, 6, dtype=torch.float64) * 2.5 + 0.4).requires_grad_()
    depth = (torch.rand(1, 1, 5, 6, dtype=torch.float64) * 3 + 1).requires_grad_()
    return image, coc, depth


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", list(PSFS))
def test_gradcheck_image_coc_depth(name, mode):
    image, coc, depth = _small_inputs()
    psf = PSFS[name]().double()
    assert gradcheck(
        lambda i, c, d: render_defocus(i, c, psf, mode, depth=d, n_layers=3),
        (image, coc, depth), fast_mode=True,
    )


def test_gradcheck_paper_preset():
    image, coc, _ = _small_inputs()
    assert gradcheck(lambda i, c: render_defocus(i, c * 3, preset="gur_wolf_2019"), (image, coc),
                     fast_mode=True)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", ["gaussian", "disk"])
def test_gradcheck_camera_parameters(name, mode):
    image, _, depth = _small_inputs(4)
    depth = (depth.detach() * 0.5 + 0.5).requires_grad_()  # 1-2.5 m around the 1.7 m focus
    params = [torch.tensor(v, dtype=torch.float64, requires_grad=True)
              for v in (0.05, 2.0, 1.7, 3e-4)]

    def render(image, depth, focal_length, f_number, focus_distance, pixel_pitch):
        camera = Camera(ThinLens(focal_length, f_number, focus_distance), Sensor(pixel_pitch),
                        PSFS[name]().double())
        return camera.render(image, depth, mode=mode, n_layers=3)

    assert gradcheck(render, (image, depth, *params), fast_mode=True)


@pytest.mark.parametrize("mode", MODES)
def test_gaussian_scale_parameter_gradient_matches_finite_difference(mode, check_param_grad):
    image, coc, depth = (t.detach() for t in _small_inputs(5))
    psf = Gaussian(torch.nn.Parameter(torch.tensor(0.4, dtype=torch.float64)))
    weights = torch.randn_like(image)

    def loss():
        return (render_defocus(image, coc, psf, mode, depth=depth) * weights).sum()

    check_param_grad(loss, psf.scale)


# ------------------------------------------------------------------ memory and compiled kernel


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", ["gaussian", "disk"])
def test_saved_for_backward_is_independent_of_window(name, mode):
    """Autograd keeps O(image) tensors, never one weight map per window offset."""
    image = torch.rand(1, 3, 40, 40, requires_grad=True)
    coc = torch.full((1, 1, 40, 40), 12.0, requires_grad=True)  # K = 37 (Gaussian), 13 (disk)
    saved = []

    def pack(t):
        saved.append(t.numel())
        return t

    with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
        out = render_defocus(image, coc, PSFS[name](), mode, depth=coc + 1, n_layers=2)
    out.sum().backward()
    per_image = image.numel()
    layers = 2 * (3 + 1) if mode == "layered" else 1
    assert sum(saved) < 12 * per_image * layers


@pytest.mark.skipif(_render_cpp.library() is None, reason="no C++ compiler")
@pytest.mark.parametrize("shape,half", [((2, 3, 19, 23), 4), ((1, 6, 11, 40), 7), ((1, 1, 3, 2), 5)])
def test_compiled_kernel_matches_pytorch_loop(shape, half, dtype):
    torch.manual_seed(6)
    b, c, h, w = shape
    x, g = torch.rand(shape, dtype=dtype), torch.randn(shape, dtype=dtype)
    sigma = torch.rand(b, 1, h, w, dtype=dtype) * 3 + 0.01
    norm = torch.rand(b, 1, h, w, dtype=dtype)
    fwd = _render_ops._gaussian_scatter_forward_torch(x, sigma, norm, half)
    pairs = [(_render_cpp.gaussian_scatter_forward(x, sigma, norm, half), fwd)]
    pairs += zip(_render_cpp.gaussian_scatter_backward(g, x, sigma, half),
                 _render_ops._gaussian_scatter_backward_torch(g, x, sigma, half), strict=True)
    for got, want in pairs:  # sums of up to K^2 terms in another order: relative to their size
        scale = float(want.abs().max())
        torch.testing.assert_close(got, want, rtol=0, atol=scale * (1e-6 if dtype == torch.float32
                                                                    else 1e-13))


@pytest.mark.parametrize("mode", MODES)
def test_pytorch_fallback_equals_compiled_path(monkeypatch, mode):
    image, coc, depth = _small_inputs(7)
    outs = []
    for usable in (True, False):
        monkeypatch.setattr(_render_cpp, "usable", lambda x, u=usable: u and x.device.type == "cpu"
                            and _render_cpp.library() is not None)
        out = render_defocus(image, coc, mode=mode, depth=depth)
        (grad_image, grad_coc) = torch.autograd.grad(out.pow(2).sum(), (image, coc))
        outs.append((out, grad_image, grad_coc))
    for a, b in zip(*outs, strict=True):
        torch.testing.assert_close(a, b)


# ------------------------------------------------------------------ API behaviour


def test_max_kernel_size_truncates_with_warning():
    image = torch.rand(1, 1, 30, 30, dtype=torch.float64)
    coc = torch.full((1, 1, 30, 30), 6.0, dtype=torch.float64)  # needs 19 px
    with pytest.warns(UserWarning, match="truncated"):
        out = render_defocus(image, coc, max_kernel_size=7)
    ref = kornia.filters.gaussian_blur2d(image, (7, 7), (3.0, 3.0))
    torch.testing.assert_close(out[..., 3:-3, 3:-3], ref[..., 3:-3, 3:-3])


def test_module_equals_functional_and_broadcasts():
    image = torch.rand(1, 3, 12, 12).expand(3, -1, -1, -1)  # non-contiguous, as in focal stacks
    coc = torch.rand(1, 1, 12, 12) * 4
    renderer = DefocusRenderer(Disk(), mode="gather")
    assert "gather" in repr(renderer)
    torch.testing.assert_close(renderer(image, coc), render_defocus(image, coc, Disk(), "gather"))
    out = render_defocus(image, coc)
    torch.testing.assert_close(out[0], out[2])
    assert out.dtype == image.dtype


@pytest.mark.parametrize(
    "kwargs,error,match",
    [
        ({"coc_px": torch.zeros(1, 2, 8, 8)}, ValueError, "coc_px must have shape"),
        ({"coc_px": torch.zeros(1, 1, 8, 7)}, ValueError, "coc_px must have shape"),
        ({"coc_px": torch.full((1, 1, 8, 8), float("nan"))}, ValueError, "finite"),
        ({"coc_px": torch.full((1, 1, 8, 8), float("inf"))}, ValueError, "finite"),
        ({"coc_px": -torch.ones(1, 1, 8, 8)}, ValueError, ">= 0"),
        ({"mode": "blur"}, ValueError, "mode must be one of"),
        ({"mode": "layered"}, ValueError, "needs depth"),
        ({"max_kernel_size": 8}, ValueError, "positive odd"),
        ({"preset": "paper"}, ValueError, "preset must be"),
        ({"preset": "gur_wolf_2019", "psf": Disk()}, ValueError, "fixes a Gaussian"),
        ({"preset": "gur_wolf_2019", "mode": "gather"}, ValueError, "fixes a Gaussian"),
        ({"psf": "disk"}, TypeError, "psf must be an Aperture"),
        ({"mode": "layered", "depth": torch.zeros(1, 1, 8, 8)}, ValueError, "depth must be > 0"),
        ({"mode": "layered", "depth": torch.ones(1, 1, 8, 8), "n_layers": 0}, ValueError,
         "n_layers"),
    ],
)
def test_invalid_arguments_fail_early(kwargs, error, match):
    args = {"image": torch.rand(1, 3, 8, 8), "coc_px": torch.ones(1, 1, 8, 8), **kwargs}
    with pytest.raises(error, match=match):
        render_defocus(**args)


def test_image_must_be_4d_float():
    with pytest.raises(ValueError, match="image must have shape"):
        render_defocus(torch.rand(3, 8, 8), torch.ones(1, 1, 8, 8))
    with pytest.raises(TypeError, match="floating-point"):
        render_defocus(torch.ones(1, 3, 8, 8, dtype=torch.int64), torch.ones(1, 1, 8, 8))


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("name", ["gaussian", "disk"])
def test_cuda_matches_cpu(name, mode):
    image, coc, depth = _small_inputs(8)
    psf = PSFS[name]().double()
    cpu = render_defocus(image, coc, psf, mode, depth=depth)
    gpu = render_defocus(image.cuda(), coc.cuda(), psf.cuda(), mode, depth=depth.cuda())
    torch.testing.assert_close(gpu.cpu(), cpu)
    grads = torch.autograd.grad(gpu.sum(), (image, coc))
    torch.testing.assert_close(grads[0], torch.autograd.grad(cpu.sum(), image)[0])


@pytest.mark.parametrize(("options", "message"), [
    ({"max_kernel_size": 4}, "max_kernel_size must be a positive odd integer"),
    ({"preset": "foo"}, "preset must be None or one of"),
    ({"mode": "fast"}, "mode must be one of"),
    ({"n_layers": 0}, "n_layers must be a positive integer"),
    ({"psf": "disk"}, "psf must be an Aperture"),
])
def test_defocus_renderer_checks_its_options_when_built(options, message):
    from optics import DefocusRenderer

    with pytest.raises((ValueError, TypeError), match=message):
        DefocusRenderer(**options)
