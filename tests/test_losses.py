"""Self-supervised losses: perfect prediction is the minimum, gradients reach the depth."""

import importlib.util
import json
from pathlib import Path

import kornia
import pytest
import torch

from models.losses import (
    DefocusLoss,
    edge_aware_smoothness,
    photometric_loss,
    sharpness_loss,
    ssim_map,
    supervised_depth_loss,
)
from optics import CameraSettings, render_focal_stack


def _camera(dtype, b=1):
    return CameraSettings(0.05, 2.0, [[2.0, 6.0]] * b, 180e-6).to(dtype)


def _scene(dtype, b=1, size=16):
    g = torch.Generator().manual_seed(0)
    image = torch.rand(b, 3, size, size, generator=g).to(dtype)
    depth = (1.5 + 5 * torch.rand(b, 1, size, size, generator=g)).to(dtype)
    return image, depth


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_photometric_matches_definition(dtype):
    g = torch.Generator().manual_seed(1)
    a, b = torch.rand(2, 3, 12, 12, generator=g).to(dtype), torch.rand(2, 3, 12, 12, generator=g).to(dtype)
    ssim = kornia.metrics.ssim(a, b, 7)
    expected = 0.85 * ((1 - ssim) / 2).clamp(0, 1).mean() + 0.15 * (a - b).abs().mean()
    torch.testing.assert_close(photometric_loss(a, b), expected)
    assert float(photometric_loss(a, a)) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("window_size", [3, 7, 11])
def test_ssim_map_matches_kornia_values_and_gradients(dtype, window_size):
    g = torch.Generator().manual_seed(2)
    a = torch.rand(2, 3, 13, 17, generator=g).to(dtype).requires_grad_()
    b = torch.rand(2, 3, 13, 17, generator=g).to(dtype).requires_grad_()
    ours = ssim_map(a, b, window_size)
    theirs = kornia.metrics.ssim(a, b, window_size)
    tol = {"atol": 1e-5, "rtol": 1e-5} if dtype == torch.float32 else {}
    torch.testing.assert_close(ours, theirs, **tol)
    weight = torch.rand(ours.shape, generator=g).to(dtype)
    grads = torch.autograd.grad((ours * weight).sum(), (a, b))
    expected = torch.autograd.grad((theirs * weight).sum(), (a, b))
    for got, want in zip(grads, expected, strict=True):
        torch.testing.assert_close(got, want, **tol)


def test_ssim_map_gradcheck():
    g = torch.Generator().manual_seed(3)
    a = torch.rand(1, 2, 6, 7, generator=g, dtype=torch.float64, requires_grad=True)
    b = torch.rand(1, 2, 6, 7, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x, y: ssim_map(x, y, 5), (a, b))


def test_ssim_map_window_made_in_inference_mode_still_trains():
    a, b = torch.rand(1, 3, 9, 9), torch.rand(1, 3, 9, 9)
    with torch.inference_mode():
        ssim_map(a, b, 9)  # the first call makes the cached window
    x = a.clone().requires_grad_()
    ssim_map(x, b, 9).mean().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all()


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"window_size": 4}, "window_size must be an odd number of pixels >= 1, got 4"),
    ({"y": torch.rand(1, 3, 8, 9)}, "x and y must have the same shape"),
])
def test_ssim_map_refuses_bad_input(kwargs, match):
    args = {"x": torch.rand(1, 3, 8, 8), "y": torch.rand(1, 3, 8, 8), **kwargs}
    with pytest.raises(ValueError, match=match):
        ssim_map(**args)


def test_render_focal_stack_matches_camera_render():
    image, depth = _scene(torch.float64, b=2)
    camera = _camera(torch.float64, b=2)
    out = render_focal_stack(image, depth, camera)
    for i in range(2):
        for f in range(2):
            cam = camera[i].shot(f)
            # windows follow the largest CoC of the batch: Gaussian tails beyond 3 sigma differ
            torch.testing.assert_close(out[i, f], cam.render(image[i:i + 1], depth[i:i + 1])[0],
                                       atol=2e-4, rtol=0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_perfect_depth_is_the_minimum(dtype):
    image, depth = _scene(dtype)
    camera = _camera(dtype)
    focused = render_focal_stack(image, depth, camera)
    loss = DefocusLoss(smoothness_weight=0.0)
    best = float(loss(depth, image, focused, camera)["loss"])
    assert best == pytest.approx(0.0, abs=1e-6)
    for factor in (0.8, 0.95, 1.05, 1.3):
        assert float(loss(depth * factor, image, focused, camera)["loss"]) > best + 1e-4
    constant = torch.full_like(depth, float(depth.median()))
    assert float(loss(constant, image, focused, camera)["loss"]) > best + 1e-3


def test_gradients_reach_depth():
    image, depth = _scene(torch.float64, size=10)
    camera = _camera(torch.float64)
    focused = render_focal_stack(image, depth, camera)
    guess = (depth * 1.2).requires_grad_()
    terms = DefocusLoss()(guess, image, focused, camera)
    terms["loss"].backward()
    assert guess.grad is not None and float(guess.grad.abs().sum()) > 0
    assert torch.isfinite(guess.grad).all()


def test_gradcheck_photometric_and_smoothness():
    image, depth = _scene(torch.float64, size=5)
    target = torch.rand(1, 3, 5, 5, dtype=torch.float64)
    rendered = image.clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda x: photometric_loss(x, target, window_size=3),
                                    (rendered,))
    assert torch.autograd.gradcheck(lambda x: sharpness_loss(x, target), (rendered,))
    d = depth.clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda x: edge_aware_smoothness(x, image), (d,))


def test_gradcheck_loss_wrt_depth():
    image, depth = _scene(torch.float64, size=5)
    camera = _camera(torch.float64)
    focused = render_focal_stack(image, depth * 0.9, camera)
    loss = DefocusLoss(window_size=3)
    d = depth.clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda x: loss(x, image, focused, camera)["loss"], (d,),
                                    atol=1e-5)


def test_smoothness_edge_aware():
    depth = torch.ones(1, 1, 8, 8)
    depth[..., 4:] = 2.0
    flat, edge = torch.zeros(1, 3, 8, 8), torch.zeros(1, 3, 8, 8)
    edge[..., 4:] = 1.0
    assert float(edge_aware_smoothness(depth, edge)) < float(edge_aware_smoothness(depth, flat))
    assert float(edge_aware_smoothness(torch.full((1, 1, 8, 8), 5.0), flat)) == 0.0


def test_supervised_loss_by_hand():
    d = torch.tensor([[[[1.0, 3.0]]]])
    g = torch.tensor([[[[2.0, 2.0]]]])
    assert float(supervised_depth_loss(d, g)) == pytest.approx(0.5)
    mask = torch.tensor([[[[True, False]]]])
    assert float(supervised_depth_loss(d, g, mask)) == pytest.approx(0.5)


def test_errors():
    with pytest.raises(ValueError, match="same shape"):
        photometric_loss(torch.rand(1, 3, 8, 8), torch.rand(1, 3, 8, 9))
    with pytest.raises(ValueError, match="ssim_weight"):
        photometric_loss(torch.rand(1, 3, 8, 8), torch.rand(1, 3, 8, 8), ssim_weight=2.0)
    with pytest.raises(ValueError, match="depth"):
        render_focal_stack(torch.rand(1, 3, 8, 8), torch.rand(1, 2, 8, 8) + 1, _camera(torch.float32))


def test_loss_benchmark_prints_its_table_and_goals(tmp_path, capsys):
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "loss.py"
    spec = importlib.util.spec_from_file_location("loss_benchmark", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    out = tmp_path / "ssim.json"
    assert bench.main(["--sizes", "8,12", "--repeats", "2", "--batch", "2", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "goal: forward operations <= half Kornia's" in printed
    rows = json.loads(out.read_text())["rows"]
    assert [r["size"] for r in rows] == [8, 12]
    assert all(r["ops"][0] < r["kornia_ops"][0] and r["max_difference"] <= 1e-4 for r in rows)
