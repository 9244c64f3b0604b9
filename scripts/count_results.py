#!/usr/bin/env python3
"""Counts the test cases in the JUnit XML files under a folder; prints 'N passed, N failed'.

Exits 1 when any test failed or errored, or when no test ran at all.

Each rostest writes two files: rosunit-<test>.xml with the test's own cases, and rostest-<file>.xml
with one case per test node that only says whether the node ran and left results. The latter counts
only when it failed (a crash, a time-out, a fixture node that did not launch), so passes are not
counted twice and such failures are not missed. Disabled gtest cases (status="notrun") are skipped.
"""
import pathlib
import sys
import xml.etree.ElementTree as ET


def main(folder):
    passed = failed = skipped = 0
    for path in sorted(pathlib.Path(folder).rglob("*.xml")):
        try:
            root = ET.parse(path).getroot()
        except ET.ParseError as error:
            print(f"{path}: unreadable result file: {error}")
            failed += 1
            continue
        rostest_wrapper = path.name.startswith("rostest-")
        for case in root.iter("testcase"):
            if case.find("failure") is not None or case.find("error") is not None:
                failed += 1
                print(f"FAILED: {case.get('classname')}.{case.get('name')} ({path.name})")
            elif rostest_wrapper:
                continue
            elif case.find("skipped") is not None or case.get("status") == "notrun":
                skipped += 1
            else:
                passed += 1
    if passed + failed == 0:
        failed = 1
        print(f"no test results found under {folder}")
    line = f"{passed} passed, {failed} failed"
    if skipped:
        line += f", {skipped} skipped"
    print(line)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "build/test_results"))
