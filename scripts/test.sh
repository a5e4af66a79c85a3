#!/usr/bin/env bash
# The test suite: lint, then every package's tests and the cross-package integration tests.
set -eo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# shellcheck disable=SC1091
source setup.bash
echo "[test] ruff check"
ruff check .
echo "[test] pytest"
# One worker per core; a module's tests stay on one worker (their module-scoped processes and
# models are made once), handed out in conftest.py's order, longest module first
# (--no-loadscope-reorder: xdist would otherwise order them by their number of tests).
# PYTEST_WORKERS=0 runs in this process alone.
exec python -m pytest -n "${PYTEST_WORKERS:-auto}" --dist loadfile --no-loadscope-reorder "$@"
