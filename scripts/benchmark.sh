#!/usr/bin/env bash
# Builds the package and runs the core's Google Benchmark: medians of 5 repetitions.
# Extra arguments go to the benchmark, e.g. --benchmark_filter=Basis2D
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
bash "$REPO_DIR/scripts/build.sh" core_benchmark > /dev/null
"$WS_DIR/devel/lib/modal_mass_spring/core_benchmark" --benchmark_repetitions=5 \
  --benchmark_report_aggregates_only=true --benchmark_min_time=0.1 "$@" | grep -E "median|ERROR|^Run|^CPU|^Load"
