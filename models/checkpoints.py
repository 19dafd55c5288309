"""Checkpoint files that hold only tensors and plain data, and a folder of them.

Opening a checkpoint never runs code: every load uses `torch.load(..., weights_only=True)`, whose
unpickler builds tensors, `dict`, `list`, `tuple`, `str`, numbers, `bool` and `None` and refuses
anything else (an object whose pickle names a function or a class, such as `os.system`). A refused
file raises `CheckpointError` (a `ValueError`) with one line that names the file; nothing in the
file has run by then.

A checkpoint written by the `Trainer` is a `dict` of:

- `model`, `optimizer`, `scheduler`: state dicts as PyTorch writes them (tensors and plain data);
- `step`: an `int`; `config`: the `TrainConfig` as a dict of primitives (`out_dir` a `str`);
- `history`: a list of dicts of floats; `rng`: the global random states as `uint8` tensors;
- `format`: `CHECKPOINT_FORMAT`.

Files written by earlier versions load when they already hold only those types. A file that
holds other objects (an older or foreign file) can be converted with `convert_checkpoint` or the
command `defocus convert-checkpoint --trust OLD NEW`, which unpickles it with code execution:
only for files you trust.

Example:
    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> store = CheckpointStore(folder, keep=1)
    >>> _ = store.save({"model": {"w": torch.ones(2)}, "step": 3, "config": {}}, step=3)
    >>> sorted(p.name for p in folder.iterdir())
    ['last.pt', 'step_000003.pt']
    >>> load_checkpoint(store.last)["step"]
    3
"""

from __future__ import annotations

import dataclasses
import datetime
import enum
import io
import os
import pickle
import re
import zipfile
from collections import OrderedDict
from collections.abc import Mapping
from pathlib import Path, PurePath
from typing import Any

import torch
from torch import Tensor

#: version of the checkpoint layout written by `CheckpointStore` (files without it are older)
CHECKPOINT_FORMAT = 2

#: the command that converts a trusted file (printed in refusals)
CONVERT_HINT = ("if you trust this file, convert it with `defocus convert-checkpoint --trust "
                "{path} NEW.pt` (that runs whatever the file holds)")


class CheckpointError(ValueError):
    """A file that is not a checkpoint, or one refused because it holds more than tensors and
    plain data. The message is one line and names the file."""


#: the `kind` of a weights file of the camera-general network (`models.loading.save_weights`)
WEIGHTS_KIND = "DepthFromDefocus"
_LOAD_ERRORS = (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, TypeError,
                AttributeError, ImportError, IndexError, KeyError, zipfile.BadZipFile,
                UnicodeDecodeError)


def _refusal(path: Path, error: Exception, after: str = "") -> CheckpointError:
    """The one-line error for a file that `torch.load` did not open (`after` ends it)."""
    text = str(error)
    if isinstance(error, ImportError | AttributeError):  # a class or module the file names
        return CheckpointError(f"{path} could not be unpickled: {type(error).__name__}: "
                               f"{' '.join(text.split())[:120]} (the code that wrote it must "
                               f"be importable){after}")
    found = re.search(r"GLOBAL ([\w.]+)", text)
    if found:
        return CheckpointError(
            f"refused to open checkpoint {path}: it holds a Python object ({found.group(1)}) "
            "besides tensors and plain data, and loading it could run code, so nothing in it "
            f"was run; {CONVERT_HINT.format(path=path)}{after}")
    detail = re.search(r"Unsupported operand \d+|invalid load key[^.\n]*", text)
    if detail:
        reason = f"neither a zip archive nor a pickle: {detail.group(0)}"
    elif isinstance(error, EOFError):
        reason = "empty or truncated"
    elif isinstance(error, KeyError | IndexError) or "Memo value not found" in text:
        reason = "neither a zip archive nor a pickle (text or another format?)"
    else:
        reason = re.split(r"(?<=\.)\s", " ".join(text.split()))[0].rstrip(".")[:120]
    reason = reason or type(error).__name__
    return CheckpointError(f"{path} is not a readable PyTorch checkpoint ({reason}){after}")


def _read(path: Path, map_location: Any, weights_only: bool = True, mmap: bool = False,
          after: str = "") -> dict[str, Any]:
    """`torch.load` of a checkpoint or weights file, refused in one line naming it (`after`
    ends each refusal)."""
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist or is not a file")
    try:
        state = torch.load(path, map_location=map_location, weights_only=weights_only, mmap=mmap)
    except _LOAD_ERRORS as error:
        raise _refusal(path, error, after) from None
    if not isinstance(state, Mapping) or not (state.get("kind") == WEIGHTS_KIND or {
            "model", "config"} <= set(state) and isinstance(state["config"], Mapping)):
        found = (f"its keys are {sorted(map(str, state))[:6]}" if isinstance(state, Mapping)
                 else f"it holds a {type(state).__name__}")
        raise CheckpointError(f"{path} is not a defocus checkpoint (a dict with 'model' and "
                              f"'config' entries; {found}){after}")
    return dict(state)


def load_checkpoint(path: str | Path, map_location: Any = "cpu",
                    mmap: bool = False) -> dict[str, Any]:
    """Read a model file without running any code (`weights_only=True`): the one loader of
    training checkpoints and weights files (`models.loading` builds models from what it reads).

    Args:
        path: a `.pt` file written by `CheckpointStore`, `save_checkpoint` or
            `models.loading.save_weights`.
        map_location: where tensors go, as for `torch.load`.
        mmap: memory-map the file instead of reading its tensors (a zip archive only).

    Returns:
        the checkpoint `dict`: at least `model` and `config` (a mapping), or a weights file's
        (`kind` `WEIGHTS_KIND`).

    Raises:
        FileNotFoundError: no such file.
        CheckpointError: the file is not a checkpoint, or holds objects other than tensors and
            plain data (refused; nothing in it runs).
    """
    return _read(Path(path), map_location, mmap=mmap)


def restore_weights(module: torch.nn.Module, weights: Mapping[str, Tensor],
                    source: str | Path) -> None:
    """`module.load_state_dict(weights)`, refused in one line when the weights of checkpoint
    `source` do not fit the network its config builds (a hand-edited file, or one of another
    version).

    Raises:
        CheckpointError: naming the missing and unexpected weights and those of another shape.

    Example:
        >>> restore_weights(torch.nn.Linear(2, 3), {"weight": torch.zeros(3, 3)}, "a.pt")
        Traceback (most recent call last):
        ...
        models.checkpoints.CheckpointError: a.pt: its weights do not fit the network its config builds: missing ['bias']; other shapes: weight (3, 3) in the file, (3, 2) in the network
    """
    try:
        module.load_state_dict(weights)
    except RuntimeError:
        mismatch = _weights_mismatch(module, weights)
        if mismatch is None:
            raise
        raise CheckpointError(f"{source}: its weights do not fit the network its config "
                              f"builds: {mismatch}") from None


def _weights_mismatch(module: torch.nn.Module, weights: Mapping[str, Tensor]) -> str | None:
    """The weights missing from `weights`, unexpected in it, or of another shape than
    `module`'s, in words; None where names and shapes all agree."""
    own = module.state_dict()
    missing = sorted(set(own) - set(weights))
    unexpected = sorted(set(weights) - set(own))
    shapes = [f"{name} {tuple(weights[name].shape)} in the file, {tuple(own[name].shape)} in "
              "the network" for name in own if name in weights
              and isinstance(weights[name], Tensor) and weights[name].shape != own[name].shape]
    parts = [f"missing {missing[:4]}" * bool(missing),
             f"unexpected {unexpected[:4]}" * bool(unexpected),
             f"other shapes: {', '.join(shapes[:3])}" * bool(shapes)]
    return "; ".join(p for p in parts if p) or None


def _atomic_write(data: bytes, target: Path) -> None:
    """Write `data` to a temporary file next to `target`, then rename it over `target`
    (`os.replace`), so that a reader never sees a partly written file."""
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        with tmp.open("wb") as file:
            file.write(data)
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def serialize(state: Mapping[str, Any]) -> bytes:
    """The bytes of `torch.save(state)`, after checking that it holds only plain data."""
    check_plain(state)
    buffer = io.BytesIO()
    torch.save(dict(state), buffer)
    return buffer.getvalue()


def save_checkpoint(state: Mapping[str, Any], path: str | Path) -> Path:
    """Write a checkpoint atomically (temporary file + `os.replace`); returns `path`."""
    path = Path(path)
    _make_parent(path)
    _atomic_write(serialize(state), path)
    return path


_PLAIN_SCALARS = (str, int, float, bool, complex, type(None), torch.dtype, torch.device,
                  torch.Size)


def check_plain(value: Any, where: str = "checkpoint") -> None:
    """Raise `ValueError` unless `value` is made of tensors and plain data only (exact types:
    a numpy float, a subclass of `float`, is not plain data)."""
    kind = type(value)
    if kind in (Tensor, torch.nn.Parameter) or kind in _PLAIN_SCALARS:
        return
    if kind in (dict, OrderedDict):
        for key, item in value.items():
            check_plain(key, f"{where} key")
            check_plain(item, f"{where}[{key!r}]")
        return
    if kind in (list, tuple):
        for i, item in enumerate(value):
            check_plain(item, f"{where}[{i}]")
        return
    raise ValueError(f"{where} holds a {kind.__module__}.{kind.__qualname__}, not a tensor or "
                     "plain data")


def to_plain(value: Any, where: str = "checkpoint") -> Any:
    """A copy of `value` made of tensors and plain data: paths become `str`, numpy arrays and
    parameters tensors, numpy scalars numbers, dates ISO strings, sets sorted lists,
    dataclasses dicts.

    Raises:
        ValueError: a value of another type (named with its place in `value`).
    """
    import numpy as np

    if isinstance(value, Tensor):
        return value if type(value) is Tensor else value.detach().as_subclass(Tensor).clone()
    if isinstance(value, np.ndarray):
        return torch.from_numpy(np.array(value))
    if isinstance(value, np.generic):
        return value.item()
    if type(value) in _PLAIN_SCALARS:
        return value
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, datetime.date | datetime.time):
        return value.isoformat()
    if isinstance(value, enum.Enum):
        return to_plain(value.value, where)
    for kind in (bool, int, float, complex, str):  # other subclasses
        if isinstance(value, kind):
            return kind(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        to_dict = getattr(value, "to_dict", None)
        return to_plain(to_dict() if callable(to_dict) else dataclasses.asdict(value), where)
    if isinstance(value, Mapping):
        kind = OrderedDict if isinstance(value, OrderedDict) else dict
        return kind((to_plain(k, f"{where} key"), to_plain(v, f"{where}[{k!r}]"))
                    for k, v in value.items())
    if isinstance(value, set | frozenset):
        items = [to_plain(v, where) for v in value]
        try:
            return sorted(items)
        except TypeError:
            return items
    if isinstance(value, list | tuple):
        items = [to_plain(v, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if isinstance(value, tuple) else items
    raise ValueError(f"cannot convert {where}: a {type(value).__module__}."
                     f"{type(value).__qualname__} is not a tensor or plain data")


def convert_checkpoint(source: str | Path, target: str | Path) -> Path:
    """Rewrite a trusted checkpoint so that it opens with `weights_only=True`.

    Warning:
        This unpickles `source` with `weights_only=False`, which runs whatever code the file
        holds. Use it only on files you wrote yourself or whose author you trust.

    Returns:
        `target`, written atomically and checked by reading it back safely.
    """
    source, target = Path(source), Path(target)
    state = _read(source, "cpu", weights_only=False,
                  after=f"; nothing written: {target} is left as it was")
    data = serialize(to_plain(state, str(source)))
    # checked at a temporary name beside target: a failed conversion leaves target as it was
    _make_parent(target)
    checked = target.with_name(f".{target.name}.{os.getpid()}.converted")
    try:
        _atomic_write(data, checked)
        load_checkpoint(checked)
        os.replace(checked, target)
    except CheckpointError as error:
        reason = str(error).replace(str(checked), str(target))
        raise CheckpointError(f"converting {source} did not give a safe checkpoint: "
                              f"{reason}; {target} is left as it was") from None
    finally:
        checked.unlink(missing_ok=True)
    return target


def file_in_the_way(folder: str | Path) -> Path | None:
    """The file (or broken link) at `folder` or at a folder above it, which stops `folder` from
    being a folder; None where there is none.

    Example:
        >>> import tempfile
        >>> file = Path(tempfile.mkdtemp()) / "notes.txt"
        >>> _ = file.write_text("x")
        >>> file_in_the_way(file / "run" / "checkpoints") == file, file_in_the_way(file.parent)
        (True, None)
    """
    folder = Path(folder)
    for path in (folder, *folder.parents):
        if path.exists() or path.is_symlink():
            return None if path.is_dir() else path
    return None


def _make_parent(target: Path) -> None:
    """Create the folder of `target`, or raise `NotADirectoryError` naming the file in the way."""
    blocker = file_in_the_way(target.parent)
    if blocker is not None:
        raise NotADirectoryError(f"cannot write {target}: {blocker} is a file, not a folder; "
                                 "choose another path")
    target.parent.mkdir(parents=True, exist_ok=True)


class CheckpointStore:
    """The checkpoints of one run: `step_XXXXXX.pt` files and `last.pt` in one folder.

    Args:
        directory: the folder (created on the first save).
        keep: keep only the newest `keep` step files after each save (0: keep all);
            `last.pt` is always kept.
    """

    def __init__(self, directory: str | Path, keep: int = 0):
        self.directory = Path(directory)
        self.keep = int(keep)

    @property
    def last(self) -> Path:
        """Path of `last.pt` (which may not exist yet)."""
        return self.directory / "last.pt"

    def path(self, step: int) -> Path:
        """Path of the checkpoint of `step`."""
        return self.directory / f"step_{int(step):06d}.pt"

    def exists(self) -> bool:
        """Whether `last.pt` exists (a run to resume)."""
        return self.last.is_file()

    def save(self, state: Mapping[str, Any], step: int) -> Path:
        """Write `state` as the step file and as `last.pt` (each atomically), then prune.

        Returns:
            the path of `last.pt`.
        """
        self.directory.mkdir(parents=True, exist_ok=True)
        data = serialize(state)
        _atomic_write(data, self.path(step))
        _atomic_write(data, self.last)
        self.prune()
        return self.last

    def load(self, path: str | Path | None = None, map_location: Any = "cpu") -> dict[str, Any]:
        """Read `path` (default `last.pt`) safely, see `load_checkpoint`."""
        return load_checkpoint(self.last if path is None else path, map_location)

    def remove_temporaries(self) -> list[Path]:
        """Delete temporary files that an interrupted save left behind (call it only while
        no save is under way); returns them."""
        stray = sorted(self.directory.glob(".*.tmp")) if self.directory.is_dir() else []
        for path in stray:
            path.unlink(missing_ok=True)
        return stray

    def list(self) -> list[Path]:
        """The step files, oldest first."""
        if not self.directory.is_dir():
            return []
        return sorted(self.directory.glob("step_[0-9]*.pt"))

    def prune(self, keep: int | None = None) -> list[Path]:
        """Delete all but the newest `keep` (default `self.keep`; 0: none) step files.

        Returns:
            the deleted paths.
        """
        keep = self.keep if keep is None else int(keep)
        if keep <= 0:
            return []
        removed = self.list()[:-keep]
        for path in removed:
            path.unlink(missing_ok=True)
        return removed


__all__ = ["CHECKPOINT_FORMAT", "WEIGHTS_KIND", "CheckpointError", "CheckpointStore", "check_plain",
           "convert_checkpoint", "load_checkpoint", "save_checkpoint", "to_plain"]
