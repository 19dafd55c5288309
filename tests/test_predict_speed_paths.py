"""The fast paths of `estimate_depth` on big photos: a working resolution for a 12-megapixel set
(without running the sweep on it), the cost volume computed once for the whole photo, the
window means taken in chunks, and the semi-global scans over a transposed copy. Each is
checked against an independent, plain computation. The 12-megapixel timings and memory live
in `benchmarks/predict.py`."""

from __future__ import annotations

import kornia
import numpy as np
import pytest
import torch

from datasets.capture import CaptureNoise, capture
from datasets.synthetic import generate_scene
from models.depth_from_photos import SweepDepth, cost_volume, estimate_depth
from models.depth_from_photos.relative_blur import RelativeBlurDepth, pair_errors
from models.depth_from_photos.semi_global import semi_global_paths
from models.depth_from_photos.sweep import blur_errors
from models.depth_from_photos.thin_lens import WINDOW_CHUNK, box_filter, median_filter
from optics import CameraSettings, Disk


class _Recording(torch.nn.Module):
    """A method that records the photos it is given and returns a constant depth."""

    max_coc_px, needs_image = 20.0, True

    def __init__(self):
        super().__init__()
        self.seen = []

    def forward(self, image, focused, settings, near, far):
        self.seen.append((tuple(focused.shape), float(settings.pixel_pitch.reshape(-1)[0])))
        b, n, _, h, w = focused.shape
        return {"depth": torch.full((b, 1, h, w), 3.0), "confidence": torch.ones(b, 1, h, w),
                "blur": torch.zeros(b, n, h, w)}


def test_a_12_megapixel_set_is_swept_at_1_5_megapixels():
    """The benchmark's camera (18 mm f/8, 1.5 um) on 3000x4000 photos: the method sees them at
    sqrt(1.5 / 12) of their side with the pixel pitch grown alike, and the depth comes back at
    full size. The photos are constant views (no 12-megapixel memory)."""
    focused = torch.full((1, 1, 1, 1), 0.5).expand(2, 3, 3000, 4000)
    image = torch.full((1, 1, 1), 0.4).expand(3, 3000, 4000)
    settings = CameraSettings(0.018, 8.0, [1.5, 4.0], 1.5e-6, "disk")
    method = _Recording()
    out = estimate_depth(focused, settings, (0.8, 10.0), image=image, model=method, align=False,
                         refine_range=False, all_in_focus=False)
    (shape, pitch), = method.seen
    assert shape == (1, 2, 3, 1061, 1414)  # 1.5 megapixels, the aspect kept
    assert pitch == pytest.approx(1.5e-6 * 4000 / 1414, rel=1e-6)
    assert out["depth"].shape == (1, 3000, 4000) and out["scale"] == 1414 / 4000


def _scene(seed=0, size=(64, 160)):
    rng = np.random.default_rng(seed)
    image, depth = generate_scene(size, rng, (1.5, 6.0))
    settings = CameraSettings(0.05, 2.0, [2.0, 5.0], 1.2e-4, "disk")
    aif, focused = capture(image, depth, settings, rng, CaptureNoise())
    return aif[None], focused[None], settings


def test_the_whole_photos_volume_gives_the_depth_of_volumes_per_tile(monkeypatch):
    """The cost volume computed once for the whole photo, aggregated tile by tile, gives the
    depth of the per-tile volumes (each tile's costs computed on its crop with context) within
    1 % at 95 % of the pixels or more (99.6 % for the sweep, 97 % for the relative blur on this
    scene: the scan lines start at the crop's border, where a crop's own
    costs are those of a mirrored photo; with window sums both are exact: `tests/test_sweep.py`
    compares tiles with the whole photo)."""
    aif, focused, settings = _scene()
    aif, focused = aif.double(), focused.double()
    monkeypatch.setattr(cost_volume, "SEMI_GLOBAL_CONTEXT_PX", 8)  # small enough to tile
    methods = (SweepDepth(n_candidates=12, tile=32), RelativeBlurDepth(n_candidates=12, tile=32))
    for method, guide in zip(methods, (aif, None), strict=True):
        whole = method(guide, focused, settings, 1.0, 10.0)["depth"]
        with monkeypatch.context() as patch:
            patch.setattr(cost_volume, "MAX_VOLUME_BYTES", 0)  # every tile its own volume
            tiled = method(guide, focused, settings, 1.0, 10.0)["depth"]
        close = ((whole - tiled).abs() <= 0.01 * whole).double().mean()
        assert float(close) >= 0.95, (type(method).__name__, float(close))


def test_blur_errors_in_chunks_are_each_candidates_own():
    """More candidates than `WINDOW_CHUNK`: each candidate's errors are those it has alone, and
    `out=` adds them to what it holds."""
    g = torch.Generator().manual_seed(0)
    image, focused = torch.rand(1, 3, 40, 50, generator=g), torch.rand(1, 3, 40, 50, generator=g)
    blurs = torch.linspace(0.0, 6.0, WINDOW_CHUNK + 5, dtype=torch.float64)
    image, focused = image.double(), focused.double()
    noise = torch.tensor([[1e-4, 1e-3]], dtype=torch.float64)
    together = blur_errors(image, focused, Disk(), blurs, noise)
    alone = torch.cat([blur_errors(image, focused, Disk(), blurs[i:i + 1], noise)
                       for i in range(len(blurs))], 1)
    torch.testing.assert_close(together, alone, rtol=1e-12, atol=1e-15)
    start = torch.rand(together.shape, generator=g, dtype=torch.float64)
    added = blur_errors(image, focused, Disk(), blurs, noise, out=start.clone())
    torch.testing.assert_close(added, start + together, rtol=1e-12, atol=1e-15)
    first, second = torch.linspace(0, 5, 21, dtype=torch.float64), torch.full((21,), 2.0,
                                                                              dtype=torch.float64)
    together = pair_errors(image, focused, Disk(), first, second, noise)
    alone = torch.cat([pair_errors(image, focused, Disk(), first[i:i + 1], second[i:i + 1],
                                   noise) for i in range(21)], 1)
    torch.testing.assert_close(together, alone, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("shape,size", [((1, 16, 40, 50), 5), ((2, 1, 31, 23), 9),
                                        ((1, 3, 12, 9), 49), ((1, 2, 40, 50), 17)])
def test_scipy_filters_are_kornias(dtype, shape, size):
    """On a CPU without gradients the window means and medians are scipy's, in bands of rows
    over threads: kornia's values (the medians bit for bit), on many planes, one plane in bands
    and windows larger than the photo; with gradients they are kornia's own."""
    x = torch.rand(shape, generator=torch.Generator().manual_seed(size), dtype=dtype)
    tol = 1e-6 if dtype == torch.float32 else 1e-13
    expected = kornia.filters.box_blur(x, (size, size), border_type="replicate")
    torch.testing.assert_close(box_filter(x, size), expected, rtol=0, atol=tol)
    if size <= min(shape[-2:]):  # kornia's median mirrors, which needs the window inside
        assert torch.equal(median_filter(x, size), kornia.filters.median_blur(x, size))
    graded = x.clone().requires_grad_()
    assert box_filter(graded, size).grad_fn is not None
    torch.testing.assert_close(box_filter(graded, size).detach(), expected, rtol=0, atol=tol)


def _plain_paths(cost, smooth, jumps):
    """Semi-global path costs, pixel line by pixel line in plain loops (the recurrence of
    `semi_global`'s module docstring)."""
    b, k, h, w = cost.shape
    total = torch.zeros_like(cost)
    for direction, (dy, dx) in enumerate(((0, 1), (0, -1), (1, 0), (-1, 0))):
        paths = torch.zeros_like(cost)
        ys = range(h) if dy >= 0 else range(h - 1, -1, -1)
        xs = range(w) if dx >= 0 else range(w - 1, -1, -1)
        for y in ys:
            for x in xs:
                py, px = y - dy, x - dx
                if not (0 <= py < h and 0 <= px < w):
                    paths[:, :, y, x] = cost[:, :, y, x]
                    continue
                prev = paths[:, :, py, px]  # (B,K)
                floor = prev.amin(1, keepdim=True)
                options = [prev, (floor + jumps[:, direction, y, x, None]).expand_as(prev)]
                options.append(torch.cat([prev[:, :1] * 0 + float("inf"), prev[:, :-1] + smooth], 1))
                options.append(torch.cat([prev[:, 1:] + smooth, prev[:, :1] * 0 + float("inf")], 1))
                best = torch.stack(options).amin(0)
                paths[:, :, y, x] = cost[:, :, y, x] + best - floor
        total += paths
    return total


def test_semi_global_paths_match_the_plain_recurrence():
    g = torch.Generator().manual_seed(1)
    cost = torch.rand(2, 5, 7, 9, generator=g, dtype=torch.float64)
    jumps = 0.1 + torch.rand(2, 4, 7, 9, generator=g, dtype=torch.float64)
    torch.testing.assert_close(semi_global_paths(cost, 0.1, jumps), _plain_paths(cost, 0.1, jumps))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_semi_global_cost_in_a_reused_workspace_is_the_same(dtype):
    """Tiles of two sizes aggregated one after the other in one workspace give what fresh
    memory gives; a workspace too small, or of another dtype, is refused."""
    from models.depth_from_photos.semi_global import semi_global_cost

    g = torch.Generator().manual_seed(5)
    workspace = torch.empty(3 * 7 * 12 * 15, dtype=dtype)
    for h, w in ((12, 15), (9, 11)):
        cost = torch.rand(1, 7, h, w, generator=g, dtype=dtype)
        image = torch.rand(1, 3, h, w, generator=g, dtype=dtype)
        torch.testing.assert_close(semi_global_cost(cost, image, workspace=workspace),
                                   semi_global_cost(cost, image), rtol=0, atol=0)
    with pytest.raises(ValueError, match="workspace must be"):
        semi_global_cost(torch.rand(1, 7, 13, 15, dtype=dtype), torch.rand(1, 3, 13, 15,
                         dtype=dtype), workspace=workspace)
