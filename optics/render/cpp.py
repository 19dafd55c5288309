"""Optional compiled CPU kernels of the renderer, `optics/render/csrc/render_kernels.cpp`.

The kernels are plain C++ with OpenMP and a C ABI, loaded with `ctypes`: they need no PyTorch
headers, so they build in a few seconds on first use with the system's C++ compiler (`$CXX`,
else `c++`/`g++`/`clang++`). `optics.render.ops` wraps them as `torch.library` custom operators
(with fake implementations and registered autograd), which is what lets `torch.compile` trace the
renderer without graph breaks; the ctypes call itself stays inside the operator.

Where the library lives and when it is trusted:

- It is built into the per-user cache, `user_cache_dir("kernels")` of `optics.cache`
  (`$DEFOCUS_CACHE_DIR/kernels`, else `$XDG_CACHE_HOME/defocus/kernels`, else
  `~/.cache/defocus/kernels`): never the working directory, the package folder or the shared
  temporary folder. The file name is keyed by a hash of the source, the compiler, the flags and the
  CPU, so editing the source rebuilds.
- It is loaded only when that folder and its parents up to the cache root, and the file itself,
  are owned by the current user and not writable by group or others; otherwise a warning (once)
  names the path and the renderer uses its pure PyTorch path.
- The library's sha256 is written next to it (`<name>.sha256`, atomically) when it is built and
  checked before every load; on a mismatch it is rebuilt (with a warning), and when that fails
  the pure path is used.

When no compiler is found or the build fails, `usable` returns `False` and the renderer uses its
pure PyTorch loops (same results, tested against each other). `DEFOCUS_NO_CPP=1` forces the
PyTorch path. Build ahead of time with `python -c "import optics.render.cpp as k; k.library()"`.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import stat
import subprocess
import tempfile
import threading
import warnings
from pathlib import Path

import torch
from torch import Tensor

from ..cache import cache_root, is_private_dir, user_cache_dir

SOURCE = Path(__file__).with_name("csrc") / "render_kernels.cpp"
FLAG_SETS = (
    ["-O3", "-march=native", "-fopenmp", "-shared", "-fPIC", "-std=c++17"],
    ["-O3", "-fopenmp", "-shared", "-fPIC", "-std=c++17"],
    ["-O3", "-shared", "-fPIC", "-std=c++17"],
)
#: Name of the kernels' folder inside the per-user cache.
KERNEL_SUBDIR = "kernels"

_lock = threading.RLock()
_state: dict[str, object] = {}
_warned: set[str] = set()


def _warn_once(message: str) -> None:
    if message not in _warned:
        _warned.add(message)
        warnings.warn(message, RuntimeWarning, stacklevel=3)


def reset() -> None:
    """Forget the loaded library (and the warnings given), so that the next call looks again."""
    with _lock:
        _state.clear()
        _warned.clear()


def kernel_dir() -> Path:
    """Folder of the compiled kernels: `user_cache_dir("kernels")`."""
    return user_cache_dir(KERNEL_SUBDIR)


def _compiler() -> str | None:
    for name in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if name and shutil.which(name):
            return name
    return None


def _cpu_signature() -> str:
    """The CPU's model and features: a library built with `-march=native` is tied to them."""
    try:
        info = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        info = []
    keep = [line for line in info if line.startswith(("model name", "flags", "Features"))][:2]
    return platform.machine() + "".join(keep)


def _make_private_dirs(folder: Path, root: Path) -> None:
    """Create `root` .. `folder` with mode 0o700 where missing (existing ones are left alone)."""
    root.parent.mkdir(parents=True, exist_ok=True)  # above the root: not ours to restrict
    missing = [p for p in [folder, *folder.parents] if p == root or root in p.parents]
    for path in reversed(missing):
        if not path.exists():
            path.mkdir(mode=0o700, exist_ok=True)


def _file_problem(path: Path) -> str | None:
    """Why `path` must not be trusted (not a regular file of ours, or writable by others)."""
    try:
        info = path.lstat()
    except OSError as error:
        return f"cannot stat {path}: {error}"
    if not stat.S_ISREG(info.st_mode):
        return f"{path} is not a regular file"
    if hasattr(os, "getuid") and info.st_uid != os.getuid():
        return f"{path} is owned by uid {info.st_uid}, not the current user ({os.getuid()})"
    if info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"{path} is writable by group or others (mode {oct(info.st_mode & 0o777)})"
    return None


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _write_atomic(path: Path, data: bytes) -> None:
    handle, partial = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as stream:
            stream.write(data)
        os.chmod(partial, 0o600)
        os.replace(partial, path)
    except BaseException:
        Path(partial).unlink(missing_ok=True)
        raise


def _compile(compiler: str, flags: list[str], library: Path) -> bool:
    """Build `library` (atomically) and record its sha256 next to it; `False` on failure."""
    handle, partial = tempfile.mkstemp(dir=library.parent, prefix=f".{library.name}.", suffix=".tmp")
    os.close(handle)
    try:
        subprocess.run([compiler, *flags, str(SOURCE), "-o", partial], check=True,
                       capture_output=True, timeout=300)
        os.chmod(partial, 0o700)
        digest = _sha256(Path(partial))
        _write_atomic(_sidecar(library), digest.encode())
        os.replace(partial, library)  # atomic: concurrent builds never see a half-written file
        return True
    except (OSError, subprocess.SubprocessError):
        return False
    finally:
        Path(partial).unlink(missing_ok=True)


def _sidecar(library: Path) -> Path:
    return library.with_name(library.name + ".sha256")


def _verified(library: Path) -> tuple[bool, str]:
    """Whether `library` is ours, private and matches its recorded sha256."""
    for path in (library, _sidecar(library)):
        problem = _file_problem(path)
        if problem is not None:
            return False, problem
    recorded = _sidecar(library).read_text().strip()
    actual = _sha256(library)
    if recorded != actual:
        return False, f"{library} has sha256 {actual[:16]}..., recorded {recorded[:16]}..."
    return True, ""


def _build() -> ctypes.CDLL | None:
    compiler = _compiler()
    if compiler is None or not SOURCE.exists():
        return None
    root, folder = cache_root(), kernel_dir()
    try:
        _make_private_dirs(folder, root)
    except OSError as error:
        _warn_once(f"defocus: cannot create the kernel cache {folder} ({error}); using the pure "
                   "PyTorch renderer")
        return None
    private, why = is_private_dir(folder, root)
    if not private:
        _warn_once(f"defocus: not loading compiled kernels from {folder}: {why}; using the pure "
                   "PyTorch renderer (fix the permissions, e.g. chmod go-w, or set "
                   "DEFOCUS_CACHE_DIR)")
        return None
    source = SOURCE.read_bytes()
    for flags in FLAG_SETS:
        signature = " ".join([compiler, *flags, _cpu_signature()])
        key = hashlib.sha256(source + signature.encode()).hexdigest()[:16]
        library = folder / f"render_kernels_{key}.so"
        if library.exists() or _sidecar(library).exists():
            ok, why = _verified(library)
            if not ok:
                _warn_once(f"defocus: not loading the compiled kernel library: {why}; rebuilding it")
                if not _compile(compiler, flags, library):
                    _warn_once(f"defocus: rebuilding {library} failed; using the pure PyTorch "
                               "renderer")
                    return None
        elif not _compile(compiler, flags, library):
            continue
        ok, why = _verified(library)  # checked again right before loading
        if not ok:
            _warn_once(f"defocus: not loading the compiled kernel library: {why}; using the pure "
                       "PyTorch renderer")
            return None
        try:
            return _bind(ctypes.CDLL(str(library)))
        except (OSError, AttributeError):
            continue
    return None


def _bind(lib: ctypes.CDLL) -> ctypes.CDLL:
    ptr, i64, i32 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int
    for suffix in ("f32", "f64"):
        getattr(lib, f"gs_forward_{suffix}").argtypes = [ptr] * 4 + [i64] * 5 + [i32]
        getattr(lib, f"gs_backward_{suffix}").argtypes = [ptr] * 5 + [i64] * 5 + [i32]
        getattr(lib, f"gs_window_sums_{suffix}").argtypes = [ptr] * 3 + [i64] * 2 + [i32]
        getattr(lib, f"cl_forward_{suffix}").argtypes = [ptr] * 5 + [i64] * 5 + [i32]
        getattr(lib, f"cl_backward_{suffix}").argtypes = [ptr] * 6 + [i64] * 5 + [i32]
        getattr(lib, f"cl_window_sums_{suffix}").argtypes = (
            [ptr] * 3 + [i64] + [ptr] * 2 + [i64] + [i32]
        )
        getattr(lib, f"gs_render_{suffix}").argtypes = [ptr] * 4 + [i64] * 5 + [i32]
        getattr(lib, f"gs_render_backward_{suffix}").argtypes = [ptr] * 7 + [i64] * 5 + [i32]
        getattr(lib, f"cl_render_{suffix}").argtypes = (
            [ptr] * 5 + [i64] + [ptr] * 2 + [i64] * 5 + [i32]
        )
        getattr(lib, f"cl_render_backward_{suffix}").argtypes = (
            [ptr] * 8 + [i64] + [ptr] * 2 + [i64] * 5 + [i32]
        )
        getattr(lib, f"gs_layered_{suffix}").argtypes = [ptr] * 5 + [i64] * 6 + [i32]
        getattr(lib, f"gs_layered_backward_{suffix}").argtypes = [ptr] * 9 + [i64] * 6 + [i32]
        getattr(lib, f"cl_layered_{suffix}").argtypes = (
            [ptr] * 6 + [i64] + [ptr] * 2 + [i64] * 6 + [i32]
        )
        getattr(lib, f"cl_layered_backward_{suffix}").argtypes = (
            [ptr] * 9 + [i64] + [ptr] * 3 + [i64] * 6 + [i32]
        )
    return lib


def library() -> ctypes.CDLL | None:
    """The loaded kernel library, building it on first call; `None` if it cannot be used."""
    if "lib" not in _state:
        with _lock:
            if "lib" not in _state:
                disabled = os.environ.get("DEFOCUS_NO_CPP", "") not in ("", "0")
                _state["lib"] = None if disabled else _build()
    return _state["lib"]  # type: ignore[return-value]


def usable(x: Tensor) -> bool:
    """Whether the compiled kernels can process `x` (CPU float32/float64, library loaded)."""
    return (
        x.device.type == "cpu"
        and x.dtype in (torch.float32, torch.float64)
        and library() is not None
    )


def _suffix(x: Tensor) -> str:
    return "f32" if x.dtype == torch.float32 else "f64"


def _call(name: str, like: Tensor, *args: Tensor | int) -> None:
    """Run kernel `<name>_f32` or `<name>_f64` (by `like`'s dtype) on `args`, tensors passed as
    pointers, then the thread count."""
    getattr(library(), f"{name}_{_suffix(like)}")(
        *(a.data_ptr() if isinstance(a, Tensor) else a for a in args), torch.get_num_threads()
    )


def _family(name: str, clamp: tuple[Tensor, Tensor, Tensor] | None) -> tuple[str, tuple]:
    """The Gaussian (`clamp is None`) or clamped-distance kernel `name`, and the arguments the
    latter takes after the parameter map: `dist, dists, counts, n_dists`."""
    if clamp is None:
        return f"gs_{name}", ()
    dist, dists, counts = clamp
    return f"cl_{name}", (dist, dists, counts, dists.numel())


def gaussian_scatter_forward(x: Tensor, sigma: Tensor, norm: Tensor, half: int) -> Tensor:
    """Compiled twin of `_gaussian_scatter_forward_torch` (contiguous CPU tensors)."""
    out = torch.empty_like(x)
    _call("gs_forward", x, x, sigma, norm, out, *x.shape, half)
    return out


def window_sums(sigma: Tensor, half: int) -> tuple[Tensor, Tensor]:
    """Compiled twin of the PyTorch loop of `ops.gaussian_window_sums` (contiguous CPU tensor)."""
    line, moment = torch.empty_like(sigma), torch.empty_like(sigma)
    _call("gs_window_sums", sigma, sigma, line, moment, sigma.numel(), half)
    return line, moment


def gaussian_scatter_backward(
    grad: Tensor, x: Tensor, sigma: Tensor, half: int
) -> tuple[Tensor, Tensor]:
    """Compiled twin of `_gaussian_scatter_backward_torch`: `(dx_raw, m1)`."""
    dx_raw, m1 = torch.empty_like(x), torch.empty_like(sigma)
    _call("gs_backward", x, grad, x, sigma, dx_raw, m1, *x.shape, half)
    return dx_raw, m1


def clamp_scatter_forward(x: Tensor, rho: Tensor, norm: Tensor, dist: Tensor, half: int) -> Tensor:
    """Compiled twin of `_clamp_scatter_forward_torch` (contiguous CPU tensors, `dist` K x K)."""
    out = torch.empty_like(x)
    _call("cl_forward", x, x, rho, norm, dist, out, *x.shape, half)
    return out


def clamp_scatter_backward(
    grad: Tensor, x: Tensor, rho: Tensor, dist: Tensor, half: int
) -> tuple[Tensor, Tensor]:
    """Compiled twin of `_clamp_scatter_backward_torch`: `(dx_raw, m)`."""
    dx_raw, m = torch.empty_like(x), torch.empty_like(rho)
    _call("cl_backward", x, grad, x, rho, dist, dx_raw, m, *x.shape, half)
    return dx_raw, m


def clamp_window_sums(rho: Tensor, dists: Tensor, counts: Tensor) -> tuple[Tensor, Tensor]:
    """Compiled twin of `_clamp_window_sums_torch`: `(Z, dZ/drho)` per pixel."""
    total, slope = torch.empty_like(rho), torch.empty_like(rho)
    _call("cl_window_sums", rho, rho, dists, counts, dists.numel(), total, slope, rho.numel())
    return total, slope


def gaussian_render(x: Tensor, sigma: Tensor, half: int) -> tuple[Tensor, Tensor]:
    """Fused normalised Gaussian scatter: `(y, den)`, see `render_kernels.cpp`."""
    y, den = torch.empty_like(x), torch.empty_like(sigma)
    _call("gs_render", x, x, sigma, y, den, *x.shape, half)
    return y, den


def gaussian_render_backward(
    grad: Tensor, y: Tensor, den: Tensor, x: Tensor, sigma: Tensor, half: int
) -> tuple[Tensor, Tensor]:
    """Backward of `gaussian_render`: `(grad_x, grad_sigma)`."""
    grad_x, grad_sigma = torch.empty_like(x), torch.empty_like(sigma)
    _call("gs_render_backward", x, grad, y, den, x, sigma, grad_x, grad_sigma, *x.shape, half)
    return grad_x, grad_sigma


def clamp_render(
    x: Tensor, rho: Tensor, dist: Tensor, dists: Tensor, counts: Tensor, half: int
) -> tuple[Tensor, Tensor]:
    """Fused normalised clamped-distance scatter: `(y, den)`."""
    y, den = torch.empty_like(x), torch.empty_like(rho)
    _call("cl_render", x, x, rho, dist, dists, counts, dists.numel(), y, den, *x.shape, half)
    return y, den


def clamp_render_backward(
    grad: Tensor, y: Tensor, den: Tensor, x: Tensor, rho: Tensor, dist: Tensor, dists: Tensor,
    counts: Tensor, half: int,
) -> tuple[Tensor, Tensor]:
    """Backward of `clamp_render`: `(grad_x, grad_rho)`."""
    grad_x, grad_rho = torch.empty_like(x), torch.empty_like(rho)
    _call("cl_render_backward", x, grad, y, den, x, rho, dist, dists, counts, dists.numel(),
          grad_x, grad_rho, *x.shape, half)
    return grad_x, grad_rho


def layered_render(
    x: Tensor, pos: Tensor, param: Tensor, half: int, n_layers: int,
    clamp: tuple[Tensor, Tensor, Tensor] | None = None,
) -> tuple[Tensor, Tensor]:
    """Fused layered mode: `(out, spread)`; `clamp = (dist, dists, counts)` for the disk family.

    `spread` holds only the rows of the layers present near each row (see `window_layers` in
    `render_kernels.cpp`); the others are left unwritten."""
    b, c, h, w = x.shape
    out = torch.empty_like(x)
    spread = torch.empty(b, n_layers, c + 1, h, w, dtype=x.dtype)
    name, extra = _family("layered", clamp)
    _call(name, x, x, pos, param, *extra, spread, out, b, c, h, w, half, n_layers)
    return out, spread


def layered_render_backward(
    grad: Tensor, out: Tensor, spread: Tensor, x: Tensor, pos: Tensor, param: Tensor, half: int,
    n_layers: int, clamp: tuple[Tensor, Tensor, Tensor] | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Backward of `layered_render`: `(grad_x, grad_pos, grad_param)`."""
    grad_x, grad_pos, grad_param = torch.empty_like(x), torch.empty_like(pos), torch.empty_like(pos)
    name, extra = _family("layered_backward", clamp)
    _call(name, x, grad, out, spread, x, pos, param, *extra, grad_x, grad_pos, grad_param,
          *x.shape, half, n_layers)
    return grad_x, grad_pos, grad_param
