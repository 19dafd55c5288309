"""MkDocs hook: maths as MathML, converted at build time (no JavaScript, works offline).

`pymdownx.arithmatex` (with `generic: true`) turns `$x$` into `<span class="arithmatex">\\(x\\)</span>`
and a `$$ ... $$` block into `<div class="arithmatex">\\[ ... \\]</div>`, which only a script such
as MathJax would typeset. This hook replaces them in every page (Markdown pages and docstrings
rendered by mkdocstrings alike) with MathML from `latex2mathml`, which browsers display natively.
An expression latex2mathml cannot convert is left as it was and logged.

Enabled in mkdocs.yml with `hooks: [docs/hooks/mathml.py]`.
"""

from __future__ import annotations

import html
import logging
import re

from latex2mathml.converter import convert

log = logging.getLogger("mkdocs.hooks.mathml")

#: arithmatex's generic output: inline `\(...\)` spans and display `\[...\]` divs.
MATH_RE = re.compile(
    r'<(?P<tag>span|div) class="arithmatex">\s*'
    r"(?:\\\((?P<inline>.*?)\\\)|\\\[(?P<block>.*?)\\\])"
    r"\s*</(?P=tag)>",
    re.DOTALL,
)


def to_mathml(match: re.Match[str]) -> str:
    block = match.group("block") is not None
    tex = html.unescape(match.group("block") if block else match.group("inline")).strip()
    try:
        mathml = convert(tex, display="block" if block else "inline")
    except Exception as error:  # noqa: BLE001 - any failure: keep the TeX, say which
        log.info("mathml: left %r as TeX (%s: %s)", tex, type(error).__name__, error)
        return match.group(0)
    if block:
        return f'<div class="arithmatex mathml">{mathml}</div>'
    return f'<span class="arithmatex mathml">{mathml}</span>'


def convert_html(text: str) -> str:
    """The page's HTML with each arithmatex expression replaced by MathML."""
    return MATH_RE.sub(to_mathml, text)


def on_page_content(html_text, page, config, files):
    return convert_html(html_text)
