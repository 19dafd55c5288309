"""Progress bars that suit where they are written.

On a terminal a bar redraws live. Written to a file, a pipe or a CI log, every redraw would be one
more line (carriage returns that most log viewers show as lines), so there a bar writes at most
one update every `LOG_INTERVAL_S` seconds, and none for work shorter than that. tqdm does both
through its own options (`mininterval`, `miniters`); this only chooses them.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any, TextIO

from tqdm.auto import tqdm

#: Seconds between two updates of a bar that is not written to a terminal.
LOG_INTERVAL_S = 30.0


def writes_to_terminal(stream: TextIO | None = None) -> bool:
    """Whether `stream` (standard error by default, where bars go) is a terminal.

    Example:
        >>> import io
        >>> writes_to_terminal(io.StringIO())
        False
    """
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False


def progress_bar(iterable: Iterable[Any] | None = None, **options: Any) -> tqdm:
    """`tqdm(iterable, **options)`, live on a terminal and at most one line every
    `LOG_INTERVAL_S` seconds elsewhere (see the module docstring). `disable=True` hides it.

    Example:
        >>> import io
        >>> log = io.StringIO()
        >>> total = sum(progress_bar(range(1000), desc="work", file=log))
        >>> log.getvalue().count("\\r") <= 2  # the first and the last update only
        True
    """
    if not writes_to_terminal(options.get("file")):
        options.setdefault("mininterval", LOG_INTERVAL_S)
        options.setdefault("maxinterval", LOG_INTERVAL_S)
        # redraw decisions by time only (tqdm's dynamic miniters would skip the last updates)
        options.setdefault("miniters", 1)
    return tqdm(iterable, **options)
