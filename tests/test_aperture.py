import math

import pytest
import torch

from optics import Camera, Disk, Gaussian, Mask, Polygon, Sensor, ThinLens, parse_aperture


def disk_mask(size=65):
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, size), torch.linspace(-1, 1, size), indexing="ij")
    return ((xx**2 + yy**2) <= 1).double()


APERTURES = {
    "gaussian": lambda: Gaussian(),
    "disk": lambda: Disk(),
    "hexagon": lambda: Polygon(6, rotation=0.3),
    "triangle": lambda: Polygon(3),
    "mask": lambda: Mask(disk_mask()),
}


@pytest.mark.parametrize("name", APERTURES)
@pytest.mark.parametrize("coc", [0.0, 0.7, 3.0, 8.5])
def test_kernels_sum_to_one_and_are_centred(name, coc, dtype):
    aperture = APERTURES[name]().to(dtype)
    kernel = aperture.kernel(torch.tensor([coc], dtype=dtype))
    assert kernel.dtype == dtype and kernel.shape[-1] % 2 == 1
    torch.testing.assert_close(kernel.sum((-2, -1)), torch.ones(1, dtype=dtype))
    assert (kernel >= 0).all()
    half = kernel.shape[-1] // 2
    offsets = torch.arange(-half, half + 1, dtype=dtype)
    # Centred: the first moments vanish (a triangle is not point-symmetric: only nearly).
    mean_y = (kernel[0].sum(-1) * offsets).sum()
    mean_x = (kernel[0].sum(-2) * offsets).sum()
    tol = 1e-5 if dtype == torch.float32 else 1e-9
    if name != "triangle":
        assert abs(mean_y) < tol and abs(mean_x) < tol
    else:  # a triangle's centroid is the circle's centre; pixel sampling shifts it by < 0.1 px
        assert math.hypot(mean_y, mean_x) < 0.1


@pytest.mark.parametrize("name", APERTURES)
def test_zero_coc_is_a_delta(name):
    kernel = APERTURES[name]().kernel(0.0)
    assert kernel.shape == (1, 1, 1) and kernel.item() == 1.0


def test_gaussian_kernel_matches_closed_form(dtype):
    coc, size = 3.0, 9
    sigma = 0.5 * coc
    offsets = torch.arange(size, dtype=dtype) - size // 2
    g = torch.exp(-(offsets**2) / (2 * sigma**2))
    expected = torch.outer(g, g) / torch.outer(g, g).sum()
    torch.testing.assert_close(Gaussian().kernel(coc, size)[0].to(dtype), expected)
    assert Gaussian().kernel_size(coc) == 2 * math.ceil(3 * sigma) + 1


def test_disk_area_matches_circle():
    kernel_weights = Disk().profile(
        torch.arange(-20, 21.0).view(-1, 1), torch.arange(-20, 21.0).view(1, -1), torch.tensor(30.0)
    )
    # The anti-aliased edge conserves area to first order: sum of weights ~ pi r^2.
    assert abs(kernel_weights.sum().item() / (math.pi * 15**2) - 1) < 0.01


def test_polygon_is_inside_disk_and_hexagon_area():
    coc = torch.tensor(40.0)
    grid = torch.arange(-25, 26.0)
    dy, dx = grid.view(-1, 1), grid.view(1, -1)
    hexagon = Polygon(6).profile(dy, dx, coc)
    assert (hexagon <= Disk().profile(dy, dx, coc) + 1e-6).all()
    radius = 20.0
    area = 3 * math.sqrt(3) / 2 * radius**2
    assert abs(hexagon.sum().item() / area - 1) < 0.01


@pytest.mark.parametrize("name", ["disk", "hexagon", "gaussian", "mask"])
@pytest.mark.parametrize("coc", [2.3, 5.1])
def test_kernel_gradient_wrt_coc_matches_finite_differences(name, coc):
    aperture = APERTURES[name]().double()
    size = aperture.kernel_size(coc + 1.0)
    value = torch.tensor([coc], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda c: aperture.kernel(c, size), (value,), eps=1e-6, atol=1e-6
    )
    grad = torch.autograd.grad(
        (aperture.kernel(value, size) * torch.randn(size, size).double()).sum(), value
    )[0]
    assert grad.abs().item() > 0


def test_disk_radius_gradient_is_nonzero_for_any_radius():
    for coc in torch.linspace(1.1, 12.0, 40, dtype=torch.float64):
        value = coc.clone().reshape(1).requires_grad_(True)
        kernel = Disk().kernel(value, 15)
        # The spread (second moment) of the kernel grows with the disk.
        offsets = torch.arange(-7, 8, dtype=torch.float64)
        spread = (kernel[0] * (offsets.view(-1, 1) ** 2 + offsets.view(1, -1) ** 2)).sum()
        (grad,) = torch.autograd.grad(spread, value)
        assert grad.item() > 0, float(coc)


def test_batched_kernels():
    kernels = Disk().kernel(torch.tensor([1.0, 4.0, 6.0]))
    assert kernels.shape == (3, 7, 7)
    torch.testing.assert_close(kernels.sum((-2, -1)), torch.ones(3))


@pytest.mark.parametrize(
    "build, exc, name",
    [
        (lambda: Polygon(2), ValueError, "n_blades"),
        (lambda: Polygon(6, rotation=float("nan")), ValueError, "rotation"),
        (lambda: Gaussian(0.0), ValueError, "scale"),
        (lambda: Mask(torch.zeros(5, 5)), ValueError, "image"),
        (lambda: Mask(torch.ones(5)), ValueError, "image"),
        (lambda: Mask([[1.0]]), TypeError, "image"),
        (lambda: Disk().kernel(-1.0), ValueError, "coc_px"),
        (lambda: Disk().kernel(2.0, kernel_size=4), ValueError, "kernel_size"),
    ],
)
def test_bad_aperture_input(build, exc, name):
    with pytest.raises(exc, match=name):
        build()


@pytest.mark.parametrize(("make", "error", "message"), [
    (lambda: Gaussian(torch.tensor([0.5, 1.0])), ValueError, "one floating-point number"),
    (lambda: Gaussian(torch.tensor(1)), ValueError, "one floating-point number"),
    (lambda: Gaussian(6.0), ValueError, "at most 5"),
    (lambda: Gaussian(True), TypeError, "must be a number"),
    (lambda: Gaussian("0.5"), TypeError, "must be a number"),
    (lambda: Polygon(65), ValueError, "from 3 to 64"),
    (lambda: Polygon(6, rotation="abc"), ValueError, "finite angle"),
    (lambda: Polygon(6, rotation=None), ValueError, "finite angle"),
])
def test_apertures_refuse_what_their_spec_cannot_hold(make, error, message):
    with pytest.raises(error, match=message):
        make()


@pytest.mark.parametrize("aperture", [Gaussian(5.0), Gaussian(1e-3), Polygon(64), Polygon(3, 0.5)])
def test_every_aperture_that_can_be_built_has_a_spec(aperture):
    settings = Camera(ThinLens(0.05, 2.0, 2.0), Sensor(1e-5), aperture).settings()
    again = parse_aperture(settings.aperture)
    assert type(again) is type(aperture) and again.extra_repr() == aperture.extra_repr()
