"""Semi-global aggregation of a cost volume (models.depth_from_photos.semi_global)."""

import itertools

import pytest
import torch

from models.depth_from_photos import aggregate_cost
from models.depth_from_photos.semi_global import cost_scale, semi_global_cost, semi_global_paths


def _chain_minima(cost, p1, p2):
    """Brute force over every labelling of a 1-D chain `(K, N)`: for each pixel and label, the
    cheapest sum of costs and change penalties over labellings of the pixels up to it that end
    there (`forward`), and of those from it to the end (`backward`)."""
    k, n = cost.shape
    forward = torch.full((k, n), float("inf"), dtype=cost.dtype)
    backward = torch.full((k, n), float("inf"), dtype=cost.dtype)

    def penalty(a, b):
        return 0.0 if a == b else (p1 if abs(a - b) == 1 else p2)

    for labels in itertools.product(range(k), repeat=n):
        steps = [penalty(a, b) for a, b in zip(labels[:-1], labels[1:], strict=True)]
        for i in range(n):
            head = sum(float(cost[labels[j], j]) for j in range(i + 1)) + sum(steps[:i])
            tail = sum(float(cost[labels[j], j]) for j in range(i, n)) + sum(steps[i:])
            forward[labels[i], i] = min(forward[labels[i], i], head)
            backward[labels[i], i] = min(backward[labels[i], i], tail)
    return forward, backward


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_paths_match_brute_force_on_a_chain(dtype):
    """On one row the two horizontal scans are exact minima over all labellings (up to a shift
    per pixel, the subtracted minima), and the vertical scans are the pixel's own cost."""
    g = torch.Generator().manual_seed(0)
    cost = torch.rand(1, 3, 1, 5, generator=g, dtype=dtype)
    p1, p2 = 0.15, 0.6
    jumps = torch.full((1, 4, 1, 5), p2, dtype=dtype)
    total = semi_global_paths(cost, p1, jumps)[0, :, 0]
    forward, backward = _chain_minima(cost[0, :, 0], p1, p2)
    expected = forward + backward + 2 * cost[0, :, 0]  # + the two one-pixel vertical scans
    shift = lambda t: t - t.amin(0, keepdim=True)  # noqa: E731
    torch.testing.assert_close(shift(total), shift(expected))


def test_no_penalty_leaves_each_pixel_its_own_cost():
    cost = torch.rand(2, 5, 6, 7, dtype=torch.float64)
    total = semi_global_paths(cost, 0.0, torch.zeros(2, 4, 6, 7, dtype=torch.float64))
    torch.testing.assert_close(total, 4 * cost)


def test_jump_penalty_is_read_where_the_jump_enters():
    """Nine pixels prefer candidate 0, the last three candidate 3 (by 1 each): a jump penalty of
    10 overrules them, unless it is lowered where each horizontal scan enters the edge (column 9
    from the left, column 8 from the right); lowering the vertical scans' penalties does not
    help."""
    cost = torch.zeros(1, 4, 1, 12, dtype=torch.float64)
    cost[0, 1:, 0, :9] = 1.0
    cost[0, :3, 0, 9:] = 1.0
    jumps = torch.full((1, 4, 1, 12), 10.0, dtype=torch.float64)
    assert semi_global_paths(cost, 5.0, jumps).argmin(1).unique().tolist() == [0]
    at_edge, vertical = jumps.clone(), jumps.clone()
    at_edge[0, 0, 0, 9] = at_edge[0, 1, 0, 8] = 0.0
    vertical[0, 2:] = 0.0  # the vertical scans never cross the edge
    assert semi_global_paths(cost, 5.0, at_edge).argmin(1)[0, 0].tolist() == [0] * 9 + [3] * 3
    assert semi_global_paths(cost, 5.0, vertical).argmin(1).unique().tolist() == [0]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_cost_is_free_of_the_costs_units(dtype):
    """Adding a constant and scaling the costs changes nothing: penalties are relative."""
    g = torch.Generator().manual_seed(1)
    cost = torch.rand(1, 8, 10, 12, generator=g, dtype=dtype)
    image = torch.rand(1, 3, 10, 12, generator=g, dtype=dtype)
    torch.testing.assert_close(semi_global_cost(7 * cost + 3, image),
                               semi_global_cost(cost, image))


def test_noisy_costs_keep_a_thin_stripe_that_windows_lose():
    """A 3-pixel stripe at another depth, its costs buried in noise: per pixel, 15 % of the picks
    are off by more than a candidate; aggregated along scan lines the stripe survives (its
    edges are in the photo), while sums over square windows give it to the background."""
    g = torch.Generator().manual_seed(0)
    truth = torch.zeros(1, 1, 32, 32, dtype=torch.long)
    truth[..., 14:17] = 9
    wrong = (torch.arange(12).view(1, 12, 1, 1) - truth).abs().clamp(max=3).double() / 3
    cost = wrong + 1.5 * torch.rand(1, 12, 32, 32, generator=g, dtype=torch.float64)
    image = torch.where(truth > 0, 0.7, 0.2).double().expand(1, 3, 32, 32)

    def off(picked):
        return ((picked.argmin(1, keepdim=True) - truth).abs() > 1).double()

    assert float(off(cost).mean()) > 0.1
    picked = off(semi_global_cost(cost, image))
    assert float(picked.mean()) < 0.05
    assert float(picked[..., 14:17].mean()) < 0.1
    assert float(off(aggregate_cost(cost))[..., 14:17].mean()) > 0.5


def test_cost_scale_reads_every_fourth_candidate():
    cost = torch.zeros(1, 9, 2, 2)
    cost[:, 1::2] = 100.0  # only unread candidates are expensive
    assert float(cost_scale(cost)) == 0.0
    cost[:, 4] = 3.0  # read: candidates 0, 4, 8 -> mean 1, lowest 0
    assert float(cost_scale(cost)) == pytest.approx(1.0)
    assert float(cost_scale(cost[:, ::4], stride=1)) == pytest.approx(1.0)


@pytest.mark.parametrize("kwargs, match", [
    (dict(smooth_penalty=-1.0), "smooth_penalty"),
    (dict(jump_penalty=float("nan")), "jump_penalty"),
    (dict(edge_contrast=0.0), "edge_contrast"),
    (dict(scale=torch.ones(3)), "scale"),
])
def test_bad_arguments_are_refused(kwargs, match):
    cost, image = torch.rand(1, 4, 5, 6), torch.rand(1, 3, 5, 6)
    with pytest.raises(ValueError, match=match):
        semi_global_cost(cost, image, **kwargs)


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="image"):
        semi_global_cost(torch.rand(1, 4, 5, 6), torch.rand(1, 3, 5, 7))
    with pytest.raises(ValueError, match="cost"):
        semi_global_cost(torch.rand(4, 5, 6), torch.rand(1, 3, 5, 6))
    with pytest.raises(ValueError, match="jump_penalty"):
        semi_global_paths(torch.rand(1, 4, 5, 6), 0.1, torch.rand(1, 2, 5, 6))
