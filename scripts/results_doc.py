"""The generated blocks of the results pages. Every table a script regenerates lies between
`<!-- NAME:start -->` and `<!-- NAME:end -->` in exactly one page under docs/results/;
`write_block` finds that page and replaces the text between the markers, leaving the rest
of the page as it is.

    from results_doc import write_block
    write_block("euroc-table", body)   # -> docs/results/euroc.md
"""

from __future__ import annotations

import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"


def markers(name: str) -> tuple[str, str]:
    """The start and end markers of block `name`."""
    return f"<!-- {name}:start -->", f"<!-- {name}:end -->"


def block_page(name: str) -> pathlib.Path:
    """The page under docs/results/ that holds block `name`; exactly one page must hold it,
    once, with its end marker after its start marker."""
    start, end = markers(name)
    pages = [p for p in sorted(RESULTS.rglob("*.md")) if start in p.read_text(encoding="utf-8")]
    if len(pages) != 1:
        where = ", ".join(str(p.relative_to(ROOT)) for p in pages) or "none"
        raise SystemExit(f"error: the {name} block must be in exactly one page of docs/results/ (pages holding it: {where})")
    text = pages[0].read_text(encoding="utf-8")
    if text.count(start) != 1 or text.count(end) != 1 or text.index(end) < text.index(start):
        raise SystemExit(f"error: {pages[0].relative_to(ROOT)}: the {name} block needs one {start} followed by one {end}")
    return pages[0]


def write_block(name: str, body: str) -> pathlib.Path:
    """Put `body` between the markers of block `name` (one line break on either side) in the
    page that holds it; returns that page."""
    path = block_page(name)
    text = path.read_text(encoding="utf-8")
    start, end = markers(name)
    i, j = text.index(start) + len(start), text.index(end)
    path.write_text(text[:i] + "\n" + body + "\n" + text[j:], encoding="utf-8")
    return path
