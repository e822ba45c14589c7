#!/usr/bin/env bash
# The whole test suite, run by `make test` (inside env.sh) and so by .ci/run.
# Includes the Python 3.8 compatibility and lint checks (tests/test_code_checks.py).
# Extra pytest arguments pass through: make test TEST_ARGS="-k ros_mongo".
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
exec python -m pytest --durations=20 "$@"
