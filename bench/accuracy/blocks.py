"""Generated blocks of ``docs/accuracy.md``: each bench writes its own block between markers,
and keeps the others (``python -m bench.accuracy --write-docs`` regenerates the rest of the
page around them)."""

from __future__ import annotations

import re
from pathlib import Path

#: Blocks, in the order they stand at the top of the page.
ORDER = (
    "service-live",
    "end-to-end",
    "end-to-end-defaults",
    "end-to-end-adaptive",
    "real-logs",
    "real-logs-other",
    "robustness",
    "formats",
    "range",
    "fleet",
)


def _pattern(name: str) -> re.Pattern[str]:
    return re.compile(
        rf"<!-- block {re.escape(name)}: begin -->.*?<!-- block {re.escape(name)}: end -->\n?",
        re.S,
    )


def wrap(name: str, text: str) -> str:
    return f"<!-- block {name}: begin -->\n{text.rstrip()}\n<!-- block {name}: end -->\n"


def blocks_of(page: str) -> dict[str, str]:
    """The generated blocks found in ``page``, by name."""
    out = {}
    for name in ORDER:
        m = _pattern(name).search(page)
        if m:
            out[name] = m.group(0)
    return out


def with_blocks(page: str, blocks: dict[str, str]) -> str:
    """``page`` without its blocks, then ``blocks`` put back (in :data:`ORDER`) after the
    page's first paragraph (the title and the generator's note)."""
    for name in ORDER:
        page = _pattern(name).sub("", page)
    page = re.sub(r"\n{3,}", "\n\n", page)  # the blank lines around the blocks taken out
    text = "".join(blocks[n] + "\n" for n in ORDER if n in blocks)
    anchor = page.find("\n## ")
    if anchor < 0:
        return page.rstrip() + "\n\n" + text
    return page[: anchor + 1] + text + page[anchor + 1 :]


def put_block(path: Path, name: str, text: str) -> None:
    """Write block ``name`` into the page at ``path`` (created if missing)."""
    page = path.read_text() if path.exists() else "# Accuracy\n\n"
    blocks = blocks_of(page)
    blocks[name] = wrap(name, text)
    path.write_text(with_blocks(page, blocks))
