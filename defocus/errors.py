"""The errors a command reports in one line, and how it writes them.

The library raises `ValueError`, `TypeError`, `FileNotFoundError`, ... for bad input, with a
message that names the argument, the value and what is allowed; the command line reports those in
one line (exit code 2). `CommandError` is a problem with the command's own options.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator


class CommandError(Exception):
    """A problem with the user's input that a command reports in one line (exit code 2)."""


class OutputError(OSError):
    """An output file could not be written (a full disk, a read-only folder): nothing was
    replaced and no partial file is left (`defocus.app.outputs`)."""


#: Exceptions reported in one line: the library raises these for bad input, with a message that
#: names the argument, the value and what is allowed.
USER_ERRORS = (CommandError, ValueError, TypeError, FileNotFoundError, IsADirectoryError,
               PermissionError, NotADirectoryError, FileExistsError, FloatingPointError,
               OutputError)


def one_line(error: BaseException) -> str:
    """The message of `error` on one line.

    Example:
        >>> one_line(ValueError("two\\n  lines"))
        'two lines'
    """
    return " ".join(str(error).split())


@contextlib.contextmanager
def script_errors() -> Iterator[None]:
    """End a script (`examples/`) with one line for bad input: a `USER_ERRORS` exception
    raised inside becomes `SystemExit` with its message.

    Example:
        >>> with script_errors():
        ...     raise ValueError("--root: no such folder")
        Traceback (most recent call last):
        ...
        SystemExit: --root: no such folder
    """
    try:
        yield
    except USER_ERRORS as error:
        raise SystemExit(one_line(error)) from None
