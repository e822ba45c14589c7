#!/usr/bin/env bash
# Runs every benchmark in bench/<package>/ (make bench); each prints its figures and writes
# artifacts/bench/<name>.json. BENCH_ARGS=--quick for a smoke run. bench/experiments/ holds the
# runs that chose settings; they are not run here. Exit status: failures count.
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
mkdir -p artifacts/bench
failed=()
for bench in bench/*/*.py; do
  case "$bench" in bench/experiments/*) continue ;; esac
  grep -q '__main__' "$bench" || continue  # shared helper modules are not benchmarks
  echo "=== $bench ==="
  # shellcheck disable=SC2086
  python "$bench" ${BENCH_ARGS:-} || failed+=("$bench")
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "failed: ${failed[*]}"
  exit 1
fi
echo "all benchmarks finished; figures in artifacts/bench/"
