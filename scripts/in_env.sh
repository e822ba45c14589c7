#!/usr/bin/env bash
# Run one command inside the workspace environment (devel space + venv): scripts/in_env.sh CMD ARGS...
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
command=("$@")
set --  # devel/setup.bash reads the positional parameters as its own options
# shellcheck disable=SC1091
source "$ROOT/env.sh"
exec "${command[@]}"
