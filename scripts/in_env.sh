#!/usr/bin/env bash
# Run one command inside the workspace environment (devel space + venv): scripts/in_env.sh CMD ARGS...
set -eo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# shellcheck disable=SC1091
source "$ROOT/env.sh"
exec "$@"
