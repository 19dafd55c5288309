"""Depth from defocus by a sweep over depth (models.depth_from_photos.sweep): no network."""

import math

import numpy as np
import pytest
import torch
from skimage import data

from datasets.capture import CaptureNoise, capture, random_camera
from datasets.synthetic import generate_scene
from models.depth_from_photos import (
    cost_volume,
    estimate_depth,
    scene_range,
    sweep,
    widen_cut_range,
)
from models.depth_from_photos.resolution import run_at_working_resolution as predict_depth
from models.depth_from_photos.semi_global import cost_scale, semi_global_cost
from models.depth_from_photos.sweep import SweepDepth, blur_errors, noise_model, sweep_cost
from models.metrics import best_constant_depth, confident_half_error, depth_metrics
from optics import CameraSettings, Disk, render_defocus, translate, warp


def _texture(size=(96, 128), dtype=torch.float32):
    h, w = size
    grey = torch.from_numpy(data.camera()[80:80 + h, 150:150 + w]).to(dtype) / 255
    rgb = torch.stack([grey, grey.flip(0), grey.flip(1)])
    return (0.05 + 0.9 * rgb).contiguous()


def test_noise_model_measures_shot_and_read_noise():
    """Texture mistaken for noise inflates the estimate; pooling a defocused photo of the same
    sensor (as `sweep_cost` does) removes most of it."""
    image = _texture((128, 128), torch.float64)[None]
    defocused = render_defocus(image, torch.full((1, 1, 128, 128), 6.0, dtype=torch.float64),
                               Disk())
    g = torch.Generator().manual_seed(0)
    a, b = 1e-4, 1e-3

    def noisy(x):
        return x + torch.randn(x.shape, generator=g, dtype=torch.float64) * (a + b * x).sqrt()

    alone = noise_model(noisy(image))[0].tolist()
    pooled = noise_model(torch.cat([noisy(image), noisy(defocused)], 1))[0].tolist()
    for level in (0.2, 0.8):  # the variance each predicts
        truth = a + b * level
        assert alone[0] + alone[1] * level == pytest.approx(truth, rel=0.5)
        assert pooled[0] + pooled[1] * level == pytest.approx(truth, rel=0.2)
    clean = noise_model(torch.cat([image, defocused], 1))[0].tolist()
    assert clean[0] + clean[1] * 0.5 < 0.1 * (a + b * 0.5)


def test_noise_model_of_a_large_stack():
    """Six photos of 1000x1000 (18 channels, more values than torch.quantile takes at once), as
    five focused photos at a 1-megapixel working resolution give."""
    g = torch.Generator().manual_seed(3)
    flat = torch.linspace(0.1, 0.9, 1000).expand(1, 18, 1000, 1000)
    noisy = flat + torch.randn(1, 18, 1000, 1000, generator=g) * (1e-4 + 1e-3 * flat).sqrt()
    a, b = noise_model(noisy)[0].tolist()
    assert b == pytest.approx(1e-3, rel=0.2) and a < 5e-4


def test_noise_model_of_tiny_images_is_zero():
    assert torch.equal(noise_model(torch.rand(2, 3, 8, 8)), torch.zeros(2, 2))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_blur_errors_are_least_at_the_true_blur_despite_noise(dtype):
    image = _texture(dtype=dtype)[None]
    focused = render_defocus(image, torch.full((1, 1, 96, 128), 3.0, dtype=dtype), Disk())
    g = torch.Generator().manual_seed(1)
    image = image + 0.02 * torch.randn(image.shape, generator=g, dtype=dtype)
    focused = focused + 0.02 * torch.randn(focused.shape, generator=g, dtype=dtype)
    grid = torch.arange(0, 7.5, 0.5, dtype=dtype)
    errors = blur_errors(image, focused, Disk(), grid)[0, :, 10:-10, 10:-10].mean((-2, -1))
    assert float(grid[errors.argmin()]) == pytest.approx(3.0, abs=0.5)
    assert errors.dtype == dtype


def _photographed_planes(depths, seed=0, focus=(2.0, 6.0), noise=None, lens=(0.05, 2.0)):
    """A textured scene at one or two depths (left, right halves), photographed with `noise`'s
    imperfections (noise and misalignment by default) by a camera of `lens` (focal length m,
    f-number; 50 mm f/2 by default) focused at `focus` metres."""
    image = _texture()
    depth = torch.full((1, 96, 128), float(depths[0]))
    depth[..., 64:] = float(depths[-1])
    settings = CameraSettings(*lens, list(focus), 1.2e-4, aperture="disk")
    aif, focused = capture(image, depth, settings, np.random.default_rng(seed),
                           noise or CaptureNoise())
    return aif, focused, settings, depth


def test_sweep_finds_a_plane_at_its_depth():
    aif, focused, settings, _ = _photographed_planes([3.0])
    out = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 10.0)
    inner = out["depth"][0, 16:-16, 16:-16]
    assert float(inner.median()) == pytest.approx(3.0, rel=0.03)


def test_sweep_separates_two_planes():
    aif, focused, settings, _ = _photographed_planes([2.5, 4.5], seed=1, focus=(1.5, 8.0))
    depth = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 10.0)["depth"][0]
    assert float(depth[16:-16, 8:48].median()) == pytest.approx(2.5, rel=0.05)
    assert float(depth[16:-16, 80:-8].median()) == pytest.approx(4.5, rel=0.05)


@pytest.mark.parametrize("align", [True, False], ids=["aligned", "unaligned"])
def test_predict_runs_on_the_photos_device(device, align):
    """The photos' device is the computation's: on CUDA the depth of two planes matches the
    CPU's (every tensor the sweep, the noise model, the alignment and the smoothing make
    follows the photos)."""
    aif, focused, settings, _ = _photographed_planes([2.5, 4.5], seed=1, focus=(1.5, 8.0))
    here = predict_depth(SweepDepth(), aif.to(device), focused.to(device), settings, 1.0, 10.0,
                         align=align)
    cpu = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 10.0, align=align)
    assert here["depth"].device.type == device.type
    assert here["confidence"].device.type == device.type
    assert here["depth_range"] == pytest.approx(cpu["depth_range"], rel=1e-3)
    relative = (here["depth"].cpu() - cpu["depth"]).abs() / cpu["depth"]
    assert float(relative.median()) < 1e-3 and float(relative.mean()) < 0.01


def test_alignment_removes_the_bias_of_misaligned_shots():
    """Misaligned by about a pixel, unaligned shots read as extra blur: for shots focused in
    front of the plane, the depth comes out too far."""
    aif, focused, settings, _ = _photographed_planes([3.0], seed=2)
    raw = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 10.0, align=False)
    aligned = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 10.0)
    error = [abs(float(out["depth"][0, 16:-16, 16:-16].median()) / 3.0 - 1)
             for out in (raw, aligned)]
    assert error[1] < 0.03 and error[1] < error[0]


def test_sweep_beats_a_constant_on_held_out_procedural_scenes():
    """Six procedural scenes, random cameras (18-200 mm, f/1.2-f/8, 2-3 shots), noise and
    misalignment; no setting of the sweep was chosen on them. The semi-global aggregation beats
    the window sums on each (0.33 against 0.34 median when measured)."""
    ratios = {"semi-global": [], "windows": []}
    for i in range(6):
        rng = np.random.default_rng([77, i])
        near = float(np.exp(rng.uniform(np.log(0.5), np.log(4))))
        far = near * float(np.exp(rng.uniform(np.log(2), np.log(6))))
        image, depth = generate_scene((128, 192), rng, (near, far))
        settings = random_camera(rng, near, far, int(rng.integers(2, 4)), (3.0, 20.0))
        aif, focused = capture(image, depth, settings, rng, CaptureNoise())
        constant = best_constant_depth(target=depth[None])
        base = depth_metrics(pred=torch.full_like(depth[None], constant), target=depth[None])
        for aggregation, scores in ratios.items():
            out = predict_depth(SweepDepth(aggregation=aggregation), aif, focused,
                                settings.to(torch.float32), near * 0.8, far * 1.25)
            ours = depth_metrics(pred=out["depth"][None], target=depth[None])
            scores.append(ours["abs_rel"] / base["abs_rel"])
    assert float(np.median(ratios["semi-global"])) < 0.4, ratios
    assert all(a < b for a, b in zip(ratios["semi-global"], ratios["windows"], strict=True)), ratios


@pytest.mark.parametrize("shape", [(8, 8), (9, 11), (40, 7)])
def test_sweep_handles_photos_smaller_than_the_blur(shape):
    """Kernels wider than the photo: the border is repeated beyond what the photo can mirror."""
    settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
    g = torch.Generator().manual_seed(0)
    image, focused = torch.rand(3, *shape, generator=g), torch.rand(2, 3, *shape, generator=g)
    out = predict_depth(SweepDepth(), image, focused, settings, 1.0, 10.0)
    assert out["depth"].shape == (1, *shape) and torch.isfinite(out["depth"]).all()


def test_sweep_output_is_finite_on_flat_photos():
    settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
    flat = torch.full((1, 3, 32, 32), 0.5)
    out = SweepDepth()(flat, flat[:, None].expand(1, 2, 3, 32, 32), settings, 1.0, 10.0)
    assert torch.isfinite(out["depth"]).all() and float(out["confidence"].max()) < 0.1


def test_predict_refuses_photos_with_nan():
    settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
    image, focused = torch.rand(3, 32, 32), torch.rand(2, 3, 32, 32)
    focused[1, 0, 5, 7] = float("nan")
    with pytest.raises(ValueError, match=r"focused has 1 NaN .* at index \(1, 0, 5, 7\)"):
        estimate_depth(focused, settings, (1.0, 10.0), image=image)
    image = image[None]
    image[0, 1, 2, 3] = float("inf")
    with pytest.raises(ValueError, match="image has 0 NaN and 1 infinite"):
        SweepDepth()(image, focused[None].nan_to_num(), settings, 1.0, 10.0)


@pytest.mark.parametrize(("near", "far", "match"), [
    (0.0, 10.0, "0 < near < far"), (5.0, 1.0, "0 < near < far"),
    (float("nan"), 3.0, "finite metres"), (1.0, float("inf"), "finite metres")])
def test_predict_refuses_a_bad_depth_range(near, far, match):
    settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
    with pytest.raises(ValueError, match=match):
        estimate_depth(torch.rand(2, 3, 16, 16), settings, (near, far), image=torch.rand(3, 16, 16))


@pytest.mark.parametrize(("option", "value"), [
    ("max_coc_px", 0.0), ("max_coc_px", float("nan")), ("max_pixels", 0)])
def test_predict_refuses_a_bad_working_resolution(option, value):
    settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
    with pytest.raises(ValueError, match=f"{option}={value!r}"):
        estimate_depth(torch.rand(2, 3, 16, 16), settings, (1.0, 10.0),
                       image=torch.rand(3, 16, 16), **{option: value})


def test_sweep_refuses_bad_arguments():
    with pytest.raises(ValueError, match="n_candidates"):
        SweepDepth(n_candidates=2)
    with pytest.raises(ValueError, match="smoothing"):
        SweepDepth(smoothing=-1.0)
    settings = CameraSettings(0.05, 2.0, [2.0, 6.0, 9.0], 1e-4)
    image = torch.rand(1, 3, 16, 16)
    with pytest.raises(ValueError, match="settings 3"):
        SweepDepth()(image, image[:, None].expand(1, 2, 3, 16, 16), settings, 1.0, 10.0)
    with pytest.raises(ValueError, match="near"):
        SweepDepth()(image, image[:, None].expand(1, 3, 3, 16, 16), settings, 5.0, 1.0)


def test_tiles_give_the_untiled_depth():
    """Window sums reach a known distance: tiles with that much context are exact."""
    aif, focused, settings, _ = _photographed_planes([2.5, 4.5], seed=3, focus=(1.5, 8.0))
    aif, focused = aif.double()[None], focused.double()[None]
    whole = SweepDepth(aggregation="windows")(aif, focused, settings, 1.0, 10.0)["depth"]
    tiled = SweepDepth(tile=24, aggregation="windows")(aif, focused, settings, 1.0, 10.0)["depth"]
    torch.testing.assert_close(tiled, whole, rtol=1e-6, atol=0)


def test_semi_global_tiles_share_the_whole_photos_cost_scale(monkeypatch):
    """Every tile's penalties are relative to the whole photo's cost scale (`cost_scale` of the
    untiled cost volume), not to its own."""
    aif, focused, settings, _ = _photographed_planes([2.5, 4.5], seed=3, focus=(1.5, 8.0))
    aif, focused = aif.double()[None], focused.double()[None]
    received, volumes = [], []

    def recording(cost, image, *penalties, scale=None, **options):
        received.append(scale)
        volumes.append(cost)
        return semi_global_cost(cost, image, *penalties, scale=scale, **options)

    monkeypatch.setattr(cost_volume, "semi_global_cost", recording)
    SweepDepth()(aif, focused, settings, 1.0, 10.0)
    assert received == [None]  # one tile: its own volume is the photo's
    whole = cost_scale(volumes[0])
    monkeypatch.setattr(cost_volume, "SEMI_GLOBAL_CONTEXT_PX", 0)  # small enough to tile 96x128
    received.clear()
    SweepDepth(tile=24)(aif, focused, settings, 1.0, 10.0)
    assert len(received) == 4 * 6
    for scale in received:
        torch.testing.assert_close(scale, whole, rtol=1e-6, atol=0)


def test_sweep_cost_every_few_candidates_is_a_subset():
    aif, focused, settings, _ = _photographed_planes([3.0], seed=2)
    aif, focused = aif[None], focused[None]
    full = sweep_cost(aif, focused, settings, 1.0, 10.0, n_candidates=10)
    torch.testing.assert_close(sweep_cost(aif, focused, settings, 1.0, 10.0, n_candidates=10,
                                          every=4), full[:, ::4], rtol=1e-4, atol=1e-7)
    with pytest.raises(ValueError, match="every"):
        sweep_cost(aif, focused, settings, 1.0, 10.0, every=0)


def test_sweep_refuses_an_unknown_aggregation():
    with pytest.raises(ValueError, match="aggregation"):
        SweepDepth(aggregation="boxes")


def test_blur_errors_gradcheck():
    """Differentiable in both photos (the noise coefficients given: measuring them is not)."""
    g = torch.Generator().manual_seed(0)
    image = torch.rand(1, 3, 12, 12, generator=g, dtype=torch.float64, requires_grad=True)
    focused = torch.rand(1, 3, 12, 12, generator=g, dtype=torch.float64, requires_grad=True)
    noise = torch.tensor([[1e-4, 1e-3]], dtype=torch.float64)
    blurs = torch.tensor([0.0, 2.5], dtype=torch.float64)
    assert torch.autograd.gradcheck(
        lambda a, b: blur_errors(a, b, Disk(), blurs, noise), (image, focused))


def test_predict_reports_how_far_each_shot_moved():
    aif, focused, settings, _ = _photographed_planes([3.0], seed=4, noise=CaptureNoise.none())
    moved = torch.tensor([[0.7, -1.3], [-0.4, 0.9]])
    focused = torch.cat([translate(f[None], m[None]) for f, m in zip(focused, moved, strict=True)])
    out = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 10.0)
    assert torch.allclose(out["shifts"], moved, atol=0.1), out["shifts"]
    assert float(out["depth"][0, 16:-16, 16:-16].median()) == pytest.approx(3.0, rel=0.03)


def test_sweep_sees_through_focus_breathing():
    """The lens magnifies each focused photo a little (1.5 % and -1 %): aligned with a zoom, the
    plane comes out at its depth; moved only, it does not."""
    aif, focused, settings, _ = _photographed_planes([3.0], seed=5,
                                                     noise=CaptureNoise(shift_px=0.0))
    zooms = torch.tensor([1.015, 0.99])
    focused = torch.cat([warp(f[None], torch.zeros(1, 2), z[None])
                         for f, z in zip(focused, zooms, strict=True)])
    out = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 10.0)
    assert torch.allclose(out["zooms"], zooms, atol=2e-3), out["zooms"]
    raw = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 10.0, align=False)
    inner = (0, slice(8, -8), slice(8, -8))
    error = [float(((o["depth"][inner] - 3.0).abs() / 3.0).mean()) for o in (out, raw)]
    assert error[0] < 0.03 and error[1] > 2 * error[0], error


def test_scene_range_is_the_depth_maps_own_with_a_margin():
    depth = torch.tensor([2.0, 2.5, 4.0, 5.0]).reshape(1, 1, 2, 2)
    # the extremes, widened by at least 2 % of the stated range's inverse-depth span
    pad = 0.02 * (1 / 1.0 - 1 / 15.0)
    assert scene_range(depth, 1.0, 15.0, tail=0.0, margin=0.0) == pytest.approx(
        (1 / (0.5 + pad), 1 / (0.2 - pad)))
    # 15 % of the inverse-depth span on each side, and never beyond the stated range
    span = 1 / 2.0 - 1 / 5.0
    assert scene_range(depth, 1.0, 15.0, tail=0.0) == pytest.approx(
        (1 / (0.5 + 0.15 * span), 1 / (0.2 - 0.15 * span)))
    assert scene_range(depth, 2.2, 4.5, tail=0.0) == pytest.approx((2.2, 4.5))
    # one depth: still a range
    assert scene_range(torch.full((1, 1, 4, 4), 3.0), 1.0, 15.0) == pytest.approx(
        (1 / (1 / 3.0 + pad), 1 / (1 / 3.0 - pad)))


def test_widen_cut_range_moves_a_cut_side_by_the_kept_span():
    """A side is widened by the kept range's inverse-depth span (closed form) where more than
    the share of pixels sit at its limit, never beyond the stated range, and only where the
    first pass set that limit."""
    kept, stated = (2.5, 5.0), (1.0, 15.0)
    span = 1 / 2.5 - 1 / 5.0
    piled_near = torch.cat([torch.full((30,), 2.5), torch.linspace(2.6, 4.5, 70)])
    assert widen_cut_range(piled_near, kept, stated) == pytest.approx((1 / (0.4 + span), 5.0))
    piled_far = torch.cat([torch.full((30,), 4.0), torch.linspace(2.6, 3.9, 70)])
    assert widen_cut_range(piled_far, (2.5, 4.0), stated) == pytest.approx(
        (2.5, 1 / (0.25 - (0.4 - 0.25))))
    # a span that would reach beyond infinity stops at the stated far limit
    assert widen_cut_range(piled_far.clamp(max=5.0) + 1.0, kept, stated) == pytest.approx(
        (2.5, 15.0))
    # within the share: left alone
    few = torch.cat([torch.full((1,), 2.5), torch.linspace(2.6, 4.5, 99)])
    assert widen_cut_range(few, kept, stated) == kept
    # a stated limit is never widened, and a widened side stops at the stated one
    assert widen_cut_range(piled_near, kept, (2.5, 15.0)) == kept
    assert widen_cut_range(piled_near, kept, (2.0, 15.0)) == pytest.approx((2.0, 5.0))
    with pytest.raises(ValueError, match="share must be in"):
        widen_cut_range(piled_near, kept, stated, share=0.0)


class _CoarseMisreader(torch.nn.Module):
    """A fake method: the true depth of a two-plane scene, clamped to the range it is given,
    except over the stated range, where it reads the near plane 40 % too far (a coarse first
    pass that misses the near part of the scene)."""

    max_coc_px = 20.0
    needs_image = False

    def __init__(self, truth: torch.Tensor, stated: tuple[float, float]):
        super().__init__()
        self.truth, self.stated, self.ranges = truth, stated, []

    def forward(self, image, focused, settings, near, far):
        self.ranges.append((near, far))
        depth = torch.nn.functional.interpolate(self.truth[None], size=focused.shape[-2:],
                                                mode="nearest")
        if (near, far) == self.stated:
            depth = torch.where(depth < 3.0, depth * 1.4, depth)
        depth = depth.clamp(near, far)
        blur = torch.zeros(1, focused.shape[1], *focused.shape[-2:])
        return {"depth": depth, "confidence": torch.ones_like(depth), "blur": blur}


def test_predict_widens_a_refined_range_that_cut_the_scene():
    """The first pass misses the near plane (2 m read as 2.8 m), so the refined range starts
    near 2.6 m and a third of the pixels pile up at its limit: the range is widened and the near
    plane comes out at 2 m (without the widening it stays at the cut limit)."""
    settings = CameraSettings(0.135, 2.8, [3.0, 8.0], 1.2e-4)
    truth = torch.full((1, 48, 64), 4.0)
    truth[:, :, :24] = 2.0
    photos = torch.rand(2, 3, 48, 64, generator=torch.Generator().manual_seed(0))
    model = _CoarseMisreader(truth, (1.0, 20.0))
    out = predict_depth(model, None, photos, settings, 1.0, 20.0)
    assert len(model.ranges) >= 3 and model.ranges[1][0] > 2.4  # refined, then widened
    near, far = out["depth_range"]
    assert 1.0 <= near < 2.0 and 4.0 < far <= 20.0
    assert torch.allclose(out["depth"][:, 8:-8, 4:20], torch.tensor(2.0), rtol=1e-4)


def test_predict_on_flat_photos_with_a_wide_range():
    """A textureless scene reads as one depth: the refined range must not collapse."""
    settings = CameraSettings(0.135, 2.8, [3.0, 8.0], 1.2e-4)
    flat = torch.full((3, 48, 64), 0.5)
    out = predict_depth(SweepDepth(), flat, flat[None].expand(2, 3, 48, 64), settings, 1.0, 20.0)
    near, far = out["depth_range"]
    assert 1.0 <= near < far <= 20.0 and torch.isfinite(out["depth"]).all()


def test_predict_refines_a_stated_range_wider_than_the_scene():
    """A 135 mm lens, a scene at 2.5-4.5 m stated as 1-20 m: the blur at 1 m would force the
    photos down to 40 % of their size; the scene's own range lets the second pass work at full
    resolution, and its depth is closer to the truth."""
    aif, focused, settings, depth = _photographed_planes([2.5, 4.5], seed=6, focus=(3.0, 8.0),
                                                         lens=(0.135, 2.8))
    once = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 20.0, refine_range=False)
    twice = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 20.0)
    assert once["scale"] < 0.5 and twice["scale"] > 0.9
    near, far = twice["depth_range"]
    assert 1.0 < near < 2.5 and 4.5 < far < 20.0
    errors = [float(((o["depth"] - depth).abs() / depth)[:, 8:-8, 8:-8].mean())
              for o in (once, twice)]
    assert errors[1] < 0.05 and errors[1] < errors[0], errors


def test_sweep_sees_through_a_turned_camera():
    """Hand-held: the focused photos are turned by 0.8 and -0.6 degrees (the corners move by
    about a pixel): aligned with a rotation the plane comes out at its depth; moved only, it
    does not."""
    aif, focused, settings, _ = _photographed_planes([3.0], seed=7,
                                                     noise=CaptureNoise(shift_px=0.0))
    turns = torch.tensor([0.8, -0.6])
    focused = torch.cat([warp(f[None], torch.zeros(1, 2), angle=torch.deg2rad(t)[None])
                         for f, t in zip(focused, turns, strict=True)])
    out = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 10.0)
    assert torch.allclose(out["rotations"], turns, atol=0.08), out["rotations"]
    raw = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 10.0, align=False)
    inner = (0, slice(8, -8), slice(8, -8))
    error = [float(((o["depth"][inner] - 3.0).abs() / 3.0).mean()) for o in (out, raw)]
    assert error[0] < 0.02 and error[1] > 3 * error[0], error


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_depth_edge_confidence_is_the_closed_form(dtype):
    blur = torch.full((2, 3, 9, 16), 4.0, dtype=dtype)
    torch.testing.assert_close(sweep.depth_edge_confidence(blur), torch.ones(2, 1, 9, 16,
                                                                               dtype=dtype))
    blur[:, 1, :, 8:] += 1.5  # shot 1's blur jumps by 1.5 px between columns 7 and 8
    got = sweep.depth_edge_confidence(blur, window=5, span_px=0.5)
    expected = torch.ones(16, dtype=dtype)
    expected[6:10] = math.exp(-1.5 / 0.5)  # within 2 px of the jump
    torch.testing.assert_close(got, expected.expand(2, 1, 9, 16))


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"window": 4}, "window"), ({"window": 0}, "window"), ({"span_px": 0.0}, "span_px"),
    ({"span_px": float("nan")}, "span_px")])
def test_depth_edge_confidence_refuses_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        sweep.depth_edge_confidence(torch.zeros(1, 2, 8, 8), **kwargs)


def test_sweep_confidence_is_low_across_a_depth_edge():
    aif, focused, settings, _ = _photographed_planes([2.5, 4.5], seed=1, focus=(1.5, 8.0))
    confidence = predict_depth(SweepDepth(), aif, focused, settings, 1.0, 10.0)["confidence"][0]
    edge = confidence[16:-16, 62:66].mean()
    planes = torch.cat([confidence[16:-16, 16:48], confidence[16:-16, 80:112]], 1).mean()
    assert float(edge) < 0.5 * float(planes)


def test_sweep_confidence_ranks_its_errors_on_held_out_scenes():
    """On procedural scenes under random cameras (none used to choose `BLUR_SPAN_PX`), the more
    confident half of the pixels has a lower mean error than all of them, and lower than the
    texture-only confidence's half (measured on these six: median 0.71 of the mean error,
    texture alone 0.89; no worse on any scene)."""
    ranked, texture_only = [], []
    for i in range(6):
        rng = np.random.default_rng([55, i])
        near = float(np.exp(rng.uniform(np.log(0.5), np.log(4))))
        far = near * float(np.exp(rng.uniform(np.log(2), np.log(6))))
        image, depth = generate_scene((96, 128), rng, (near, far))
        settings = random_camera(rng, near, far, 2, (3.0, 20.0))
        aif, focused = capture(image, depth, settings, rng, CaptureNoise())
        out = predict_depth(SweepDepth(), aif, focused, settings.to(torch.float32), near * 0.8,
                            far * 1.25)
        error = ((out["depth"] - depth).abs() / depth).flatten()
        texture = sweep.texture_confidence(aif[None])
        for confidence, scores in ((out["confidence"], ranked), (texture, texture_only)):
            scores.append(confident_half_error(error, confidence.flatten()))
    assert float(np.median(ranked)) < 0.8, ranked
    assert float(np.median(ranked)) < float(np.median(texture_only)) - 0.1, (ranked, texture_only)
    assert all(a <= b + 0.02 for a, b in zip(ranked, texture_only, strict=True)), (ranked,
                                                                                  texture_only)


def test_blur_errors_tell_the_side_through_an_oriented_code():
    """One focus plane: a textured image blurred through a code without point symmetry at a
    signed CoC of +c (beyond) or -c (nearer) is matched best by its own sign
    (`Aperture.oriented`)."""
    from optics import Mask, render_defocus

    gen = torch.Generator().manual_seed(0)
    code = Mask(torch.rand(6, 6, generator=gen, dtype=torch.float64))
    image = torch.rand(1, 3, 40, 40, generator=gen, dtype=torch.float64)
    blurs = torch.tensor([5.0, -5.0], dtype=torch.float64)
    for sign in (1.0, -1.0):
        focused = render_defocus(image, torch.full((1, 1, 40, 40), 5.0 * sign,
                                                   dtype=torch.float64), code)
        errors = blur_errors(image, focused, code, blurs)[0, :, 10:-10, 10:-10].mean((1, 2))
        right, wrong = (errors[0], errors[1]) if sign > 0 else (errors[1], errors[0])
        assert float(right) < 0.2 * float(wrong)


def test_sweep_tells_the_side_of_one_focus_plane_through_a_code():
    """One focus plane at 2 m; the top half of the photo at 1.43 m, the bottom at its mirror
    across the plane, 3.33 m, both blurred 2.6 px. Through a random code (no point symmetry)
    the sweep puts each half on its own side; through the open disk both halves blur alike and
    land on one side."""
    from optics import Mask, disk_mask, render_focal_stack

    image = _texture((64, 96), torch.float64)[None]
    settings = CameraSettings(0.05, 2.0, [2.0], 1e-4)  # 6.4 px of blur at infinity
    near, far = 1 / 0.7, 1 / 0.3
    depth = torch.full((1, 1, 64, 96), near, dtype=torch.float64)
    depth[..., 32:, :] = far
    code = Mask(torch.rand(16, 16, generator=torch.Generator().manual_seed(0),
                           dtype=torch.float64) * disk_mask(16))
    halves = {}
    for name, aperture in (("code", code), ("disk", Disk())):
        focused = render_focal_stack(image, depth, settings, aperture=aperture)
        found = SweepDepth(aperture)(image, focused, settings, 1.0, 10.0)["depth"][0, 0]
        halves[name] = (float(found[8:24, 8:-8].median()), float(found[40:56, 8:-8].median()))
    assert halves["code"][0] == pytest.approx(near, rel=0.1), halves
    assert halves["code"][1] == pytest.approx(far, rel=0.1), halves
    assert (halves["disk"][0] > 2.0) == (halves["disk"][1] > 2.0), halves


def test_sweep_channels_point_at_the_true_depth_without_gradients():
    """`sweep_channels`: per pixel, standardised over the candidates (mean 0), highest at the
    candidate nearest a plane's true depth; the camera gets no gradient through them."""
    from models.depth_from_photos.sweep import sweep_channels
    from models.depth_from_photos.thin_lens import candidate_inverse_depths
    from optics import render_focal_stack

    image = _texture((48, 64))[None]
    settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
    focused = render_focal_stack(image, torch.full((1, 1, 48, 64), 3.0), settings,
                                 aperture=Disk())
    image.requires_grad_(True)
    channels = sweep_channels(image, focused, settings, 1.0, 10.0, 12, Disk())
    assert channels.shape == (1, 12, 48, 64) and not channels.requires_grad
    torch.testing.assert_close(channels.mean(1), torch.zeros(1, 48, 64), atol=1e-4, rtol=0)
    x = candidate_inverse_depths(1.0, 10.0, 12, channels)
    best = int(channels[0, :, 12:-12, 12:-12].mean((1, 2)).argmax())
    assert best == int((x - 1 / 3.0).abs().argmin())


def test_predict_through_a_code_has_no_mirrored_depths(recwarn):
    """`estimate_depth` with the sweep's `aperture` a code: one focus plane, no warning of
    mirrored depths, and a plane beyond the focus found beyond it."""
    from optics import Mask, disk_mask, render_focal_stack

    image = _texture((64, 96))
    settings = CameraSettings(0.05, 2.0, [2.0], 1e-4)
    code = Mask(torch.rand(16, 16, generator=torch.Generator().manual_seed(0)) * disk_mask(16))
    focused = render_focal_stack(image[None], torch.full((1, 1, 64, 96), 3.33), settings,
                                 aperture=code)[0]
    out = estimate_depth(focused, settings, (1.0, 10.0), image=image,
                         options={"aperture": code}, align=False)  # registered photos
    assert out["mirrored_depths"] is None
    assert not [w for w in recwarn if "mirror" in str(w.message)]
    assert float(out["depth"][0, 16:-16, 16:-16].median()) == pytest.approx(3.33, rel=0.1)
