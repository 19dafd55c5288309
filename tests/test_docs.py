"""The documentation: docstrings are Markdown (no reStructuredText left), the generated CLI
reference covers the whole parser, the site checker finds leftovers, the pages are in the nav.

Fast: nothing here builds the site (`make test` runs `mkdocs build --strict` and
`docs/check_site.py` on the result).
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import io
import re
import tokenize
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("optics", "models", "datasets", "defocus")
DOCS = ROOT / "docs"

#: reStructuredText that mkdocstrings (Markdown) shows verbatim.
RST_PATTERNS = {
    "Sphinx role": re.compile(
        r":(?:py:)?(?:class|func|meth|attr|data|mod|math|obj|exc|const|ref|term|doc):`"
    ),
    "RST directive": re.compile(r"^\s*\.\. [a-z-]+::", re.MULTILINE),
    "RST double backticks": re.compile(r"(?<!`)``[^`\n]+``(?!`)"),
}


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _python_files() -> list[Path]:
    return sorted(p for package in PACKAGES for p in (ROOT / package).rglob("*.py"))


def _docstrings_and_comments(path: Path) -> list[tuple[int, str]]:
    """`(first line, text)` of each docstring (a string statement of its own) and `#` comment."""
    source = path.read_text(encoding="utf-8")
    found = []
    for node in ast.walk(ast.parse(source)):
        if (
            isinstance(node, ast.Expr)
            and isinstance(node.value, ast.Constant)
            and isinstance(node.value.value, str)
        ):
            found.append((node.lineno, node.value.value))
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            found.append((token.start[0], token.string))
    return found


def _without_code(text: str) -> str:
    """The text less doctest examples (`>>>` lines and their output) and fenced code blocks."""
    kept, in_doctest, in_fence = [], False, False
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("```"):
            in_fence = not in_fence
            continue
        if stripped.startswith(">>>"):
            in_doctest = True
        elif not stripped:
            in_doctest = False
        kept.append("" if in_fence or in_doctest else line)
    return "\n".join(kept)


def test_docstrings_are_markdown_without_rst_leftovers():
    """mkdocstrings renders docstrings as Markdown: no Sphinx roles, no `.. math::`, no ``x``."""
    offences = []
    for path in _python_files():
        for lineno, text in _docstrings_and_comments(path):
            body = _without_code(text)
            for kind, pattern in RST_PATTERNS.items():
                for match in pattern.finditer(body):
                    line = lineno + body.count("\n", 0, match.start())
                    offences.append(f"{path.relative_to(ROOT)}:{line}: {kind}: {match.group(0)}")
    assert not offences, (
        f"{len(offences)} reStructuredText leftover(s) in docstrings/comments (write Markdown: "
        "`code`, $maths$, a $$ block):\n" + "\n".join(offences[:60])
    )


@pytest.fixture(scope="module")
def cli_reference():
    return _load("cli_reference_hook", DOCS / "hooks" / "cli_reference.py")


def _walk(parser: argparse.ArgumentParser, prefix: str = ""):
    """`(name, parser)` for `parser` and every subcommand parser below it."""
    yield prefix or parser.prog, parser
    for name, sub in parser.commands.items():
        yield from _walk(sub, f"{prefix or parser.prog} {name}")


def test_cli_reference_covers_every_subcommand_and_option(cli_reference):
    from defocus.cli import build_parser

    markdown = cli_reference.cli_reference_markdown()
    parsers = list(_walk(build_parser()))
    assert len(parsers) > 1, "defocus has no subcommand?"
    missing = []
    for name, parser in parsers:
        if f"## `{name}`" not in markdown:
            missing.append(f"section of {name!r}")
        section = markdown.split(f"## `{name}`", 1)[-1].split("\n## `", 1)[0]
        if parser.description and " ".join(parser.description.split())[:40] not in section:
            missing.append(f"description of {name!r}")
        if "usage: " + name not in section:
            missing.append(f"usage of {name!r}")
        missing += [f"subcommand {sub!r} in the table" for sub in parser.commands
                    if f"`{sub}`" not in markdown]
        for action in parser.arguments:
            names = action.option_strings or [action.metavar or action.dest]
            for option in names:
                if f"`{option}" not in section:
                    missing.append(f"{option} of {name!r}")
            if (
                action.option_strings
                and action.default not in (None, argparse.SUPPRESS, [], ())
                and action.dest != "help"
            ):
                default = action.default
                default = " ".join(map(str, default)) if isinstance(default, list) else str(default)
                if f"`{default}`" not in section:
                    missing.append(f"default of {names[0]} of {name!r}: {default}")
    assert not missing, "the generated CLI reference lacks: " + ", ".join(missing)


def test_cli_reference_is_generated_not_kept(cli_reference):
    """The page exists only at build time (the hook adds it), and the nav points at it."""
    assert not (DOCS / cli_reference.PAGE).exists(), "docs/cli.md is generated: do not commit it"
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    assert "docs/hooks/cli_reference.py" in config.get("hooks", [])


def _nav_pages(nav) -> list[str]:
    pages = []
    for entry in nav:
        value = next(iter(entry.values())) if isinstance(entry, dict) else entry
        pages.extend(_nav_pages(value) if isinstance(value, list) else [value])
    return pages


def test_nav_lists_every_page_and_they_exist(cli_reference):
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    pages = _nav_pages(config["nav"])
    for page in ("install.md", "architecture.md", cli_reference.PAGE):
        assert page in pages
    for page in pages:
        assert page == cli_reference.PAGE or (DOCS / page).is_file(), page
    assert "example.invalid" not in (ROOT / "mkdocs.yml").read_text(encoding="utf-8")


def test_architecture_figure_is_committed_and_small():
    figure = DOCS / "img" / "architecture.png"
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert figure.stat().st_size < 300_000
    assert "img/architecture.png" in (DOCS / "architecture.md").read_text(encoding="utf-8")


def test_check_site_finds_rst_leftovers(tmp_path, capsys):
    check_site = _load("check_site", DOCS / "check_site.py")
    (tmp_path / "good").mkdir()
    (tmp_path / "good" / "index.html").write_text(
        "<p>The <code>ThinLens</code> maps <span class='arithmatex'>\\(D\\)</span> to a CoC.</p>\n"
    )
    assert check_site.main([str(tmp_path / "good")]) == 0
    bad = tmp_path / "bad" / "api"
    bad.mkdir(parents=True)
    (bad / "index.html").write_text(
        "<p>ok</p>\n<p>See :class:<code>~optics.ThinLens</code>.</p>\n"
        "<p>.. math:: c = f^2</p>\n<p>:func:`render_defocus`</p>\n"
    )
    assert check_site.main([str(tmp_path / "bad")]) == 1
    out = capsys.readouterr().out
    for line in (2, 3, 4):
        assert f"index.html:{line}:" in out
    assert check_site.main([str(tmp_path / "empty")]) == 2


def test_license_is_the_full_apache_2_text():
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    for section in range(1, 10):
        assert re.search(rf"^\s*{section}\. \S", text, re.MULTILINE), f"section {section}"
    assert "END OF TERMS AND CONDITIONS" in text
    assert "APPENDIX: How to apply the Apache License to your work." in text


def test_maths_become_mathml():
    """arithmatex's `$x$` and `$$` output is turned into MathML at build time (no JavaScript)."""
    mathml = _load("mathml_hook", DOCS / "hooks" / "mathml.py")
    page = (
        '<p>depth <span class="arithmatex">\\(D_f &lt; D\\)</span></p>\n'
        '<div class="arithmatex">\\[\nc = \\frac{f^2}{N}\n\\]</div>'
    )
    out = mathml.convert_html(page)
    assert "\\(" not in out and "\\[" not in out
    assert out.count("<math ") == 2 and 'display="block"' in out and "<mfrac>" in out
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    assert "docs/hooks/mathml.py" in config["hooks"]
