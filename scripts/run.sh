#!/usr/bin/env bash
# The main job: sets up this machine (Debian packages), builds, and runs the simulation node on the
# default config (config/paper_2d.yaml) through launch/simulation.launch: with rviz when $DISPLAY is
# set, headless otherwise. The node logs its start-up line (grid, modes, frequencies) and a status
# line every few seconds; roslaunch starts a ROS master when none is running.
#
# Usage: scripts/run.sh [duration in seconds] [roslaunch arguments...]
#   DURATION=20 scripts/run.sh              stop by itself after 20 s (0 or unset: run until Ctrl-C)
#   scripts/run.sh 0 method:=full           any simulation.launch argument: config:=, method:=, rviz:=
#   LAUNCH=compare_methods.launch scripts/run.sh 30    the three methods side by side
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
duration="${1:-${DURATION:-0}}"
[ $# -gt 0 ] && shift
launch="${LAUNCH:-simulation.launch}"

if [ -n "${DISPLAY:-}" ]; then
  rviz=true
  export MODAL_VIEWER=1  # install_deps.sh adds rviz
else
  rviz=false
fi

echo "== [1/3] installing missing Debian packages (scripts/install_deps.sh)"
bash "$REPO_DIR/scripts/install_deps.sh"
echo "== [2/3] building in $WS_DIR (scripts/build.sh)"
bash "$REPO_DIR/scripts/build.sh" >"$WS_DIR.build.log" 2>&1 || { tail -40 "$WS_DIR.build.log"; exit 1; }
echo "   built; log in $WS_DIR.build.log"
set +u; source "$WS_DIR/devel/setup.bash"; set -u

echo "== [3/3] roslaunch modal_mass_spring $launch rviz:=$rviz $*" \
     "($( [ "$rviz" = true ] && echo "display $DISPLAY" || echo "no display: headless"))," \
     "$( [ "$duration" != 0 ] && echo "stopping after $duration s" || echo "Ctrl-C to stop")"
echo "   topics: /modal_mass_spring/markers, /modal_mass_spring/status, /tf, /tf_static, /diagnostics;" \
     "services: /modal_mass_spring/{set_method,reset,pause}"
if [ "$duration" != 0 ]; then
  # SIGINT is roslaunch's own clean shutdown; timeout's 124 means it ran for the whole duration.
  status=0
  timeout --signal=INT --kill-after=20 "$duration" roslaunch modal_mass_spring "$launch" rviz:="$rviz" "$@" || status=$?
  if [ "$status" -eq 124 ]; then
    echo "== stopped after $duration s"
    exit 0
  fi
  exit "$status"
fi
exec roslaunch modal_mass_spring "$launch" rviz:="$rviz" "$@"
