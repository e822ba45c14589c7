#!/usr/bin/env bash
# The whole test suite, run by `make test` (inside env.sh) and so by .ci/run.
# Includes the Python 3.8 compatibility and lint checks (tests/test_code_checks.py).
# Test files run in parallel (pytest-xdist, one file per worker at a time: a file's fixtures are
# built once); every test has its own roscore port and database, so they do not interfere.
# TEST_WORKERS sets the number of workers (default 2, one per core of a robot's computer: each
# worker starts its own servers and imports TensorFlow and PyTorch, so a third saves a little
# wall time for about 25 CPU-seconds more); TEST_WORKERS=0 runs in this process.
# Extra pytest arguments pass through: make test TEST_ARGS="-k ros_mongo".
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
workers="${TEST_WORKERS:-2}"
# Several test processes, and the nodes they start, share the cores: one math thread each keeps
# TensorFlow's, PyTorch's and BLAS's thread pools from spinning against each other (about a tenth
# of the TensorFlow tests' CPU). Set any of them to override.
for name in OMP_NUM_THREADS MKL_NUM_THREADS OPENBLAS_NUM_THREADS TF_NUM_INTRAOP_THREADS \
    TF_NUM_INTEROP_THREADS; do
  export "$name=${!name:-1}"
done
parallel=()
if [ "$workers" != "0" ]; then
  parallel=(-n "$workers" --dist loadfile)
fi
exec python -m pytest --durations=25 "${parallel[@]}" "$@"
