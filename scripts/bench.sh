#!/usr/bin/env bash
# Every speed benchmark, one after the other (they share 2 cores: never run them in parallel).
# Each prints its figures and rewrites its own section of docs/benchmarks.md.
set -eo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# shellcheck disable=SC1091
source setup.bash
echo "[bench] 1/3 physics and environment speed"
OPENBLAS_NUM_THREADS=1 python scripts/bench_physics.py
echo "[bench] 2/3 closed loop over DDS (sim + SPGD, latency, raw round trip)"
python scripts/bench_closed_loop.py
echo "[bench] 3/3 Gymnasium bridge over DDS vs in-process"
python scripts/bench_bridge.py --write docs/benchmarks.md
