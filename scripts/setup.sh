#!/usr/bin/env bash
# One idempotent set-up for a fresh Debian 12 machine, run by `make demo` and `make test`:
#   1. Debian packages: ROS 1 (Noetic versions, from Debian), python3-venv, Node.js/npm, rviz+Xvfb
#   2. .venv: made from /usr/bin/python3 with system site packages, pinned requirements installed
#      with uv (pip when uv cannot run), at the same time as 3
#   3. tools/pouchdb-server: the CouchDB-compatible server from npm (pinned by package-lock.json)
#   4. the catkin workspace: catkin_make (devel space)
# Each step is skipped when what it would do is already done (stamps in .setup/), so a second run
# takes a few seconds. Uses sudo for system packages when not run as root.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
STAMPS="$ROOT/.setup"
mkdir -p "$STAMPS"
cd "$ROOT"

APT_PACKAGES=(
  # ROS 1 from Debian (see README: there is no /opt/ros; everything is under /usr)
  ros-core-python-dev catkin ros-message-generation rosbash
  python3-rospy python3-rosbag python3-roslaunch python3-rostopic python3-rosservice python3-rostest
  python3-std-msgs python3-geometry-msgs python3-sensor-msgs python3-nav-msgs
  python3-visualization-msgs python3-diagnostic-msgs python3-std-srvs python3-tf2-ros
  python3-tf2-geometry-msgs python3-actionlib python3-actionlib-msgs python3-move-base-msgs
  # build tools catkin_make needs, and catkin_lint (tests/test_manifests.py lints every package)
  cmake g++ make catkin-lint
  # the virtual environment
  python3-venv
  # rviz, headless (tests take screenshots under Xvfb)
  rviz xvfb libgl1-mesa-dri imagemagick
  # WordNet glosses: the embedding corpus a fresh machine can always get
  wordnet-base
  # what the real Apache CouchDB of ../shared/couchdb links against (its tests and benchmarks)
  libicu72 libssl3
)

log() { printf '[setup] %s\n' "$*"; }
elapsed() { echo $(( $(date +%s) - $1 ))s; }

as_root() {
  if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi
}

hash_of() {  # hash_of FILE... : one sha256 over the files' names and contents
  local file
  for file in "$@"; do printf '%s\n' "$file"; cat "$file"; done | sha256sum | cut -d' ' -f1
}

stamp_matches() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }

step_apt() {
  local start missing=() pkg
  start=$(date +%s)
  for pkg in "${APT_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q 'install ok installed' || missing+=("$pkg")
  done
  command -v npm >/dev/null 2>&1 || missing+=(nodejs npm)
  if [ ${#missing[@]} -eq 0 ]; then
    log "Debian packages: all present"
    return
  fi
  log "Debian packages: installing ${missing[*]}"
  as_root env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
    "${missing[@]}" >"$STAMPS/apt.log" 2>&1 || { tail -30 "$STAMPS/apt.log"; exit 1; }
  log "Debian packages: done in $(elapsed "$start")"
}

pip_config_sources() {  # the index options this machine's pip is configured with, for uv
  local key value item
  for key in find-links extra-index-url; do
    value=$(.venv/bin/python -m pip config get "global.$key" 2>/dev/null || true)
    [ "$key" = find-links ] && value="$value ${PIP_FIND_LINKS:-}"
    [ "$key" = extra-index-url ] && value="$value ${PIP_EXTRA_INDEX_URL:-}"
    for item in $value; do printf -- '--%s\n%s\n' "$key" "$item"; done
  done
}

install_requirements() {  # uv (parallel downloads, bytecode compiled); pip when uv cannot run
  local sources=()
  mapfile -t sources < <(pip_config_sources)
  if .venv/bin/python -m pip install -q --disable-pip-version-check -c constraints.txt uv \
      && .venv/bin/python -m uv pip install --python .venv/bin/python --compile-bytecode \
        --index-strategy unsafe-best-match "${sources[@]}" \
        -r requirements.txt -c constraints.txt --excludes requirements-exclude.txt; then
    return 0
  fi
  echo "uv failed: installing with pip" >&2
  .venv/bin/python -m pip install --disable-pip-version-check \
    -r requirements.txt -c constraints.txt
}

step_venv() {
  local start want
  start=$(date +%s)
  want=$(hash_of requirements.txt constraints.txt requirements-exclude.txt)
  if [ -x .venv/bin/python ] && stamp_matches venv "$want"; then
    log "Python venv: up to date"
    return
  fi
  if [ ! -x .venv/bin/python ]; then
    /usr/bin/python3 -m venv --system-site-packages .venv || return 1
  fi
  log "Python venv: installing pinned requirements (about a minute the first time)"
  install_requirements >"$STAMPS/pip.log" 2>&1 \
    || { grep -v 'is ignored: it is neither' "$STAMPS/pip.log" | tail -30; return 1; }
  echo "$want" >"$STAMPS/venv"
  log "Python venv: done in $(elapsed "$start")"
}

step_pouchdb() {
  local start want dir=tools/pouchdb-server
  start=$(date +%s)
  want=$(hash_of "$dir/package.json" "$dir/package-lock.json")
  if [ -x "$dir/node_modules/.bin/pouchdb-server" ] && stamp_matches pouchdb "$want"; then
    log "pouchdb-server: up to date"
    return
  fi
  log "pouchdb-server: npm ci (about 20 seconds the first time)"
  # Install scripts run for leveldown only (it picks its prebuilt binary, or builds one where none
  # fits). sqlite3 is pouchdb-server's optional SQLite adapter, never used here; its script
  # compiled SQLite from source (about 70 CPU-seconds) because its binaries are not on npm.
  (cd "$dir" && npm ci --no-audit --no-fund --loglevel=error --ignore-scripts \
    && npm rebuild leveldown --loglevel=error) >"$STAMPS/npm.log" 2>&1 \
    || { tail -30 "$STAMPS/npm.log"; return 1; }
  echo "$want" >"$STAMPS/pouchdb"
  log "pouchdb-server: done in $(elapsed "$start")"
}

step_catkin() {
  local start want files
  start=$(date +%s)
  # What changes the build: manifests, CMake files, setup.py, message/service definitions, nodes.
  mapfile -t files < <(find src -mindepth 2 \( -name package.xml -o -name CMakeLists.txt \
    -o -name setup.py -o -name '*.msg' -o -name '*.srv' -o -name '*.action' -o -path '*/nodes/*' \) | LC_ALL=C sort)
  want=$(hash_of "${files[@]}")
  if [ -f devel/setup.bash ] && stamp_matches catkin "$want"; then
    log "catkin workspace: up to date"
    return
  fi
  log "catkin workspace: catkin_make"
  # Debian's catkin must not see a pyenv shim (README, Troubleshooting). The venv's Python (made
  # from /usr/bin/python3, so it sees catkin_pkg) goes into the devel-space node relays' shebang,
  # so nodes started by roslaunch see the pinned pip packages.
  (PATH="/usr/bin:/bin:$PATH" catkin_make -DPYTHON_EXECUTABLE="$ROOT/.venv/bin/python3" \
    -DCATKIN_ENABLE_TESTING=ON --force-cmake) >"$STAMPS/catkin.log" 2>&1 \
    || { tail -40 "$STAMPS/catkin.log"; exit 1; }
  echo "$want" >"$STAMPS/catkin"
  log "catkin workspace: done in $(elapsed "$start")"
}

main() {
  local start npm_pid
  start=$(date +%s)
  # One set-up at a time (parallel `make test` runs would otherwise race in catkin_make and pip).
  exec 9>"$STAMPS/lock"
  flock 9
  step_apt
  # The venv and pouchdb-server mostly wait on downloads: both at once.
  step_pouchdb &
  npm_pid=$!
  step_venv || { wait "$npm_pid" || true; exit 1; }
  wait "$npm_pid" || exit 1
  step_catkin
  log "ready in $(elapsed "$start"); use it by hand with: source env.sh"
}

main "$@"
