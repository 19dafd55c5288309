"""The layering of DESIGN.md, read from the imports of every module (no module is run)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("optics", "models", "datasets", "defocus")
#: package -> packages it must never import
FORBIDDEN = {
    "optics": {"models", "datasets", "defocus"},
    "models": {"datasets", "defocus"},
    "datasets": {"models", "defocus"},
    "defocus": set(),
}


def imported_modules(path: Path, package: str) -> list[tuple[int, str]]:
    """Absolute names of every module `path` imports (relative imports resolved)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    here = ".".join(path.relative_to(ROOT).with_suffix("").parts)
    parts = here.split(".")
    if path.name == "__init__.py":
        parts = parts[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                # a module's own package is parts[:-1]; an __init__'s is parts itself
                keep = len(parts) - (node.level - 1 if path.name == "__init__.py" else node.level)
                base = parts[:keep]
                module = ".".join([*base, node.module] if node.module else base)
            else:
                module = node.module or ""
            found.append((node.lineno, module))
            found += [(node.lineno, f"{module}.{alias.name}") for alias in node.names]
    return found


def edges() -> list[tuple[str, int, str, str]]:
    out = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            for line, module in imported_modules(path, package):
                out.append((str(path.relative_to(ROOT)), line, package, module))
    return out


def test_layers_import_only_downwards():
    bad = [f"{file}:{line}: {package} imports {module}"
           for file, line, package, module in edges()
           if module.split(".")[0] in FORBIDDEN[package]]
    assert not bad, "forbidden imports:\n" + "\n".join(bad)


def test_private_optics_modules_stay_inside_optics():
    bad = [f"{file}:{line}: imports {module}" for file, line, package, module in edges()
           if package != "optics" and any(p.startswith("_") and not p.startswith("__")
                                          for p in module.split(".")[1:2])
           and module.startswith("optics.")]
    # Tests may look inside (white-box kernel tests); examples are user code and may not.
    for path in sorted((ROOT / "examples").glob("*.py")):
        for line, module in imported_modules(path, "examples"):
            if module.startswith("optics._"):
                bad.append(f"{path.relative_to(ROOT)}:{line}: imports {module}")
    assert not bad, "private optics modules used outside optics:\n" + "\n".join(bad)


@pytest.mark.parametrize("package", ["optics", "models", "datasets"])
def test_library_never_touches_pyplot_or_the_backend(package):
    bad = [f"{file}:{line}: imports {module}" for file, line, pkg, module in edges()
           if pkg == package and module.startswith(("matplotlib.pyplot", "pylab"))]
    for path in sorted((ROOT / package).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr == "use" \
                    and isinstance(node.value, ast.Name) and node.value.id == "matplotlib":
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: matplotlib.use")
    assert not bad, "\n".join(bad)


def test_the_checker_resolves_relative_imports():
    """The import parser resolves relative imports (so the layer test can fail)."""
    names = [name for _, name in imported_modules(ROOT / "optics" / "lens.py", "optics")]
    assert "optics.checks" in names
    names = [name for _, name in imported_modules(ROOT / "optics" / "__init__.py", "optics")]
    assert "optics.lens.ThinLens" in names
