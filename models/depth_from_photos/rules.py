"""One refusal for a table of rules: the argument checks of the methods' doors, written as
`(broken, message)` pairs instead of one `if ...: raise` block each."""

from __future__ import annotations

from collections.abc import Callable, Iterable

#: whether the rule is broken, and the message that says so (built only when it is)
Rule = tuple[bool, Callable[[], str]]


def refuse_broken(rules: Iterable[Rule], error: type[Exception] = ValueError) -> None:
    """Raise `error` with the message of the first broken rule of `rules`, if any.

    Example:
        >>> sigma = -1.0
        >>> refuse_broken([(not sigma > 0, lambda: f"sigma must be > 0, got {sigma!r}")])
        Traceback (most recent call last):
        ...
        ValueError: sigma must be > 0, got -1.0
    """
    message = next((text() for broken, text in rules if broken), None)
    if message is not None:
        raise error(message)
