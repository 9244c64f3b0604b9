#!/usr/bin/env bash
# Installs what is missing and builds the package in a catkin workspace outside the repository,
# which is linked into its src/. Usage: scripts/build.sh [extra catkin_make arguments]
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
bash "$REPO_DIR/scripts/install_deps.sh"
mkdir -p "$WS_DIR/src"
ln -sfn "$REPO_DIR" "$WS_DIR/src/modal_mass_spring"
cd "$WS_DIR"
catkin_make -j"$JOBS" -DCMAKE_BUILD_TYPE=Release "$@"
