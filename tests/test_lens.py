import math

import pytest
import torch
from torch import nn

from optics import ThinLens

FOCAL_LENGTHS = [0.035, 0.05]
F_NUMBERS = [1.4, 2.8, 8.0]
FOCUS_DISTANCES = [0.5, 2.0, 8.0]
DEPTHS = [0.3, 0.9, 1.5, 2.0, 3.0, 10.0, 100.0]


def coc_by_similar_triangles(f, n, focus, depth):
    """CoC from image distances: the cone of light from the aperture converges at the object's
    image distance; its width at the sensor (placed at the focus image distance) is the CoC."""
    aperture = f / n
    sensor_distance = 1 / (1 / f - 1 / focus)
    image_distance = 1 / (1 / f - 1 / depth)
    return aperture * abs(image_distance - sensor_distance) / image_distance


@pytest.mark.parametrize("f", FOCAL_LENGTHS)
@pytest.mark.parametrize("n", F_NUMBERS)
@pytest.mark.parametrize("focus", FOCUS_DISTANCES)
def test_coc_matches_similar_triangles(f, n, focus, dtype):
    lens = ThinLens(f, n, focus)
    depth = torch.tensor(DEPTHS, dtype=dtype)
    expected = torch.tensor([coc_by_similar_triangles(f, n, focus, d) for d in DEPTHS], dtype=dtype)
    coc = lens.coc_diameter(depth)
    assert coc.dtype == dtype
    torch.testing.assert_close(
        coc, expected, rtol=1e-5 if dtype == torch.float32 else 1e-10, atol=0
    )


def test_signed_coc_sign_and_infinity(dtype):
    lens = ThinLens(0.05, 2.0, 2.0)
    depth = torch.tensor([1.0, 2.0, 4.0, float("inf")], dtype=dtype)
    signed = lens.signed_coc_diameter(depth)
    assert signed[0] < 0 and signed[1] == 0 and signed[2] > 0
    # At infinity the CoC tends to f^2 / (N (D_f - f)).
    torch.testing.assert_close(signed[3], torch.tensor(0.05**2 / (2.0 * 1.95), dtype=dtype))
    torch.testing.assert_close(lens.coc_diameter(depth), signed.abs())


@pytest.mark.parametrize("n", F_NUMBERS)
@pytest.mark.parametrize("coc_limit", [20e-6, 30e-6])
def test_hyperfocal_closed_form_and_property(n, coc_limit):
    f = 0.05
    lens = ThinLens(f, n, 3.0)
    h = lens.hyperfocal_distance(coc_limit)
    assert math.isclose(h.item(), f * f / (n * coc_limit) + f, rel_tol=1e-6)
    # Focused at H, a point at infinity is imaged with exactly the CoC limit.
    at_h = ThinLens(torch.tensor(f, dtype=torch.float64), n, h.double())
    assert math.isclose(
        at_h.coc_diameter(torch.tensor(float("inf"), dtype=torch.float64)).item(),
        coc_limit,
        rel_tol=1e-9,
    )


@pytest.mark.parametrize("f", FOCAL_LENGTHS)
@pytest.mark.parametrize("n", F_NUMBERS)
@pytest.mark.parametrize("focus", FOCUS_DISTANCES)
def test_depth_of_field_limits(f, n, focus):
    coc_limit = 30e-6
    lens = ThinLens(torch.tensor(f, dtype=torch.float64), n, focus)
    near, far = lens.depth_of_field(coc_limit)
    hyperfocal = f * f / (n * coc_limit) + f
    # Textbook closed forms, written independently of the library.
    assert math.isclose(
        near.item(), focus * (hyperfocal - f) / (hyperfocal + focus - 2 * f), rel_tol=1e-9
    )
    if focus < hyperfocal:
        assert math.isclose(
            far.item(), focus * (hyperfocal - f) / (hyperfocal - focus), rel_tol=1e-9
        )
        assert math.isclose(
            coc_by_similar_triangles(f, n, focus, far.item()), coc_limit, rel_tol=1e-6
        )
    else:
        assert math.isinf(far.item())
    # The CoC at both limits equals the limit (a property, not the formula again).
    assert math.isclose(coc_by_similar_triangles(f, n, focus, near.item()), coc_limit, rel_tol=1e-6)
    assert near.item() < focus <= far.item()


def test_far_limit_is_infinite_beyond_hyperfocal():
    lens = ThinLens(0.035, 16.0, 5.0)  # H = 0.035^2 / (16 * 30e-6) + 0.035 = 2.59 m < 5 m
    near, far = lens.depth_of_field(30e-6)
    assert math.isinf(far.item()) and 0 < near.item() < 5.0


@pytest.mark.parametrize("focus", FOCUS_DISTANCES)
def test_depth_from_coc_inverts(focus, dtype):
    lens = ThinLens(0.05, 2.0, focus)
    depth = torch.tensor([0.3, focus * 0.7, focus * 1.6, 50.0], dtype=dtype)
    coc = lens.coc_diameter(depth)
    near, far = lens.depth_from_coc(coc)
    recovered = torch.where(depth < focus, near, far)
    torch.testing.assert_close(
        recovered, depth, rtol=1e-4 if dtype == torch.float32 else 1e-9, atol=0
    )
    torch.testing.assert_close(
        lens.depth_from_signed_coc(lens.signed_coc_diameter(depth)),
        depth,
        rtol=1e-4 if dtype == torch.float32 else 1e-9,
        atol=0,
    )
    # A CoC larger than the one at infinity has no far solution.
    _, far_big = lens.depth_from_coc(torch.tensor([1.0], dtype=dtype))
    assert torch.isinf(far_big).all()


def test_batched_parameters_broadcast():
    lens = ThinLens(0.05, torch.tensor([2.0, 4.0]), torch.tensor([2.0, 3.0]))
    depth = torch.full((2, 1, 3, 3), 5.0)
    coc = lens.coc_diameter(depth)
    assert coc.shape == (2, 1, 3, 3)
    for i, (n, focus) in enumerate([(2.0, 2.0), (4.0, 3.0)]):
        expected = coc_by_similar_triangles(0.05, n, focus, 5.0)
        assert torch.allclose(coc[i], torch.tensor(expected), rtol=1e-5)


def test_parameters_and_buffers_and_state_dict():
    lens = ThinLens(0.05, nn.Parameter(torch.tensor(2.0)), 2.0)
    assert [name for name, _ in lens.named_parameters()] == ["f_number"]
    assert set(lens.state_dict()) == {"focal_length", "f_number", "focus_distance"}
    lens64 = lens.to(torch.float64)
    assert lens64.focal_length.dtype == torch.float64


def coc_as_function(name):
    base = {"focal_length": 0.05, "f_number": 2.0, "focus_distance": 2.0}

    def fn(value, depth):
        return ThinLens(**{**base, name: value}).signed_coc_diameter(depth)

    return fn, torch.tensor(base[name], dtype=torch.float64, requires_grad=True)


@pytest.mark.parametrize("name", ["focal_length", "f_number", "focus_distance"])
def test_gradcheck_lens_parameters(name):
    fn, value = coc_as_function(name)
    depth = torch.tensor([0.7, 1.3, 3.0, 9.0], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(fn, (value, depth))
    # The unsigned CoC too, away from the focus plane where |.| has a kink.
    assert torch.autograd.gradcheck(
        lambda v, d: ThinLens(0.05, v, 2.0).coc_diameter(d),
        (value.detach().clone().requires_grad_(), depth),
    )


def test_device_and_dtype_follow_input(device, dtype):
    lens = ThinLens(0.05, 2.0, 2.0).to(device)
    depth = torch.rand(2, 1, 4, 4, device=device, dtype=dtype) + 0.5
    coc = lens.coc_diameter(depth)
    assert coc.device.type == device.type and coc.dtype == dtype


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"focal_length": -0.05, "f_number": 2.0, "focus_distance": 2.0}, "focal_length"),
        ({"focal_length": 0.0, "f_number": 2.0, "focus_distance": 2.0}, "focal_length"),
        ({"focal_length": 0.05, "f_number": 0.0, "focus_distance": 2.0}, "f_number"),
        ({"focal_length": 0.05, "f_number": float("nan"), "focus_distance": 2.0}, "f_number"),
        ({"focal_length": 0.05, "f_number": 2.0, "focus_distance": 0.04}, "focus_distance"),
        ({"focal_length": 0.05, "f_number": 2.0, "focus_distance": 0.05}, "focus_distance"),
        ({"focal_length": 0.05, "f_number": torch.ones(2, 2), "focus_distance": 2.0}, "f_number"),
    ],
)
def test_bad_lens_parameters(kwargs, name):
    with pytest.raises(ValueError, match=name):
        ThinLens(**kwargs)


def test_bad_parameter_type():
    with pytest.raises(TypeError, match="focal_length"):
        ThinLens("50mm", 2.0, 2.0)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_bad_depth(bad):
    lens = ThinLens(0.05, 2.0, 2.0)
    with pytest.raises(ValueError, match="depth"):
        lens.coc_diameter(torch.tensor([1.0, bad]))


def test_bad_coc_limit():
    with pytest.raises(ValueError, match="coc_limit"):
        ThinLens(0.05, 2.0, 2.0).hyperfocal_distance(0.0)


def test_a_nan_blur_gives_a_nan_depth_not_infinity():
    lens = ThinLens(0.05, 2.0, 2.0)
    depth = lens.depth_from_signed_coc(torch.tensor([float("nan"), 1.0]))
    assert torch.isnan(depth[0]) and torch.isinf(depth[1])
    with pytest.raises(ValueError, match="coc_diameter must be >= 0 .* the first nan"):
        lens.depth_from_coc(torch.tensor([1e-5, float("nan")]))


def test_numpy_numbers_and_arrays_are_taken_bools_are_not():
    import numpy as np

    lens = ThinLens(np.float32(0.05), np.int64(2), np.array([2.0, 3.0]))
    assert torch.allclose(lens.focus_distance, torch.tensor([2.0, 3.0], dtype=lens.focus_distance.dtype))
    assert float(lens.f_number) == 2.0 and abs(float(lens.focal_length) - 0.05) < 1e-8
    for value in (torch.tensor(True), np.bool_(True), np.array(["a"])):
        with pytest.raises(TypeError, match="focal_length must"):
            ThinLens(value, 2.0, 2.0)


def test_parameters_of_different_batch_sizes_are_refused_when_built():
    with pytest.raises(ValueError, match=r"the same B\), got sizes \{'focal_length': 2, "
                                         r"'focus_distance': 3\}"):
        ThinLens([0.05, 0.035], 2.8, [2.0, 3.0, 4.0])
    assert ThinLens([0.05, 0.035], [2.8], [2.0, 3.0]).coc_diameter(
        torch.full((2, 1, 2, 2), 4.0)).shape == (2, 1, 2, 2)
