"""The output policy of every command: nothing lost, nothing half written.

Every command that writes files (`predict`, `calibrate`, `evaluate --json`,
`convert-checkpoint`, `render`, `demo`, `sample`) plans its outputs with an `OutputPlan` before it starts
the work, and writes them through it:

1. An input is never written: an output that is one of the run's input files (or lies in an
   input folder such as a dataset's `--root` and exists there) is refused.
2. An existing result is never replaced unless the user says so (`--overwrite`); the message
   names the file and how to proceed.
3. Two outputs of one run never share a path (e.g. `calibrate --out fit.png` and its default
   figure `fit.png`).
4. Nothing is written through a symbolic link: an output path that is a link is refused.
5. Each file is written to a temporary name in its own folder and renamed over its path
   (`os.replace`) only once every output of the run is whole: a failure (a full disk, an
   interrupt) leaves the earlier files as they were and no half-written file behind.
6. A folder never mixes two runs: with `--overwrite`, an earlier run's file of one of the
   command's own output names that this run does not write (e.g. `confidence.png` of an
   earlier `predict` whose method now gives none) is removed once the new files are in place
   (`writing(remove_unwritten=True)`, reported in `OutputPlan.removed`); no other file is ever
   touched.

Example:
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> plan = OutputPlan(inputs={"--image": folder / "photo.png"})
    >>> path = plan.add(folder / "depth.txt", "depth")
    >>> with plan.writing() as write:
    ...     _ = write(path, lambda tmp: tmp.write_text("1.5"))
    >>> path.read_text()
    '1.5'
    >>> OutputPlan().add(path, "depth")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    FileExistsError: ...depth.txt already exists (an earlier depth); give --overwrite to replace it, or choose another output
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from defocus.errors import OutputError

#: writes one output at the temporary path it is given
Writer = Callable[[Path], Any]
#: input files or folders by the name the user gave them: a mapping or `(name, path)` pairs
Inputs = Mapping[str, "Path | None"] | Iterable[tuple[str, "Path | None"]]


def _pairs(inputs: Inputs | None) -> list[tuple[str, Path]]:
    items = inputs.items() if isinstance(inputs, Mapping) else (inputs or ())
    return [(name, Path(path)) for name, path in items if path is not None]


def _resolved(path: Path) -> Path:
    return Path(os.path.abspath(path)).resolve()


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.relative_to(folder)
    except ValueError:
        return False
    return True


class OutputPlan:
    """The files one run writes, checked against the policy (module docstring) as they are
    added, and written atomically by `writing`.

    Args:
        inputs: the run's input files by the name the user gave them (`"--image"`, `"SOURCE"`,
            ...), a mapping or `(name, path)` pairs; None paths are skipped.
        input_folders: input folders (a dataset's `--root`) whose existing files are inputs.
        overwrite: replace earlier results (`--overwrite`).
        how: what to say besides `--overwrite` (e.g. `"or choose another --out"`).
    """

    def __init__(self, inputs: Inputs | None = None, input_folders: Inputs | None = None,
                 overwrite: bool = False, how: str = "or choose another output") -> None:
        self.inputs = _pairs(inputs)
        self.input_folders = [(name, _resolved(p)) for name, p in _pairs(input_folders)]
        self.overwrite = bool(overwrite)
        self.how = how
        self.outputs: dict[Path, tuple[Path, str]] = {}
        #: planned outputs that held an earlier result when they were planned
        self.earlier: set[Path] = set()
        #: earlier results removed by `writing(remove_unwritten=True)`
        self.removed: list[Path] = []

    def add(self, path: Path | str, what: str) -> Path:
        """Check that `path` may receive output `what` and plan it; returns `path`.

        Raises:
            ValueError: `path` is an input, another output of this run, or a symbolic link.
            FileExistsError: `path` holds an earlier result and `overwrite` is off.
            IsADirectoryError: `path` is a folder.
        """
        path = Path(path)
        resolved = _resolved(path)
        refusal = self._refusal(path, resolved, what)
        if refusal is not None:
            raise refusal
        self.outputs[resolved] = (path, what)
        if path.exists():
            self.earlier.add(resolved)
        return path

    def _refusal(self, path: Path, resolved: Path, what: str) -> OSError | ValueError | None:
        """Why `path` may not receive output `what` (the error to raise), or None."""
        for name, given in self.inputs:
            same = resolved == _resolved(given)
            if not same and path.exists() and given.exists():
                with contextlib.suppress(OSError):
                    same = os.path.samefile(path, given)
            if same:
                return ValueError(f"the {what} would be written to {path}, which is the input "
                                  f"{name} {given}: an input is never written; choose another "
                                  "output")
        for name, folder in self.input_folders:
            if path.exists() and _inside(resolved, folder):
                return ValueError(f"the {what} would be written to {path}, an existing file of "
                                  f"the input {name} {folder}: an input is never written; "
                                  "choose an output outside it")
        if resolved in self.outputs:
            return ValueError(f"the {what} and the {self.outputs[resolved][1]} would both be "
                              f"written to {path}; give them different paths")
        if path.is_symlink():
            return ValueError(f"{path} is a symbolic link (to {os.readlink(path)}); outputs are "
                              "never written through a link: remove it or choose another output")
        if path.is_dir():
            return IsADirectoryError(f"the {what} would be written to {path}, which is a folder; "
                                     "choose another output")
        if path.exists() and not self.overwrite:
            return FileExistsError(f"{path} already exists (an earlier {what}); give --overwrite "
                                   f"to replace it, {self.how}")
        return None

    @contextlib.contextmanager
    def writing(self, remove_unwritten: bool = False) -> Iterator[Callable[[Path, Writer], Path]]:
        """A context that gives `write(path, writer)`: `writer` writes a planned output at a
        temporary path beside it (same suffix); on leaving the context every output is
        renamed over its path, and on an error every temporary file is removed.

        Args:
            remove_unwritten: once every output is in place, also remove the planned outputs
                that held an earlier result (replaced under `overwrite`) and that this run did
                not write, so that the folder holds one run (policy 6); they are listed in
                `removed`. Only planned paths are ever removed.
        """
        staged: list[tuple[Path, Path]] = []

        def write(path: Path, writer: Writer) -> Path:
            path = Path(path)
            if _resolved(path) not in self.outputs:
                raise ValueError(f"{path} was not planned as an output of this run")
            temporary = path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")
            staged.append((temporary, path))
            _guarded(path, lambda: (path.parent.mkdir(parents=True, exist_ok=True),
                                    writer(temporary)))
            return path

        try:
            yield write
            for temporary, path in staged:
                _guarded(path, lambda t=temporary, p=path: os.replace(t, p))
            if remove_unwritten:
                self._remove_unwritten({_resolved(path) for _, path in staged})
        finally:
            for temporary, _ in staged:
                with contextlib.suppress(OSError):
                    temporary.unlink()

    def _remove_unwritten(self, written: set[Path]) -> None:
        """Remove the earlier results among the planned outputs that are not in `written`."""
        for resolved in sorted(self.earlier - written):
            path = self.outputs[resolved][0]
            if path.is_symlink() or path.is_file():  # a link itself, never what it points to
                _guarded(path, lambda p=path: p.unlink(missing_ok=True))
                self.removed.append(path)


def _guarded(path: Path, action: Callable[[], Any]) -> None:
    """Run `action` (writing `path`); an operating-system error becomes one line that names
    `path` (`OutputError`, or `PermissionError` for a folder one may not write in)."""
    try:
        action()
    except PermissionError as error:
        raise PermissionError(f"cannot write {path}: permission denied "
                              f"({error.strerror or error}); choose another output folder") from None
    except OSError as error:
        if isinstance(error, (FileNotFoundError, IsADirectoryError, NotADirectoryError)) or \
                error.errno in (errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO):
            raise OutputError(f"cannot write {path}: {error.strerror or error}; nothing was "
                              "replaced and no partial file is left") from None
        raise


def plan_files(folder: Path, names: Mapping[str, str], overwrite: bool,
               inputs: Inputs | None = None,
               option: str = "--out") -> tuple[OutputPlan, dict[str, Path]]:
    """An `OutputPlan` of the files `names` (file name -> what it holds) in `folder`, and
    their paths by file name.

    Example:
        >>> import tempfile
        >>> plan, paths = plan_files(Path(tempfile.mkdtemp()), {"a.json": "metrics"}, False)
        >>> sorted(paths)
        ['a.json']
    """
    plan = OutputPlan(inputs, overwrite=overwrite, how=f"or choose another {option}")
    if folder.exists() and not folder.is_dir():
        raise NotADirectoryError(f"{option} {folder} is a file, not a folder")
    return plan, {name: plan.add(folder / name, what) for name, what in names.items()}


@contextlib.contextmanager
def creating_folder(folder: Path | str, option: str = "--out") -> Iterator[Path]:
    """Create the output `folder` and its missing parents before the work (a folder that
    cannot be created is refused at once, in one line naming `option`, the folder and why);
    on an error inside the context, the folders this created are removed again where still
    empty, so that a failed run leaves nothing behind.

    Example:
        >>> import tempfile
        >>> base = Path(tempfile.mkdtemp())
        >>> with creating_folder(base / "a" / "b") as folder:
        ...     folder.is_dir()
        True
        >>> (base / "file").write_text("x") and None
        >>> with creating_folder(base / "file" / "b", "FOLDER"):  # doctest: +ELLIPSIS
        ...     pass
        Traceback (most recent call last):
        ...
        NotADirectoryError: FOLDER .../file/b cannot be created: .../file is a file, not a folder; choose another FOLDER
    """
    folder = Path(folder)
    missing: list[Path] = []  # deepest first
    base = folder
    while not (base.exists() or base.is_symlink()) and base.parent != base:
        missing.append(base)
        base = base.parent
    if base.exists() and not base.is_dir():
        what = "is a file, not a folder" if base == folder else \
            f"cannot be created: {base} is a file, not a folder"
        raise NotADirectoryError(f"{option} {folder} {what}; choose another {option}")

    def remove_created() -> None:
        for path in missing:
            with contextlib.suppress(OSError):
                path.rmdir()

    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        remove_created()
        raise OutputError(f"{option} {folder} cannot be created in {base}: "
                          f"{error.strerror or error}; choose another {option}") from None
    try:
        yield folder
    except BaseException:
        remove_created()
        raise


def check_output_folder(folder: Path | str, option: str = "--out",
                        input_folders: Inputs | None = None) -> Path:
    """Refuse an output folder (a command's own folder, e.g. a training run's) that is a file,
    a symbolic link, or an input folder (`--root`) or a folder inside one; returns `folder`.

    Example:
        >>> check_output_folder(Path("data/run"), "--out", {"--root": Path("data")})
        Traceback (most recent call last):
        ...
        ValueError: --out data/run lies inside the input --root data: a run never writes into its input; choose an --out outside it
    """
    folder = Path(folder)
    resolved = _resolved(folder)
    inside = next(((name, given) for name, given in _pairs(input_folders)
                   if _inside(resolved, _resolved(given))), None)
    refusal = (
        ValueError(f"{option} {folder} is a symbolic link (to {os.readlink(folder)}); outputs "
                   f"are never written through a link: choose another {option}")
        if folder.is_symlink() else
        NotADirectoryError(f"{option} {folder} is a file, not a folder; choose another {option}")
        if folder.exists() and not folder.is_dir() else
        ValueError(f"{option} {folder} {'is' if resolved == _resolved(inside[1]) else 'lies inside'}"
                   f" the input {inside[0]} {inside[1]}: a run never writes into its input; "
                   f"choose an {option} outside it")
        if inside is not None else None)
    if refusal is not None:
        raise refusal
    return folder


def plan_json(path: Path | None, overwrite: bool, inputs: Inputs | None = None,
              input_folders: Inputs | None = None, what: str = "metrics JSON",
              option: str = "--json") -> OutputPlan | None:
    """The checked plan of one JSON output `path` (an option such as `--json`), None without
    one: not an input nor an existing file of an input folder, no earlier result replaced
    without `overwrite`.

    Example:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "metrics.json"
        >>> write_json(plan_json(path, overwrite=False), path, {"abs_rel": 0.1})
        >>> plan_json(path, overwrite=False)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        FileExistsError: ...metrics.json already exists (an earlier metrics JSON); give --overwrite to replace it, or choose another --json
    """
    if path is None:
        return None
    plan = OutputPlan(inputs, input_folders, overwrite, how=f"or choose another {option}")
    plan.add(path, what)
    return plan


def write_json(plan: OutputPlan, path: Path, data: Any) -> None:
    """Write `data` as JSON at `path`, whole or not at all, through `plan` (`plan_json`)."""
    text = json.dumps(data, indent=2)
    with plan.writing() as write:
        write(path, lambda tmp: tmp.write_text(text))
