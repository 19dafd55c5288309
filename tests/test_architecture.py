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


# ---- one home per job: the rules of the house -------------------------------------------------

#: The most lines a function of the packages may have.
MAX_FUNCTION_LINES = 80
#: Modules that may print: the command line and nothing else (`defocus.options` builds the
#: commands' `report` callback, `print` or nothing with `--quiet`).
MAY_PRINT = ("defocus.cli", "defocus.commands", "defocus.options")
#: Names of the camera values; a class that declares two of them is a camera value type.
CAMERA_FIELDS = {"focal_length", "f_number", "f_numbers", "focus_distance", "focus_distances",
                 "pixel_pitch"}


def package_files():
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            yield path, module_name(path), ast.parse(path.read_text(), filename=str(path))


def test_no_function_is_over_the_line_limit():
    long = [f"{path.relative_to(ROOT)}:{node.lineno}: {node.name} has "
            f"{node.end_lineno - node.lineno + 1} lines"
            for path, _, tree in package_files() for node in ast.walk(tree)
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES]
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(long)


def test_only_the_command_line_prints():
    """The library and the workflows (`defocus.app`) return results and report through
    callbacks; only the command line (`defocus.cli`, `defocus.commands`, `defocus.options`)
    prints."""
    bad = [f"{path.relative_to(ROOT)}:{node.lineno}: print"
           for path, name, tree in package_files() if not name.startswith(MAY_PRINT)
           for node in ast.walk(tree)
           if isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
           and node.func.id == "print"]
    assert not bad, "print outside the command line:\n" + "\n".join(bad)


def test_models_has_a_face():
    tree = ast.parse((ROOT / "models" / "__init__.py").read_text())
    names = [ast.literal_eval(node.value) for node in tree.body if isinstance(node, ast.Assign)
             and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)]
    assert names, "models/__init__.py has no __all__"
    for name in ("estimate_depth", "load_depth_model", "evaluate", "Trainer", "TrainConfig",
                 "depth_metrics"):
        assert name in names[0], f"models.__all__ lacks {name}"


def test_one_camera_value_type():
    """`optics.CameraSettings` is the one value type that carries camera values: no other class
    declares two of them as its fields. (The differentiable optics, `ThinLens`, `Sensor` and
    `Camera`, are modules built from settings, not value types.)"""
    bad = []
    for path, _, tree in package_files():
        for node in ast.walk(tree):
            if not isinstance(node, ast.ClassDef) or node.name == "CameraSettings" \
                    or any(ast.unparse(base) in ("nn.Module", "Module") for base in node.bases):
                continue
            fields = {stmt.target.id for stmt in node.body if isinstance(stmt, ast.AnnAssign)
                      and isinstance(stmt.target, ast.Name)} & CAMERA_FIELDS
            if len(fields) >= 2:
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.name} holds "
                           f"{sorted(fields)}")
    assert not bad, "camera values outside CameraSettings:\n" + "\n".join(bad)


def test_one_module_reads_exif():
    readers = sorted({str(path.relative_to(ROOT)) for path, name, tree in package_files()
                      for line, module in imported_modules(path, name.split(".")[0])
                      if module.split(".")[0] == "exifread"
                      or module in ("PIL.ExifTags", "PIL.TiffTags")}
                     | {str(path.relative_to(ROOT)) for path, _, tree in package_files()
                        for node in ast.walk(tree) if isinstance(node, ast.Attribute)
                        and node.attr in ("getexif", "_getexif")})
    assert len(readers) <= 1, f"EXIF read in {len(readers)} modules: {readers}"


def test_commands_import_neither_each_other_nor_the_command_line():
    bad = [f"{path.relative_to(ROOT)}:{line}: imports {module}"
           for path, name, _ in package_files() if name.startswith("defocus.commands.")
           for line, module in imported_modules(path, "defocus")
           if module.startswith(("defocus.commands.", "defocus.cli"))]
    bad += [f"{path.relative_to(ROOT)}:{line}: imports {module}"
            for path, name, _ in package_files() if name.startswith("defocus.app")
            for line, module in imported_modules(path, "defocus")
            if module.startswith(("defocus.commands", "defocus.cli"))]
    assert not bad, "\n".join(bad)


def test_no_private_module_of_another_library_is_imported():
    """Nothing reaches into a library's private modules (e.g. PyTorch's collate table in
    `torch.utils.data._utils`)."""
    bad = [f"{path.relative_to(ROOT)}:{line}: imports {module}"
           for path, name, _ in package_files()
           for line, module in imported_modules(path, name.split(".")[0])
           if module.split(".")[0] not in PACKAGES
           and any(p.startswith("_") and not p.startswith("__") for p in module.split(".")[:-1])]
    assert not bad, "\n".join(bad)


def test_no_deprecation_shims():
    bad = [f"{path.relative_to(ROOT)}:{node.lineno}: {what}"
           for path, _, tree in package_files() for node, what in
           [(n, "module __getattr__") for n in tree.body
            if isinstance(n, ast.FunctionDef) and n.name == "__getattr__"]
           + [(n, "DeprecationWarning") for n in ast.walk(tree)
              if isinstance(n, ast.Name) and n.id == "DeprecationWarning"]]
    assert not bad, "deprecation shims:\n" + "\n".join(bad)


def test_examples_have_no_second_command_line():
    """The example scripts build their parsers from `defocus.options`; no shared module of
    theirs defines options."""
    for path in sorted((ROOT / "examples").glob("_*.py")):
        assert "add_argument" not in path.read_text(), f"{path.relative_to(ROOT)} adds options"


def test_public_modules_import_no_private_names():
    """A public module (its file name has no leading underscore) imports no private name, be it
    a module (`from . import _ops`) or a symbol (`from .measure import _crop`)."""
    bad = []
    for path, name, _ in package_files():
        if path.name.startswith("_") and path.name != "__init__.py":
            continue
        for line, imported in imported_modules(path, name.split(".")[0]):
            if imported.split(".")[0] not in PACKAGES:
                continue
            if any(p.startswith("_") and not p.startswith("__") for p in imported.split(".")):
                bad.append(f"{path.relative_to(ROOT)}:{line}: imports {imported}")
    assert not bad, "private names in public modules:\n" + "\n".join(bad)


# ---- check at the door: the command line's layers ---------------------------------------------

def test_workflows_take_requests_not_command_lines():
    """`defocus.app` holds the workflows: each takes a request dataclass and returns a result.
    Parsing (argparse) and exiting (SystemExit, sys.exit) belong to the command line."""
    bad = []
    for path, name, tree in package_files():
        if not name.startswith("defocus.app"):
            continue
        bad += [f"{path.relative_to(ROOT)}:{line}: imports {module}"
                for line, module in imported_modules(path, "defocus")
                if module.split(".")[0] == "argparse"]
        bad += [f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)}"
                for node in ast.walk(tree)
                if (isinstance(node, ast.Name) and node.id == "SystemExit")
                or (isinstance(node, ast.Attribute) and ast.unparse(node) == "sys.exit")]
    assert not bad, "command-line work under defocus/app:\n" + "\n".join(bad)


def test_no_private_argparse_names():
    """The command line uses argparse's public API only (its private classes change between
    Python releases)."""
    bad = [f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)}"
           for path, _, tree in package_files() for node in ast.walk(tree)
           if isinstance(node, ast.Attribute) and node.attr.startswith("_")
           and not node.attr.startswith("__")
           and isinstance(node.value, ast.Name) and node.value.id == "argparse"]
    assert not bad, "\n".join(bad)


def test_predict_help_imports_no_training_code():
    """The command line builds only the chosen subcommand: `defocus predict --help` imports
    nothing from `models.training`."""
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "-X", "importtime", "-m", "defocus", "predict",
                             "--help"], capture_output=True, text=True, cwd=ROOT, check=True)
    imported = [line.rpartition("|")[2].strip() for line in result.stderr.splitlines()
                if line.startswith("import time:")]
    assert "defocus.cli" in imported  # (modules loaded by importlib.import_module are not listed)
    training = [name for name in imported if name.startswith("models.training")]
    assert not training, f"defocus predict --help imports {training}"


# ---- a public surface that is chosen ----------------------------------------------------------

#: Modules that implement one protocol under the same names: the subcommands (`add_arguments`,
#: `run`) and the renderer's interchangeable backends (C++, Triton, PyTorch ops).
PROTOCOL_MODULES = ("defocus.commands.", "optics.render.cpp", "optics.render.ops",
                    "optics.render.layer_ops", "optics.render.triton_kernels")
INVENTORY = Path(__file__).with_name("public_names.txt")


def public_definitions() -> dict[str, list[str]]:
    """Public top-level name -> the modules that define it (functions and classes)."""
    found: dict[str, list[str]] = {}
    for _, name, tree in package_files():
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)) \
                    and not node.name.startswith("_"):
                found.setdefault(node.name, []).append(name)
    return found


def test_one_definition_per_public_name():
    """A public name means one thing across the packages: it is defined in one module only
    (modules of one protocol, `PROTOCOL_MODULES`, aside)."""
    bad = [f"{name}: {', '.join(modules)}" for name, modules in public_definitions().items()
           if len([m for m in modules if not m.startswith(PROTOCOL_MODULES)]) > 1]
    assert not bad, "public names defined more than once:\n" + "\n".join(bad)


def faces() -> dict[str, list[str]]:
    """Package -> its `__all__` (the face users import from), read without importing."""
    out = {}
    for path, name, tree in package_files():
        if path.name != "__init__.py":
            continue
        for node in tree.body:
            if isinstance(node, ast.Assign) and any(
                    isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
                out[name] = sorted(ast.literal_eval(node.value))
    return out


def test_public_surface_is_the_inventory():
    """The public names (every package's `__all__`) are chosen: adding or removing one is a
    decision recorded in `tests/public_names.txt` (one `package.name` a line)."""
    now = {f"{package}.{name}" for package, names in faces().items() for name in names}
    listed = {line.strip() for line in INVENTORY.read_text().splitlines()
              if line.strip() and not line.startswith("#")}
    assert now == listed, (f"not in {INVENTORY.name}: {sorted(now - listed)}; "
                           f"listed but not public: {sorted(listed - now)}")


def test_every_public_name_is_defined():
    """Each name of a face's `__all__` exists in that package."""
    import importlib

    missing = [f"{package}.{name}" for package, names in faces().items()
               for name in names if not hasattr(importlib.import_module(package), name)]
    assert not missing, missing
