#!/usr/bin/env bash
# Sets up, builds and runs every test of the package (gtest and rostest), then prints
# 'N passed, N failed' on the last line. Exits non-zero on any failure or error.
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
bash "$REPO_DIR/scripts/build.sh" || { echo "0 passed, 1 failed"; exit 1; }
cd "$WS_DIR"
rm -rf build/test_results
set +u; source devel/setup.bash; set -u  # catkin's setup reads unset variables
catkin_make -j2 run_tests
catkin_test_results build/test_results
results_status=$?
/usr/bin/python3 "$REPO_DIR/scripts/count_results.py" build/test_results
count_status=$?
if [ $results_status -ne 0 ] || [ $count_status -ne 0 ]; then
  exit 1
fi
