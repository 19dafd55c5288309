"""Old import paths that keep working for one release, with a `DeprecationWarning`.

A module that moved leaves behind a stub whose `__getattr__` (PEP 562) is `moved_names(...)`:
each name is looked up in the new modules on first use and the warning says where it lives now.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any


def moved_names(old: str, new_modules: Sequence[str],
                renamed: Mapping[str, str] | None = None) -> Callable[[str], Any]:
    """A module `__getattr__` for the stub left at `old`: a public name is found in the first of
    `new_modules` that has it (under its new name where `renamed` maps it), with a
    `DeprecationWarning` that names the new home; anything else is an `AttributeError`.

    Example:
        >>> import warnings
        >>> lookup = moved_names("old.place", ["math"], {"circle_constant": "pi"})
        >>> with warnings.catch_warnings(record=True) as caught:
        ...     warnings.simplefilter("always")
        ...     round(lookup("circle_constant"), 2), caught[0].category.__name__
        (3.14, 'DeprecationWarning')
        >>> str(caught[0].message)
        'old.place.circle_constant moved to math.pi; the old path goes in the next release'
    """
    renamed = dict(renamed or {})

    def __getattr__(name: str) -> Any:
        if not name.startswith("_"):
            target = renamed.get(name, name)
            for module_name in new_modules:
                module = importlib.import_module(module_name)
                if hasattr(module, target):
                    warnings.warn(f"{old}.{name} moved to {module_name}.{target}; the old path "
                                  "goes in the next release", DeprecationWarning, stacklevel=2)
                    return getattr(module, target)
        raise AttributeError(f"module {old!r} has no attribute {name!r}")

    return __getattr__
