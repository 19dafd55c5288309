"""The compiled kernels' cache folder and the checks made before loading them (optics.cache,
optics.render.cpp)."""

import os
import shutil
import stat
import warnings
from pathlib import Path

import pytest
import torch

from optics import Disk, render_defocus
from optics.cache import cache_root, is_private_dir, user_cache_dir
from optics.render import cpp as _render_cpp

needs_library = pytest.mark.skipif(
    _render_cpp.library() is None, reason="no C++ compiler (or DEFOCUS_NO_CPP set)"
)


@pytest.fixture
def private_cache(tmp_path, monkeypatch):
    """A fresh cache root holding a copy of the built kernel library; the real one afterwards.

    Only for tests marked `needs_library`.
    """
    current = Path(_render_cpp.library()._name)  # the library of this source, flags and CPU
    root = tmp_path / "cache"
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(root))
    kernels = root / _render_cpp.KERNEL_SUBDIR
    kernels.mkdir(parents=True, mode=0o700)
    os.chmod(root, 0o700)
    for path in (current, current.with_name(current.name + ".sha256")):
        shutil.copy2(path, kernels / path.name)
    _render_cpp.reset()
    yield kernels
    monkeypatch.undo()
    _render_cpp.reset()


def _render_pair():
    torch.manual_seed(0)
    image = torch.rand(1, 3, 12, 13, dtype=torch.float64)
    coc = torch.rand(1, 1, 12, 13, dtype=torch.float64) * 5
    return image, coc


def _pure_reference(monkeypatch):
    image, coc = _render_pair()
    with monkeypatch.context() as patch:
        patch.setattr(_render_cpp, "usable", lambda x: False)
        return render_defocus(image, coc, Disk())


def test_cache_root_follows_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(tmp_path / "mine"))
    assert cache_root() == tmp_path / "mine"
    assert user_cache_dir("kernels") == tmp_path / "mine" / "kernels"
    monkeypatch.delenv("DEFOCUS_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_root() == tmp_path / "xdg" / "defocus"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_root() == tmp_path / "home" / ".cache" / "defocus"
    assert Path.cwd() not in [cache_root(), *cache_root().parents][:1]


def test_user_cache_dir_rejects_escaping_parts(monkeypatch, tmp_path):
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(tmp_path))
    for bad in ("..", "/etc", "", "a/../../b"):
        with pytest.raises(ValueError, match="user_cache_dir parts"):
            user_cache_dir(bad)
    folder = user_cache_dir("datasets", "nyu", create=True)
    assert folder.is_dir() and stat.S_IMODE(folder.stat().st_mode) == 0o700


def test_is_private_dir_flags_group_and_other_writable(tmp_path):
    root = tmp_path / "root"
    inner = root / "kernels"
    inner.mkdir(parents=True)
    os.chmod(root, 0o700)
    os.chmod(inner, 0o700)
    assert is_private_dir(inner, root) == (True, "")
    for mode in (0o702, 0o720):
        os.chmod(root, mode)
        ok, why = is_private_dir(inner, root)
        assert not ok and str(root) in why and "writable by group or others" in why
    os.chmod(root, 0o700)
    assert not is_private_dir(tmp_path, root)[0]  # outside the root


@needs_library
def test_library_is_built_in_the_user_cache_with_a_sha256_sidecar():
    folder = _render_cpp.kernel_dir()
    library = Path(_render_cpp.library()._name)
    assert library.parent == folder and folder == cache_root() / "kernels"
    sidecar = library.with_name(library.name + ".sha256")
    assert sidecar.read_text().strip() == _render_cpp._sha256(library)
    repo = Path(__file__).resolve().parents[1]
    assert repo not in library.parents and Path.cwd() not in library.parents


@needs_library
@pytest.mark.parametrize("mode", [0o702, 0o720])
def test_library_in_a_folder_writable_by_others_is_not_loaded(private_cache, monkeypatch, mode):
    expected = _pure_reference(monkeypatch)
    os.chmod(private_cache, mode)
    with pytest.warns(RuntimeWarning, match="writable by group or others"):
        assert _render_cpp.library() is None
    assert not _render_cpp.usable(torch.zeros(1))
    image, coc = _render_pair()
    torch.testing.assert_close(render_defocus(image, coc, Disk()), expected)
    os.chmod(private_cache, 0o700)


@needs_library
def test_parent_folder_writable_by_others_is_refused(private_cache):
    os.chmod(private_cache.parent, 0o777)
    with pytest.warns(RuntimeWarning, match=str(private_cache.parent)):
        assert _render_cpp.library() is None
    os.chmod(private_cache.parent, 0o700)


@needs_library
def test_tampered_library_is_not_loaded(private_cache, monkeypatch):
    expected = _pure_reference(monkeypatch)
    libraries = sorted(private_cache.glob("render_kernels_*.so"))
    assert libraries
    for library in libraries:
        with library.open("ab") as stream:
            stream.write(b"\0tampered")
    builds = []
    monkeypatch.setattr(_render_cpp, "_compile", lambda *args: builds.append(args) or False)
    with pytest.warns(RuntimeWarning, match="sha256"):
        assert _render_cpp.library() is None
    assert builds  # a rebuild was attempted instead of loading the tampered file
    image, coc = _render_pair()
    torch.testing.assert_close(render_defocus(image, coc, Disk()), expected)


@needs_library
def test_tampered_library_is_rebuilt(private_cache):
    library = sorted(private_cache.glob("render_kernels_*.so"))[0]
    with library.open("ab") as stream:
        stream.write(b"\0tampered")
    with pytest.warns(RuntimeWarning, match="sha256"):
        loaded = _render_cpp.library()
    assert loaded is not None
    rebuilt = Path(loaded._name)
    assert rebuilt.read_bytes()[-9:] != b"\0tampered"
    assert _render_cpp._verified(rebuilt) == (True, "")


@needs_library
def test_library_file_writable_by_group_is_not_loaded(private_cache, monkeypatch):
    for library in private_cache.glob("render_kernels_*.so"):
        os.chmod(library, 0o770)
    monkeypatch.setattr(_render_cpp, "_compile", lambda *args: False)
    with pytest.warns(RuntimeWarning, match="writable by group or others"):
        assert _render_cpp.library() is None


def test_warning_is_given_once(tmp_path, monkeypatch):
    root = tmp_path / "open"
    (root / "kernels").mkdir(parents=True)
    os.chmod(root, 0o777)
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(root))
    monkeypatch.setattr(_render_cpp, "_compiler", lambda: "c++")
    _render_cpp.reset()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            assert _render_cpp._build() is None
            assert _render_cpp._build() is None
        assert len([w for w in caught if "not loading" in str(w.message)]) == 1
    finally:
        monkeypatch.undo()
        _render_cpp.reset()


def test_no_cpp_environment_forces_the_pure_path(monkeypatch):
    monkeypatch.setenv("DEFOCUS_NO_CPP", "1")
    _render_cpp.reset()
    try:
        assert _render_cpp.library() is None
    finally:
        monkeypatch.undo()
        _render_cpp.reset()


def test_cache_root_and_its_parents_are_created_private(tmp_path, monkeypatch):
    root = tmp_path / "deep" / "er" / "cache"
    monkeypatch.setenv("DEFOCUS_CACHE_DIR", str(root))
    _render_cpp._make_private_dirs(_render_cpp.kernel_dir(), cache_root())
    assert is_private_dir(_render_cpp.kernel_dir(), root) == (True, "")
    assert stat.S_IMODE(root.stat().st_mode) == 0o700
