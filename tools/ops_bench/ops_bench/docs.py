"""Write a benchmark's figures into docs/benchmarks.md: the section that starts with its title
line (up to the next heading, "## " or a hand-written "### " sub-section under it, which is kept)
is replaced in place, or appended when it is not there yet."""

from __future__ import annotations

import re
from pathlib import Path

from ops_bench import REPO

BENCHMARKS_MD = REPO / "docs" / "benchmarks.md"


def write_section(title: str, text: str, path: Path = BENCHMARKS_MD) -> None:
    """Put ``text`` (which starts with the line ``title``) in place of the section ``title``."""
    doc = path.read_text() if path.exists() else "# Benchmarks\n"
    pattern = re.compile(rf"^{re.escape(title)}\n.*?(?=^##+ |\Z)", re.S | re.M)
    text = text.rstrip("\n") + "\n"
    if pattern.search(doc):
        doc = pattern.sub(lambda _: text + "\n", doc).rstrip("\n") + "\n"
    else:
        doc = doc.rstrip("\n") + "\n\n" + text
    path.write_text(doc)
    print(f"wrote {path} ({title})", flush=True)


def publish(title: str, lines: list[str], write: bool = True, path: Path = BENCHMARKS_MD) -> str:
    """Print a benchmark's section (``lines``, the first one ``title``) and, with ``write``, put
    it in place of its section of ``path``; returns the text."""
    text = "\n".join(lines)
    print(text)
    if write:
        write_section(title, text, path)
    return text


def save_figure(fig, path: Path, dpi: int = 110) -> None:
    """Lay out ``fig`` (a pyplot figure), write it to ``path`` and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
