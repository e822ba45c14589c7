#!/usr/bin/env bash
# Keep the machine's cores busy, to check that the test suite passes on a loaded machine (a robot's
# computer is never quiet). Starts N busy loops at normal priority (`nice -n 0`, N
# defaults to 2 = the cores of the reference machine) and stops them, by process id, when it ends.
#
#   scripts/cpu_hog.sh make test            # hog while the command runs; exits with its status
#   scripts/cpu_hog.sh -n 4 make test       # four busy loops
#   scripts/cpu_hog.sh                      # hog until Ctrl-C / SIGTERM
#   scripts/cpu_hog.sh start                # hog in the background (pids in .setup/cpu_hog.pids)
#   scripts/cpu_hog.sh stop                 # stop the background hog started with `start`
#
# Environment: CPU_HOG_N (default 2) is the same as -n.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PID_FILE="$ROOT/.setup/cpu_hog.pids"
N="${CPU_HOG_N:-2}"
PIDS=()

usage() { sed -n '2,12p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; }

start_loops() {  # start_loops: N busy loops in the background, their pids in PIDS
  local k
  for ((k = 0; k < N; k++)); do
    nice -n 0 bash -c 'while :; do :; done' &
    PIDS+=("$!")
  done
  echo "[cpu_hog] $N busy loop(s) at nice 0: pids ${PIDS[*]}" >&2
}

stop_loops() {  # stop_loops PID...: stop our own loops by process id
  local pid
  for pid in "$@"; do
    kill "$pid" 2>/dev/null || true
  done
  for pid in "$@"; do
    wait "$pid" 2>/dev/null || true
  done
  [ $# -eq 0 ] || echo "[cpu_hog] stopped pids $*" >&2
}

if [ "${1:-}" = "-n" ]; then
  N="${2:?-n needs a number}"
  shift 2
fi
case "$N" in
  ''|*[!0-9]*) echo "cpu_hog: the number of busy loops must be a whole number, got '$N'" >&2; exit 2 ;;
esac

case "${1:-}" in
  -h|--help)
    usage
    exit 0
    ;;
  start)
    if [ -s "$PID_FILE" ]; then
      echo "cpu_hog: already running (pids $(tr '\n' ' ' <"$PID_FILE")); stop it first: $0 stop" >&2
      exit 1
    fi
    mkdir -p "$(dirname "$PID_FILE")"
    for ((k = 0; k < N; k++)); do
      # setsid + nohup: the loops outlive this script; only `stop` ends them (by the pids written)
      nohup setsid nice -n 0 bash -c 'while :; do :; done' >/dev/null 2>&1 &
      echo "$!" >>"$PID_FILE"
    done
    echo "[cpu_hog] $N busy loop(s) at nice 0 in the background: pids $(tr '\n' ' ' <"$PID_FILE")" >&2
    ;;
  stop)
    if [ ! -s "$PID_FILE" ]; then
      echo "[cpu_hog] nothing to stop (no $PID_FILE)" >&2
      exit 0
    fi
    mapfile -t saved <"$PID_FILE"
    for pid in "${saved[@]}"; do
      # only a pid that still runs our busy loop (pids are reused after a reboot)
      if grep -q 'while :; do :; done' "/proc/$pid/cmdline" 2>/dev/null; then
        kill "$pid" 2>/dev/null || true
      fi
    done
    rm -f "$PID_FILE"
    echo "[cpu_hog] stopped pids ${saved[*]}" >&2
    ;;
  '')
    trap 'stop_loops "${PIDS[@]}"' EXIT
    trap 'exit 0' INT TERM
    start_loops
    echo "[cpu_hog] running until Ctrl-C" >&2
    wait
    ;;
  *)
    trap 'stop_loops "${PIDS[@]}"' EXIT
    trap 'exit 130' INT
    trap 'exit 143' TERM
    start_loops
    status=0
    "$@" || status=$?
    echo "[cpu_hog] '$*' exited with status $status" >&2
    exit "$status"
    ;;
esac
