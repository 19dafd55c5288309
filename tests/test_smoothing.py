"""Edge-aware weighted least-squares smoothing (models.depth_from_photos.smoothing)."""

import math

import pytest
import torch

from models.depth_from_photos.smoothing import edge_aware_smooth, guide_affinities


def _dense_solution(values, weight, guide, strength, sigma):
    """The minimiser from the normal equations, assembled pair by pair and solved densely."""
    _, _, h, w = values.shape
    g = guide[0].clamp_min(0) ** (1 / 2.2)
    matrix = torch.diag(weight.flatten()).to(torch.float64)
    for y in range(h):
        for x in range(w):
            for dy, dx in ((1, 0), (0, 1)):
                if y + dy < h and x + dx < w:
                    i, j = y * w + x, (y + dy) * w + x + dx
                    a = math.exp(-float(((g[:, y, x] - g[:, y + dy, x + dx]) ** 2).sum())
                                 / (2 * sigma**2))
                    matrix[i, i] += strength * a
                    matrix[j, j] += strength * a
                    matrix[i, j] -= strength * a
                    matrix[j, i] -= strength * a
    rhs = (weight * values).flatten().to(torch.float64)
    return torch.linalg.solve(matrix, rhs).reshape(1, 1, h, w)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_smoothing_is_the_least_squares_minimiser(dtype):
    g = torch.Generator().manual_seed(0)
    values = torch.rand(1, 1, 7, 9, generator=g, dtype=dtype)
    weight = torch.rand(1, 1, 7, 9, generator=g, dtype=dtype) + 0.01
    guide = torch.rand(1, 3, 7, 9, generator=g, dtype=dtype)
    out = edge_aware_smooth(values, weight, guide, strength=3.0, sigma=0.3, tolerance=1e-10)
    assert out.dtype == dtype
    expected = _dense_solution(values.double(), weight.double(), guide.double(), 3.0, 0.3)
    torch.testing.assert_close(out.double(), expected,
                               atol=1e-4 if dtype == torch.float32 else 1e-9, rtol=0)


def test_smoothing_keeps_edges_of_the_guide_and_fills_from_confident_pixels():
    """Two regions of the guide, each with a few confident pixels: every pixel takes its own
    region's value, none its neighbour's."""
    guide = torch.full((1, 3, 16, 16), 0.1)
    guide[..., 8:] = 0.7
    values = torch.where(torch.arange(16) < 8, 2.0, 5.0).expand(1, 1, 16, 16).clone()
    g = torch.Generator().manual_seed(1)
    weight = (torch.rand(1, 1, 16, 16, generator=g) < 0.1).float() + 1e-3
    noisy = values + (weight < 1) * torch.randn(values.shape, generator=g)  # noise where unsure
    out = edge_aware_smooth(noisy, weight, guide, strength=10.0, sigma=0.1)
    assert torch.allclose(out, values, atol=0.05)


def test_smoothing_leaves_a_constant_and_zero_strength_alone():
    g = torch.Generator().manual_seed(2)
    guide, weight = torch.rand(2, 3, 8, 8, generator=g), torch.rand(2, 1, 8, 8, generator=g)
    constant = torch.full((2, 1, 8, 8), 0.25)
    torch.testing.assert_close(edge_aware_smooth(constant, weight, guide), constant)
    values = torch.rand(2, 1, 8, 8, generator=g)
    assert edge_aware_smooth(values, weight, guide, strength=0.0) is values


def test_smoothing_gradcheck():
    g = torch.Generator().manual_seed(3)
    values = torch.rand(1, 1, 4, 5, generator=g, dtype=torch.float64, requires_grad=True)
    weight = (torch.rand(1, 1, 4, 5, generator=g, dtype=torch.float64) + 0.1).requires_grad_()
    guide = (torch.rand(1, 2, 4, 5, generator=g, dtype=torch.float64) + 0.1).requires_grad_()
    assert torch.autograd.gradcheck(
        lambda v, w, gd: edge_aware_smooth(v, w, gd, strength=2.0, sigma=0.5, tolerance=1e-13),
        (values, weight, guide))


def test_guide_affinities_are_one_on_flat_and_small_across_edges():
    guide = torch.zeros(1, 3, 4, 4)
    guide[..., 2:, :] = 0.5
    vertical, horizontal = guide_affinities(guide, 0.1)
    assert vertical.shape == (1, 1, 3, 4) and horizontal.shape == (1, 1, 4, 3)
    assert torch.equal(horizontal, torch.ones_like(horizontal))
    assert float(vertical[0, 0, 1].max()) < 1e-6 and float(vertical[0, 0, 0].min()) == 1.0


def test_smoothing_refuses_bad_arguments():
    values, weight, guide = torch.rand(1, 1, 6, 6), torch.rand(1, 1, 6, 6), torch.rand(1, 3, 6, 6)
    with pytest.raises(ValueError, match="values"):
        edge_aware_smooth(values[0], weight, guide)
    with pytest.raises(ValueError, match="share batch and size"):
        edge_aware_smooth(values, weight, guide[..., :5])
    with pytest.raises(ValueError, match="strength"):
        edge_aware_smooth(values, weight, guide, strength=-1.0)
    with pytest.raises(ValueError, match="sigma"):
        edge_aware_smooth(values, weight, guide, sigma=0.0)
    with pytest.raises(ValueError, match="weight must be >= 0"):
        edge_aware_smooth(values, -weight, guide)
    with pytest.raises(ValueError, match="positive somewhere"):
        edge_aware_smooth(values, torch.zeros_like(weight), guide)


def test_smoothing_warm_start_keeps_the_minimiser(monkeypatch):
    """A map large enough for the half-size warm start gives the minimiser of a cold start."""
    import models.depth_from_photos.smoothing as smoothing

    g = torch.Generator().manual_seed(1)
    values = torch.rand(1, 1, 70, 90, generator=g, dtype=torch.float64)
    weight = torch.rand(1, 1, 70, 90, generator=g, dtype=torch.float64) ** 4 + 0.01
    guide = torch.rand(1, 3, 70, 90, generator=g, dtype=torch.float64)
    guide[..., 40:] += 0.5
    starts = []
    coarse_start = smoothing._coarse_start
    monkeypatch.setattr(smoothing, "_coarse_start",
                        lambda *args: starts.append(args[0].shape) or coarse_start(*args))
    warm = edge_aware_smooth(values, weight, guide, strength=10.0, tolerance=1e-10)
    assert starts and starts[0][-2:] == (70, 90)
    monkeypatch.setattr(smoothing, "COARSE_MIN_PX", 10**9)
    cold = edge_aware_smooth(values, weight, guide, strength=10.0, tolerance=1e-10)
    torch.testing.assert_close(warm, cold, atol=1e-8, rtol=0)
