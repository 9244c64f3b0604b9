#!/usr/bin/env bash
# Takes an rviz screenshot of a launch file under Xvfb (software rendering), for the README.
# Usage: scripts/screenshot.sh [launch file] [output png] [seconds to let it run] [roslaunch arguments...]
# Defaults: compare_methods.launch, docs/rviz_compare_methods.png, 8 s. Builds first if needed.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
launch="${1:-compare_methods.launch}"
output="$(realpath -m "${2:-$REPO_DIR/docs/rviz_compare_methods.png}")"
seconds="${3:-8}"
shift $(( $# < 3 ? $# : 3 ))
MODAL_VIEWER=1 bash "$REPO_DIR/scripts/install_deps.sh"
[ -x "$WS_DIR/devel/lib/modal_mass_spring/modal_mass_spring_node" ] || bash "$REPO_DIR/scripts/build.sh"
set +u; source "$WS_DIR/devel/setup.bash"; set -u

# MODAL_DISPLAY and MODAL_ROS_PORT pick the display and the master's port (default: random ones).
display="${MODAL_DISPLAY:-:$((90 + RANDOM % 100))}"
Xvfb "$display" -screen 0 1280x720x24 -nolisten tcp >/dev/null 2>&1 &
xvfb_pid=$!
port="${MODAL_ROS_PORT:-$((20000 + RANDOM % 10000))}"
export DISPLAY="$display" LIBGL_ALWAYS_SOFTWARE=1 ROS_MASTER_URI="http://localhost:$port"
roslaunch -p "$port" modal_mass_spring "$launch" rviz:=true "$@" >/tmp/modal_screenshot_roslaunch.log 2>&1 &
launch_pid=$!
cleanup() {
  kill -INT "$launch_pid" 2>/dev/null && wait "$launch_pid" 2>/dev/null || true
  kill "$xvfb_pid" 2>/dev/null || true
}
trap cleanup EXIT

echo "running $launch under Xvfb $display for $seconds s (log: /tmp/modal_screenshot_roslaunch.log)"
sleep "$seconds"
mkdir -p "$(dirname "$output")"
import -display "$display" -window root "$output"
echo "wrote $output"
