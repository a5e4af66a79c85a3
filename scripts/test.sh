#!/usr/bin/env bash
# The test suite: lint, then every package's tests and the cross-package integration tests.
set -eo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# shellcheck disable=SC1091
source setup.bash
echo "[test] ruff check"
ruff check .
echo "[test] pytest"
exec python -m pytest "$@"
