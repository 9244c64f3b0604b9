#!/usr/bin/env bash
# Regenerates every CSV (docs/data/) and figure (docs/*.png) of the method comparison: builds the
# package, runs modal_compare on the paper's configs and draws the figures. The summary tables go to
# stdout and docs/data/summary.txt. Usage: scripts/compare.sh [modal_compare options for every run]
# COMPARE_BUILD=0 skips the build and uses the modal_compare already in the workspace.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

build_log="$(mktemp)"
if [ "${COMPARE_BUILD:-1}" != 0 ] && ! bash "$REPO_DIR/scripts/build.sh" >"$build_log" 2>&1; then
  tail -n 40 "$build_log"
  echo "compare.sh: the build failed (full log: $build_log)" >&2
  exit 1
fi
rm -f "$build_log"

tool="$WS_DIR/devel/lib/modal_mass_spring/modal_compare"
data="$REPO_DIR/docs/data"
configs="$REPO_DIR/config/compare"
mkdir -p "$data"
rm -f "$data"/*.csv

{
  echo "# modal_compare, $(date -u +%Y-%m-%dT%H:%MZ), commit $(git -C "$REPO_DIR" describe --always --dirty)"
  echo "# CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//'), $(nproc) cores," \
    "load average $(cut -d' ' -f1-3 /proc/loadavg) at the start (timings are only as quiet as the machine)"
  # The paper's experiments: cost over grid sizes, accuracy against full, largest stable step.
  "$tool" --config "$configs/paper_2d.yaml" --experiment all --sizes 5,10,20,40,80 --output "$data" "$@"
  "$tool" --config "$configs/paper_3d.yaml" --experiment all --sizes 5,10,20,40,80 --output "$data" "$@"
  # Beyond the paper: the same 2D setup with the basis at the hanging equilibrium and with the
  # implicit integrator (every combination).
  "$tool" --config "$configs/paper_2d.yaml" --tag paper_2d_variants --experiment accuracy,stability \
    --vary linearization=rest,equilibrium --vary integrator=explicit,implicit --sample 50 --output "$data" "$@"
  echo "# load average $(cut -d' ' -f1-3 /proc/loadavg) at the end"
} | tee "$data/summary.txt"

/usr/bin/python3 "$REPO_DIR/scripts/plot_comparison.py" --data "$data" --out "$REPO_DIR/docs"
