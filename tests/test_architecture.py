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


#: The most lines a Python file of the packages may have.
MAX_LINES = 500


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def module_graph() -> dict[str, set[str]]:
    """Module -> the package modules it imports (anywhere in it, also inside functions); a name
    imported from a package is an edge to the module that defines it, where there is one."""
    modules = {module_name(path): path for package in PACKAGES
               for path in sorted((ROOT / package).rglob("*.py"))}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        for _, imported in imported_modules(path, name.split(".")[0]):
            # "a.b.c" may be module a.b.c or name c of module a.b: keep the longest module
            while imported and imported not in modules:
                imported = imported.rpartition(".")[0]
            # `from . import sibling` also names the package itself: not an edge to its __init__
            if imported and imported != name and not name.startswith(imported + "."):
                graph[name].add(imported)
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for other in graph[node]:
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return cycles


def test_no_import_cycles():
    """No module imports, directly or through others, a module that imports it back (lazy
    imports inside functions count too: they only hide a circle)."""
    cycles = import_cycles(module_graph())
    assert not cycles, "import circles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_cycle_finder_finds_a_circle():
    assert import_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert import_cycles({"a": {"b"}, "b": set()}) == []


def test_no_python_file_is_over_the_line_limit():
    long = [f"{path.relative_to(ROOT)}: {n} lines" for package in PACKAGES
            for path in sorted((ROOT / package).rglob("*.py"))
            if (n := len(path.read_text().splitlines())) > MAX_LINES]
    assert not long, f"files over {MAX_LINES} lines (split them by concept):\n" + "\n".join(long)


def concept(module: str) -> str:
    """The concept a module belongs to: a subpackage is one (`models.depth_from_photos`); a
    module of a package is its own, and private modules named after it are part of it
    (`optics._render_ops` and `optics._render_cpp` serve `optics.render`).

    Example: `concept("optics._render_ops") == concept("optics.render") == "optics.render"`.
    """
    parts = module.split(".")
    if len(parts) < 2 or (ROOT / parts[0] / parts[1]).is_dir():
        return ".".join(parts[:2])
    return f"{parts[0]}.{parts[1].lstrip('_').split('_')[0]}"


def test_private_names_stay_inside_their_concept():
    """No module imports a private name (`_name`) from a module of another concept: what a
    concept shares is public. A subpackage (e.g. `models.depth_from_photos`) is one concept."""
    bad = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            here = module_name(path)
            for line, imported in imported_modules(path, package):
                module, _, name = imported.rpartition(".")
                if not (name.startswith("_") and not name.startswith("__")):
                    continue
                if module.count(".") == 0:  # `from . import _private_module`
                    module = imported
                if module.split(".")[0] in PACKAGES and concept(module) != concept(here):
                    bad.append(f"{path.relative_to(ROOT)}:{line}: imports {imported}")
    assert not bad, "private names used outside their concept:\n" + "\n".join(bad)


def test_concepts_group_private_modules_with_their_public_one():
    assert concept("optics._render_ops") == concept("optics.render") == "optics.render"
    assert concept("models.depth_from_photos.sweep") == "models.depth_from_photos"
    assert concept("models.training") != concept("models.checkpoints")
