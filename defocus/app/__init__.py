"""The workflows behind the commands: each returns its results and reports progress through a
`report(text)` callback (the command line passes `print`); none of them prints or parses
options."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

Request = TypeVar("Request")


def silent(text: str) -> None:
    """The `report` callback that drops the text (a workflow's default: nothing is printed)."""


def request_from(cls: type[Request], options: Any, **given: Any) -> Request:
    """The request dataclass `cls` of parsed `options`: each field from the option of its name
    where there is one, the fields `given` over those.

    Example:
        >>> @dataclasses.dataclass
        ... class Ask:
        ...     root: str = ""
        ...     quiet: bool = False
        >>> request_from(Ask, type("Options", (), {"root": "data", "extra": 1})(), quiet=True)
        Ask(root='data', quiet=True)
    """
    fields = {field.name: getattr(options, field.name) for field in dataclasses.fields(cls)
              if hasattr(options, field.name)}
    return cls(**{**fields, **given})
