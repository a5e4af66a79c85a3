"""Print pip's package sources as uv options, one word a line, for scripts/setup.sh.

setup.sh installs the pinned requirements with uv (parallel downloads: ~20 s instead of pip's
~2 min of one index page after another) from exactly the sources pip would use: the indexes,
extra indexes, find-links and constraint files of pip's configuration files and PIP_*
variables, as ``pip config list`` shows them. pip reads every index as an equal source; uv's
``--index-strategy unsafe-best-match``, which setup.sh adds, does the same.
"""

from __future__ import annotations

import shlex
import subprocess
import sys

#: pip option -> uv option (each may hold several whitespace-separated values).
OPTIONS = {
    "index-url": "--index-url",
    "extra-index-url": "--extra-index-url",
    "find-links": "--find-links",
    "constraint": "--constraint",
}


def uv_options(pip_config: str) -> list[str]:
    """uv options from ``pip config list`` output (``scope.name='value'`` lines); a value named
    twice (a file and a PIP_* variable) is passed once, and of several index URLs the
    environment's (listed first) wins, as in pip."""
    words: list[str] = []
    seen: set[tuple[str, str]] = set()
    index_url = None
    for line in pip_config.splitlines():
        key, sep, raw = line.partition("=")
        option = OPTIONS.get(key.rsplit(".", 1)[-1])
        if not sep or option is None:
            continue
        values = " ".join(shlex.split(raw)).split()
        if option == "--index-url":
            index_url = index_url or (values[0] if values else None)
            continue
        for value in values:
            if (option, value) not in seen:
                seen.add((option, value))
                words += [option, value]
    return (["--index-url", index_url] if index_url else []) + words


def main() -> int:
    done = subprocess.run(
        [sys.executable, "-m", "pip", "config", "list"], capture_output=True, text=True
    )
    if done.returncode != 0:
        print(done.stderr, file=sys.stderr)
        return 1
    print("\n".join(uv_options(done.stdout)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
