#!/usr/bin/env bash
# The test suite: lint, then every package's tests and the cross-package integration tests.
set -eo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# shellcheck disable=SC1091
source setup.bash
echo "[test] ruff check"
ruff check .
echo "[test] pytest"
# One worker more than cores: a quarter of the suite's time is spent waiting on the processes it
# starts (DDS discovery, outages, node start-up), when a worker holds no core (docs/setup.md).
# A module's tests stay on one worker (their module-scoped processes and models are made once),
# handed out in conftest.py's order, longest module first (--no-loadscope-reorder: xdist would
# otherwise order them by their number of tests). PYTEST_WORKERS=0 runs in this process alone.
workers="${PYTEST_WORKERS:-$(($(nproc) + 1))}"
exec python -m pytest -n "$workers" --dist loadfile --no-loadscope-reorder "$@"
