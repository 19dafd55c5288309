"""`FourierBlur`: whole-image convolutions through one transform of the photo."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from models.depth_from_photos.fourier_blur import FourierBlur, psf_kernel, with_floor
from optics import Disk


def _direct(image: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """The convolution (not correlation) of `image` with `kernel`, borders mirrored: an
    independent computation."""
    half = kernel.shape[-1] // 2
    padded = F.pad(image, (half,) * 4, mode="reflect")
    weight = kernel.flip((0, 1)).expand(image.shape[1], 1, *kernel.shape)
    return F.conv2d(padded, weight, groups=image.shape[1])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("grad", [False, True])
@pytest.mark.parametrize("symmetric", [True, False])
def test_apply_is_the_mirrored_convolution(dtype, grad, symmetric):
    """Both transforms (scipy's without gradients, torch's with them) give the direct
    convolution, for a point-symmetric disk (real transfer) and a lopsided kernel (complex)."""
    g = torch.Generator().manual_seed(1)
    image = torch.rand(2, 3, 23, 31, generator=g, dtype=dtype).requires_grad_(grad)
    kernel = with_floor(psf_kernel(Disk(), 3.5, image))
    if not symmetric:
        kernel = kernel * torch.linspace(0.2, 1.8, kernel.shape[-1], dtype=dtype)
        kernel = kernel / kernel.sum()
    blur = FourierBlur(image, pad=kernel.shape[-1] // 2 + 2)
    transfer = blur.transfer(kernel)
    assert transfer.is_complex() != symmetric
    out = blur.apply(transfer)
    assert out.shape == image.shape and out.dtype == dtype and out.requires_grad == grad
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    torch.testing.assert_close(out, _direct(image, kernel), rtol=0, atol=tol)


def test_apply_gradcheck():
    """Differentiable in the image and in the kernel (through its transfer function)."""
    g = torch.Generator().manual_seed(2)
    image = torch.rand(1, 2, 9, 11, generator=g, dtype=torch.float64, requires_grad=True)
    kernel = torch.rand(3, 3, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda x, k: FourierBlur(x, pad=3).apply(FourierBlur(x, pad=3).transfer(k)),
        (image, kernel))


@pytest.fixture
def threads(request):
    """`torch.set_num_threads(request.param)` for the test, restored after it."""
    before = torch.get_num_threads()
    torch.set_num_threads(request.param)
    yield request.param
    torch.set_num_threads(before)


@pytest.mark.parametrize("threads", [1, 4], indirect=True)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_scipy_transforms_are_torchs(dtype, threads):
    """`optics.fourier.rfft2`/`irfft2` on a CPU without gradients (scipy's, in place; the six
    planes shared among 4 threads unevenly) give `torch.fft`'s values; a spectrum overwritten in
    place leaves earlier results alone; with gradients they are torch's own."""
    from optics.fourier import irfft2, rfft2

    g = torch.Generator().manual_seed(3)
    x = torch.rand(2, 3, 30, 45, generator=g, dtype=dtype)
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    spectrum = rfft2(x)
    torch.testing.assert_close(spectrum, torch.fft.rfft2(x), rtol=0, atol=tol * 100)
    buffer = spectrum.clone()
    first = irfft2(buffer, (30, 45), slice(4, 20), overwrite=True)
    kept = first.clone()
    second = irfft2(buffer.copy_(spectrum * 2), (30, 45), overwrite=True)
    assert torch.equal(first, kept)
    torch.testing.assert_close(first, x[..., 4:20, :], rtol=0, atol=tol)
    torch.testing.assert_close(second, 2 * x, rtol=0, atol=2 * tol)
    graded = x.clone().requires_grad_()
    out = irfft2(rfft2(graded), (30, 45), slice(1, 5))
    assert out.grad_fn is not None
    torch.testing.assert_close(out.detach(), x[..., 1:5, :], rtol=0, atol=tol)


LEFT_THREADS = """
import os, time, torch
from optics.fourier import irfft2, rfft2
torch.set_num_threads(2)
before = len(os.listdir("/proc/self/task"))
irfft2(rfft2(torch.rand(4, 64, 96)), (64, 96))
for _ in range(40):  # a joined thread's OS thread may take a moment to leave /proc
    if len(os.listdir("/proc/self/task")) <= before:
        break
    time.sleep(0.05)
print(len(os.listdir("/proc/self/task")) - before)
"""


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="counts threads in /proc")
def test_scipy_transforms_leave_no_thread_behind():
    """The transforms' threads end with the call (counted in a fresh process): a thread pool
    left alive (scipy's `workers`) makes a later `fork()` (a DataLoader's workers) hang now and
    then in its fork handler."""
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, "-c", LEFT_THREADS], capture_output=True, text=True,
                         env=dict(os.environ, PYTHONPATH=str(root)), timeout=120, check=True)
    assert out.stdout.split()[-1] == "0"
