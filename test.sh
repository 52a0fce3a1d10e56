#!/usr/bin/env bash
# Quick start 2/2: set up (first time only) and run every check CI runs: lint, format, types, layer
# contracts and the test suite. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")"
source scripts/bootstrap.sh dev
ruff check src tests benchmarks
ruff format --check src tests benchmarks
mypy
lint-imports
# The fleet dashboard's browser test drives Debian's Chromium; install it if this machine lacks it.
bash scripts/ensure_chromium.sh
bash scripts/ensure_postgres.sh
set +e
# One worker per core, whole files per worker: a file's module-level fixtures and cached runs (the
# default service's five seeds) are computed once, as in a serial run. "-n 0" runs serially.
python -m pytest -n auto --dist loadfile "$@"
status=$?
set -e
if [ "$status" -eq 5 ]; then
  echo "pytest collected no tests: that is a failure here, not a pass" >&2
  exit 1
fi
exit "$status"
