"""Per-user cache folder of Defocus (compiled kernels, and anything else worth keeping).

The root is `$DEFOCUS_CACHE_DIR` when set, else `$XDG_CACHE_HOME/defocus`, else
`~/.cache/defocus`. It is never the working directory, the package's folder or the shared
temporary folder, so that nothing another user can write ends up loaded as code.

Example:
    >>> folder = user_cache_dir("kernels")
    >>> folder.name, folder.parent == cache_root()
    ('kernels', True)
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = ["cache_root", "is_private_dir", "user_cache_dir"]


def cache_root() -> Path:
    """The root of the per-user cache (not created).

    Returns:
        `$DEFOCUS_CACHE_DIR`, else `$XDG_CACHE_HOME/defocus`, else `~/.cache/defocus`, as an
        absolute path.
    """
    override = os.environ.get("DEFOCUS_CACHE_DIR")
    if override:
        return Path(override).expanduser().absolute()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg and Path(xdg).expanduser().is_absolute() else (
        Path.home() / ".cache"
    )
    return (base / "defocus").absolute()


def user_cache_dir(*parts: str, create: bool = False) -> Path:
    """A folder inside the per-user cache, e.g. `user_cache_dir("kernels")`.

    Args:
        *parts: path components below the cache root; each a plain name (no `..`, no separators
            that leave the root).
        create: make the folder (and the root) with mode `0o700` when missing.

    Returns:
        The folder's absolute path.

    Raises:
        ValueError: if a part is empty, absolute or climbs out of the root with `..`.

    Example:
        >>> user_cache_dir("datasets", "nyu").parts[-2:]
        ('datasets', 'nyu')
    """
    root = cache_root()
    for part in parts:
        if not isinstance(part, str) or not part or Path(part).is_absolute() or ".." in Path(
            part
        ).parts:
            raise ValueError(
                f"user_cache_dir parts must be non-empty relative names without '..', got {part!r}"
            )
    folder = root.joinpath(*parts)
    if create:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    return folder


def is_private_dir(folder: Path, root: Path | None = None) -> tuple[bool, str]:
    """Whether `folder` and its parents up to `root` are owned by this user and not writable by others.

    Args:
        folder: the folder to check.
        root: the highest folder checked (inclusive); the cache root by default. `folder` must
            be inside it.

    Returns:
        `(True, "")` when safe, else `(False, reason)` naming the offending path.
    """
    root = (cache_root() if root is None else Path(root)).absolute()
    folder = Path(folder).absolute()
    if folder != root and root not in folder.parents:
        return False, f"{folder} is not inside the cache root {root}"
    uid = os.getuid() if hasattr(os, "getuid") else None
    current = folder
    while True:
        try:
            info = current.lstat()
        except OSError as error:
            return False, f"cannot stat {current}: {error}"
        if stat.S_ISLNK(info.st_mode):
            return False, f"{current} is a symbolic link"
        if uid is not None and info.st_uid != uid:
            return False, f"{current} is owned by uid {info.st_uid}, not the current user ({uid})"
        if info.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
            return False, f"{current} is writable by group or others (mode {oct(info.st_mode & 0o777)})"
        if current == root:
            return True, ""
        current = current.parent
