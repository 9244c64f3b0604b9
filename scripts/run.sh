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
#   BUILD=0 scripts/run.sh 20                skip installing and building (the workspace is built)
# Exits non-zero when a simulation node fails (a bad parameter: its FATAL line is repeated at the end).
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

if [ "${BUILD:-1}" != 0 ]; then
  echo "== [1/3] installing missing Debian packages (scripts/install_deps.sh)"
  bash "$REPO_DIR/scripts/install_deps.sh"
  echo "== [2/3] building in $WS_DIR (scripts/build.sh)"
  bash "$REPO_DIR/scripts/build.sh" >"$WS_DIR.build.log" 2>&1 || { tail -40 "$WS_DIR.build.log"; exit 1; }
  echo "   built; log in $WS_DIR.build.log"
fi
set +u; source "$WS_DIR/devel/setup.bash"; set -u

echo "== [3/3] roslaunch modal_mass_spring $launch rviz:=$rviz $*" \
     "($( [ "$rviz" = true ] && echo "display $DISPLAY" || echo "no display: headless"))," \
     "$( [ "$duration" != 0 ] && echo "stopping after $duration s" || echo "Ctrl-C to stop")"
echo "   topics: /modal_mass_spring/markers, /modal_mass_spring/status, /tf, /tf_static, /diagnostics;" \
     "services: /modal_mass_spring/{set_method,reset,pause}"

# roslaunch exits 0 when a required node dies, so its output tells whether the node failed: a
# simulation node that died with a non-zero exit code (a FATAL, or a crash by signal).
log="$(mktemp /tmp/modal_mass_spring_run.XXXXXX.log)"
trap ':' INT  # Ctrl-C reaches roslaunch, which shuts down cleanly; this script goes on to check the log
status=0
if [ "$duration" != 0 ]; then
  # SIGINT is roslaunch's own clean shutdown; timeout's 124 means it ran for the whole duration.
  timeout --signal=INT --kill-after=20 "$duration" roslaunch modal_mass_spring "$launch" rviz:="$rviz" "$@" 2>&1 \
    | tee -i "$log" || status=$?
else
  roslaunch modal_mass_spring "$launch" rviz:="$rviz" "$@" 2>&1 | tee -i "$log" || status=$?
fi
died="$(grep -aoE 'process has died \[pid [0-9]+, exit code -?[0-9]+, cmd [^ ]*modal_mass_spring_node' "$log" \
        | grep -avE 'exit code 0,' || true)"
fatal="$(grep -a '\[FATAL\]' "$log" | head -n 3 || true)"
rm -f "$log"
if [ -n "$died" ] || [ -n "$fatal" ]; then
  echo "== the simulation node failed:" >&2
  [ -n "$fatal" ] && echo "$fatal" >&2
  [ -n "$died" ] && echo "$died" >&2
  exit 1
fi
if [ "$status" -eq 124 ]; then
  echo "== stopped after $duration s"
  exit 0
fi
exit "$status"
