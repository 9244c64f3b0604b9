#!/usr/bin/env bash
# Sets up, builds and runs every test of the package (gtest and rostest), then runs the core's and
# the comparison tool's gtests once more under AddressSanitizer and UndefinedBehaviorSanitizer, and
# prints 'N passed, N failed' on the last line. Exits non-zero on any failure or error.
set -uo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
bash "$REPO_DIR/scripts/build.sh" -DWARNINGS_AS_ERRORS=ON -DSANITIZE=OFF || { echo "0 passed, 1 failed"; exit 1; }
cd "$WS_DIR"
rm -rf build/test_results
set +u; source devel/setup.bash; set -u  # catkin's setup reads unset variables
results="$WS_DIR/build/test_results/modal_mass_spring"
# run_tests exits 0 when tests fail (catkin_test_results counts those) but not when a test does not
# build: then that is a failure of its own, or the tests that did not build would go uncounted.
if ! catkin_make -j"$JOBS" run_tests; then
  mkdir -p "$results"
  printf '<testsuites><testsuite name="build"><testcase classname="build" name="run_tests"><failure message="catkin_make run_tests failed: a test did not build (see the log above)"/></testcase></testsuite></testsuites>\n' \
    > "$results/build-run_tests.xml"
fi

# The sanitized gtests, in a workspace of their own; each writes its results beside the others.
# Warnings are not errors there: the sanitizers' instrumentation makes GCC see uninitialised values
# in the standard library that are not.
SANITIZE_WS="${WS_DIR}_sanitize"
mkdir -p "$SANITIZE_WS/src" "$results"
ln -sfn "$REPO_DIR" "$SANITIZE_WS/src/modal_mass_spring"
if (cd "$SANITIZE_WS" && catkin_make -j"$JOBS" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DSANITIZE=ON \
      -DWARNINGS_AS_ERRORS=OFF test_core test_compare); then
  for test in test_core test_compare; do
    xml="$results/sanitized-$test.xml"
    # The sanitized core library comes first: the sourced workspace would otherwise lend its own.
    (cd "$REPO_DIR" && LD_LIBRARY_PATH="$SANITIZE_WS/devel/lib:${LD_LIBRARY_PATH:-}" \
        ASAN_OPTIONS=detect_leaks=1:abort_on_error=0 UBSAN_OPTIONS=print_stacktrace=1 \
        "$SANITIZE_WS/devel/lib/modal_mass_spring/$test" --gtest_output="xml:$xml")
    status=$?
    if [ $status -ne 0 ] && ! grep -q "<failure" "$xml" 2>/dev/null; then
      # A sanitizer report ends the run before gtest writes a failure: record one.
      printf '<testsuites><testsuite name="sanitized"><testcase classname="sanitized" name="%s"><failure message="exit status %s under AddressSanitizer and UndefinedBehaviorSanitizer"/></testcase></testsuite></testsuites>\n' \
        "$test" "$status" > "$xml"
    fi
  done
else
  printf '<testsuites><testsuite name="sanitized"><testcase classname="sanitized" name="build"><failure message="the sanitized build failed"/></testcase></testsuite></testsuites>\n' \
    > "$results/sanitized-build.xml"
fi

catkin_test_results build/test_results
results_status=$?
/usr/bin/python3 "$REPO_DIR/scripts/count_results.py" build/test_results
count_status=$?
if [ $results_status -ne 0 ] || [ $count_status -ne 0 ]; then
  exit 1
fi
