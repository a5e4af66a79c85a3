"""The project's benchmarks, figure and model tools as one command, ``ops-bench`` (ops_bench.cli),
and the helpers they share with the tests: processes (ops_bench.processes), a topic observer
(ops_bench.observer), two hosts on one machine and a lossy link (ops_bench.hosts, ops_bench.relay),
a Ray cluster on them (ops_bench.ray_cluster), and the sections of docs they rewrite
(ops_bench.docs).

Installed editable from tools/ops_bench by scripts/setup.sh: the benchmarks read and write the
repository they live in (docs/, models/, runs/), found from this file.
"""

from __future__ import annotations

from pathlib import Path

# tools/ops_bench/ops_bench/__init__.py -> the repository's root.
REPO = Path(__file__).resolve().parents[3]
