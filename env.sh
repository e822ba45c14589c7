# Source this file (bash) to use the workspace by hand: `source env.sh`
# It sources the catkin devel space and activates the Python venv that scripts/setup.sh made,
# so roslaunch, rosrun, rosservice and the nodes see rospy and the pinned pip packages.
_ws_root="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
if [ ! -f "$_ws_root/devel/setup.bash" ] || [ ! -x "$_ws_root/.venv/bin/python" ]; then
  echo "env.sh: the workspace is not set up yet; run: bash $_ws_root/scripts/setup.sh" >&2
  return 1 2>/dev/null || exit 1
fi
# shellcheck disable=SC1091
source "$_ws_root/devel/setup.bash"
# shellcheck disable=SC1091
VIRTUAL_ENV_DISABLE_PROMPT=1 source "$_ws_root/.venv/bin/activate"
export ROBOT_WS_ROOT="$_ws_root"
export POUCHDB_SERVER_BIN="$_ws_root/tools/pouchdb-server/node_modules/.bin/pouchdb-server"
# TensorFlow: quiet start-up logs, CPU only
export TF_CPP_MIN_LOG_LEVEL="${TF_CPP_MIN_LOG_LEVEL:-2}"
export CUDA_VISIBLE_DEVICES="${CUDA_VISIBLE_DEVICES:-}"
unset _ws_root
