"""Optional compiled CPU kernel of the Gaussian scatter filter, ``optics/csrc/gaussian_scatter.cpp``.

The kernel is plain C++ with OpenMP and a C ABI, loaded with :mod:`ctypes`: it needs no PyTorch
headers, so it builds in a couple of seconds on first use, with the system's C++ compiler
(``$CXX``, else ``c++``/``g++``/``clang++``). The shared library is cached under
``build/defocus_cpp/`` next to the package (or ``$DEFOCUS_BUILD_DIR``; the temp directory when
neither is writable), keyed by a hash of the source and the flags, so editing the source rebuilds.

When no compiler is found or the build fails, :func:`usable` returns ``False`` and the renderer
uses its pure PyTorch loop (same results, tested against each other). Set ``DEFOCUS_NO_CPP=1`` to
force the PyTorch path. Build ahead of time with
``python -c "import optics._render_cpp as k; print(k.library())"``.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import torch
from torch import Tensor

SOURCE = Path(__file__).with_name("csrc") / "gaussian_scatter.cpp"
FLAG_SETS = (
    ["-O3", "-march=native", "-fopenmp", "-shared", "-fPIC", "-std=c++17"],
    ["-O3", "-fopenmp", "-shared", "-fPIC", "-std=c++17"],
    ["-O3", "-shared", "-fPIC", "-std=c++17"],
)

_lock = threading.Lock()
_state: dict[str, object] = {}


def _compiler() -> str | None:
    for name in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if name and shutil.which(name):
            return name
    return None


def _build_dirs() -> list[Path]:
    dirs = []
    if os.environ.get("DEFOCUS_BUILD_DIR"):
        dirs.append(Path(os.environ["DEFOCUS_BUILD_DIR"]))
    dirs.append(Path(__file__).resolve().parents[1] / "build" / "defocus_cpp")
    dirs.append(Path(tempfile.gettempdir()) / "defocus_cpp")
    return dirs


def _cpu_signature() -> str:
    """The CPU's model and features: a library built with ``-march=native`` is tied to them."""
    try:
        info = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        info = []
    keep = [line for line in info if line.startswith(("model name", "flags", "Features"))][:2]
    return platform.machine() + "".join(keep)


def _build() -> ctypes.CDLL | None:
    compiler = _compiler()
    if compiler is None or not SOURCE.exists():
        return None
    source = SOURCE.read_bytes()
    for flags in FLAG_SETS:
        signature = " ".join([compiler, *flags, _cpu_signature()])
        key = hashlib.sha256(source + signature.encode()).hexdigest()[:16]
        for folder in _build_dirs():
            library = folder / f"gaussian_scatter_{key}.so"
            if not library.exists():
                try:
                    folder.mkdir(parents=True, exist_ok=True)
                    partial = folder / f".{library.name}.{os.getpid()}.tmp"
                    subprocess.run(
                        [compiler, *flags, str(SOURCE), "-o", str(partial)],
                        check=True, capture_output=True, timeout=120,
                    )
                    os.replace(partial, library)  # atomic: concurrent builds never see a half file
                except (OSError, subprocess.SubprocessError):
                    continue
            try:
                return _bind(ctypes.CDLL(str(library)))
            except OSError:
                continue
    return None


def _bind(lib: ctypes.CDLL) -> ctypes.CDLL:
    ptr, i64, i32 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int
    for suffix in ("f32", "f64"):
        getattr(lib, f"gs_forward_{suffix}").argtypes = [ptr] * 4 + [i64] * 5 + [i32]
        getattr(lib, f"gs_backward_{suffix}").argtypes = [ptr] * 5 + [i64] * 5 + [i32]
        getattr(lib, f"gs_window_sums_{suffix}").argtypes = [ptr] * 3 + [i64] * 2 + [i32]
    return lib


def library() -> ctypes.CDLL | None:
    """The loaded kernel library, building it on first call; ``None`` if it cannot be built."""
    if "lib" not in _state:
        with _lock:
            if "lib" not in _state:
                disabled = os.environ.get("DEFOCUS_NO_CPP", "") not in ("", "0")
                _state["lib"] = None if disabled else _build()
    return _state["lib"]  # type: ignore[return-value]


def usable(x: Tensor) -> bool:
    """Whether the compiled kernel can process ``x`` (CPU float32/float64, library built)."""
    return (
        x.device.type == "cpu"
        and x.dtype in (torch.float32, torch.float64)
        and library() is not None
    )


def _suffix(x: Tensor) -> str:
    return "f32" if x.dtype == torch.float32 else "f64"


def gaussian_scatter_forward(x: Tensor, sigma: Tensor, norm: Tensor, half: int) -> Tensor:
    """Compiled twin of ``_gaussian_scatter_forward_torch`` (contiguous CPU tensors)."""
    out = torch.empty_like(x)
    b, c, h, w = x.shape
    getattr(library(), f"gs_forward_{_suffix(x)}")(
        x.data_ptr(), sigma.data_ptr(), norm.data_ptr(), out.data_ptr(),
        b, c, h, w, half, torch.get_num_threads(),
    )
    return out


def window_sums(sigma: Tensor, half: int) -> tuple[Tensor, Tensor]:
    """Compiled twin of ``_render_ops._window_line_sums`` (contiguous CPU tensor)."""
    line, moment = torch.empty_like(sigma), torch.empty_like(sigma)
    getattr(library(), f"gs_window_sums_{_suffix(sigma)}")(
        sigma.data_ptr(), line.data_ptr(), moment.data_ptr(), sigma.numel(), half,
        torch.get_num_threads(),
    )
    return line, moment


def gaussian_scatter_backward(
    grad: Tensor, x: Tensor, sigma: Tensor, half: int
) -> tuple[Tensor, Tensor]:
    """Compiled twin of ``_gaussian_scatter_backward_torch``: ``(dx_raw, m1)``."""
    dx_raw = torch.empty_like(x)
    m1 = torch.empty_like(sigma)
    b, c, h, w = x.shape
    getattr(library(), f"gs_backward_{_suffix(x)}")(
        grad.data_ptr(), x.data_ptr(), sigma.data_ptr(), dx_raw.data_ptr(), m1.data_ptr(),
        b, c, h, w, half, torch.get_num_threads(),
    )
    return dx_raw, m1


