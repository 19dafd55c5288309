"""Shared fixtures: devices and dtypes to parametrise over, a brute-force renderer, a
finite-difference check of a parameter's gradient and a loader of the repository's scripts."""

import importlib.util
import sys
from pathlib import Path

import pytest
import torch

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture(params=[torch.float32, torch.float64], ids=["float32", "float64"])
def dtype(request):
    return request.param


@pytest.fixture(params=DEVICES)
def device(request):
    return torch.device(request.param)


def _brute_force_render(image, coc, psf, scatter):
    """Independent double loop over output and source pixels, from `psf.kernel` (float64)."""
    _, c, h, w = image.shape
    half = psf.half_width(float(coc.abs().max()))  # a signed CoC (a Mask): its magnitude
    out = torch.zeros_like(image)
    for py in range(h):
        for px in range(w):
            num, den = torch.zeros(c, dtype=image.dtype), 0.0
            for qy in range(max(0, py - half), min(h, py + half + 1)):
                for qx in range(max(0, px - half), min(w, px + half + 1)):
                    # scatter: the source's PSF (normalised over its full discrete window);
                    # gather: the output's PSF, at the same offset output - source
                    owner = coc[0, 0, qy, qx] if scatter else coc[0, 0, py, px]
                    wgt = psf.kernel(owner, 2 * half + 1)[0][half + py - qy, half + px - qx]
                    num += wgt * image[0, :, qy, qx]
                    den += float(wgt)
            out[0, :, py, px] = num / den
    return out


@pytest.fixture
def brute_force_render():
    """`f(image, coc, psf, scatter)`: the rendering by an independent double loop (batch 0)."""
    return _brute_force_render


def _check_param_grad(loss, param, step=1e-6):
    """Autograd's `d loss() / d param` (a scalar parameter) matches a central difference and is
    not vanishing; `param` is left shifted by `-step`."""
    (grad,) = torch.autograd.grad(loss(), param)
    with torch.no_grad():
        param += step
        up = loss()
        param -= 2 * step
        down = loss()
    assert float(grad) == pytest.approx(float(up - down) / (2 * step), rel=1e-5, abs=1e-8)
    assert abs(float(grad)) > 1e-3


@pytest.fixture
def check_param_grad():
    """`f(loss, param)`: asserts the gradient of `loss()` in `param` against a central difference."""
    return _check_param_grad


@pytest.fixture(scope="module")
def scenes():
    """Six 16x16 synthetic scenes, rendered once per test module."""
    from datasets.synthetic import SyntheticScenes

    data = SyntheticScenes(6, (16, 16), seed=3)
    [data[i] for i in range(len(data))]
    return data


@pytest.fixture
def load_script(monkeypatch):
    """`load(relative_path)`: a script of the repository (`benchmarks/...`, `examples/...`)
    imported as a module, registered in `sys.modules` for the test (its dataclasses look
    themselves up there); the torch thread count it sets is restored after the test."""
    monkeypatch.setattr(torch.backends.cudnn, "benchmark", torch.backends.cudnn.benchmark)
    threads = torch.get_num_threads()

    def load(relative_path):
        path = Path(__file__).resolve().parents[1] / relative_path
        name = f"script_{path.parent.name}_{path.stem}"
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        monkeypatch.setitem(sys.modules, name, module)
        spec.loader.exec_module(module)
        return module

    yield load
    torch.set_num_threads(threads)
