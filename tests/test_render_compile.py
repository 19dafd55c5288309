"""`torch.compile(render_defocus, fullgraph=True)`: no graph breaks, forward and backward match eager."""

import pytest
import torch

from optics import Disk, Gaussian, Polygon, render_defocus
from optics.render import cpp as _render_cpp

CASES = [
    (Disk, "scatter"),
    (Disk, "gather"),
    (Disk, "layered"),
    (Gaussian, "scatter"),
    (lambda: Polygon(6), "scatter"),
]


def _inputs(device, seed=0):
    gen = torch.Generator().manual_seed(seed)
    image = torch.rand(1, 3, 21, 18, generator=gen).to(device).requires_grad_()
    coc = (torch.rand(1, 1, 21, 18, generator=gen) * 6).to(device).requires_grad_()
    depth = (torch.rand(1, 1, 21, 18, generator=gen) + 1).to(device)
    return image, coc, depth


def _check_compiled_matches_eager(make, mode, device, monkeypatch=None):
    torch._dynamo.reset()
    psf = make().to(device)

    def render(image, coc, depth):
        return render_defocus(image, coc, psf, mode, depth=depth, n_layers=4)

    compiled = torch.compile(render, fullgraph=True)  # fails on any graph break
    image, coc, depth = _inputs(device)
    weights = torch.randn(1, 3, 21, 18, generator=torch.Generator().manual_seed(1)).to(device)
    out = compiled(image, coc, depth)
    grads = torch.autograd.grad((out * weights).sum(), (image, coc))
    ref = render(image, coc, depth)
    ref_grads = torch.autograd.grad((ref * weights).sum(), (image, coc))
    torch.testing.assert_close(out, ref)
    for got, want in zip(grads, ref_grads, strict=True):
        torch.testing.assert_close(got, want)
    # A second CoC map with another largest CoC: the window follows it inside the graph.
    image2, coc2, depth2 = _inputs(device, seed=2)
    coc2 = (coc2.detach() * 1.7).requires_grad_()
    torch.testing.assert_close(compiled(image2, coc2, depth2), render(image2, coc2, depth2))


@pytest.mark.parametrize("make,mode", CASES, ids=[f"{i}" for i in range(len(CASES))])
def test_compile_fullgraph_matches_eager_cpu(make, mode):
    _check_compiled_matches_eager(make, mode, torch.device("cpu"))


@pytest.mark.parametrize("mode", ["scatter", "layered"])
def test_compile_fullgraph_pure_path(monkeypatch, mode):
    """The PyTorch loops (the GPU path) compile the same way: they run inside the operators;
    the layered mode's compositing (a custom autograd function) traces too."""
    monkeypatch.setattr(_render_cpp, "usable", lambda x: False)
    _check_compiled_matches_eager(Disk, mode, torch.device("cpu"))


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("make,mode", CASES[:4], ids=[f"{i}" for i in range(4)])
def test_compile_fullgraph_matches_eager_cuda(make, mode):
    _check_compiled_matches_eager(make, mode, torch.device("cuda"))
