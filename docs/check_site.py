#!/usr/bin/env python3
"""Check a BUILT MkDocs site for reStructuredText/Sphinx leftovers that Markdown does not render.

Usage: python docs/check_site.py SITE_DIR      (e.g. build/site after `mkdocs build`)

Looks in every HTML page for Sphinx roles (`:class:`, `:func:`, `:meth:`, `:attr:`, `:data:`,
`:mod:`, `:math:`, ... followed by a backtick or by the `<code>` Markdown made of it) and for
`.. math::` / other `.. directive::` lines. Prints `page:line: text` for each and exits 1 when
there is any, 0 when the site is clean, 2 when SITE_DIR holds no HTML page.
"""

from __future__ import annotations

import html
import re
import sys
from pathlib import Path

ROLES = "class|func|meth|attr|data|mod|math|obj|exc|const|ref|term|doc|py:[a-z]+"
#: What must not appear in the text of a rendered page.
PATTERNS = {
    "Sphinx role": re.compile(r":(?:" + ROLES + r"):(?:`|<code>)"),
    "RST directive": re.compile(
        r"(?:^|[\s>])\.\. (?:math|note|warning|code-block|code|seealso|versionadded|"
        r"versionchanged|deprecated|autoclass|autofunction|image|figure)::"
    ),
}


def check_page(path: Path) -> list[tuple[int, str, str]]:
    """`(line number, kind, text)` of each leftover in one HTML file."""
    found = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        for kind, pattern in PATTERNS.items():
            match = pattern.search(line) or pattern.search(html.unescape(line))
            if match:
                start = max(match.start() - 40, 0)
                found.append((number, kind, line[start : match.end() + 40].strip()))
    return found


def check_site(site: Path) -> dict[Path, list[tuple[int, str, str]]]:
    """Leftovers per page (relative path) of the site folder `site`; pages without any are left out."""
    pages = sorted(site.rglob("*.html"))
    if not pages:
        raise FileNotFoundError(f"no HTML page under {site} (build the site first)")
    report = {}
    for page in pages:
        found = check_page(page)
        if found:
            report[page.relative_to(site)] = found
    return report


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    try:
        report = check_site(Path(argv[0]))
    except FileNotFoundError as error:
        print(error, file=sys.stderr)
        return 2
    for page, found in report.items():
        for number, kind, text in found:
            print(f"{page}:{number}: {kind}: {text}")
    if report:
        n = sum(len(found) for found in report.values())
        print(f"{n} reStructuredText leftover(s) in {len(report)} page(s)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
