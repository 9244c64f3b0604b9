#!/usr/bin/env bash
# Builds the package and runs the core's Google Benchmark: medians of 5 repetitions.
# Extra arguments go to the benchmark, e.g. --benchmark_filter=Basis2D
# The basis against scipy's eigsh: /usr/bin/python3 benchmark/basis_vs_eigsh.py (needs the tests built,
# `catkin_make tests`, for basis_timing; python3-scipy is installed here, it is no test dependency).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/../scripts/env.sh"
if ! dpkg-query -W -f='${Status}' python3-scipy 2>/dev/null | grep -q "install ok installed"; then
  export DEBIAN_FRONTEND=noninteractive
  ${SUDO:-} apt-get update -q
  ${SUDO:-} apt-get install -y -q --no-install-recommends python3-scipy
fi
bash "$REPO_DIR/scripts/build.sh" core_benchmark > /dev/null
"$WS_DIR/devel/lib/modal_mass_spring/core_benchmark" --benchmark_repetitions=5 \
  --benchmark_report_aggregates_only=true --benchmark_min_time=0.1 "$@" | grep -E "median|ERROR|^Run|^CPU|^Load"
