"""Write a benchmark's figures into docs/benchmarks.md: the section that starts with its title
line (up to the next "## " heading) is replaced in place, or appended when it is not there yet."""

from __future__ import annotations

import re
from pathlib import Path

BENCHMARKS_MD = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"


def write_section(title: str, text: str, path: Path = BENCHMARKS_MD) -> None:
    """Put ``text`` (which starts with the line ``title``) in place of the section ``title``."""
    doc = path.read_text() if path.exists() else "# Benchmarks\n"
    pattern = re.compile(rf"^{re.escape(title)}\n.*?(?=^## |\Z)", re.S | re.M)
    text = text.rstrip("\n") + "\n"
    if pattern.search(doc):
        doc = pattern.sub(lambda _: text + "\n", doc).rstrip("\n") + "\n"
    else:
        doc = doc.rstrip("\n") + "\n\n" + text
    path.write_text(doc)
    print(f"wrote {path} ({title})", flush=True)
