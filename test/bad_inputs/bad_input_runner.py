#!/usr/bin/env python3
"""Runs a program on a table of bad inputs and writes one JUnit test case per input.

Each case must end with the expected exit code (2 unless told otherwise), print a message that
names what was wrong (or, for an extreme input that must give a correct result, says it), not be
killed by a signal, not hang, and write no file (unless it is such a run). A case runs in a
fresh empty folder (its working directory), where its config files are written first; anything
else found there afterwards, or in the folder the case names as its output, is a file it wrote.

Used by modal_compare_bad_inputs.py; other tables (the node's) can import Case and run_cases.
"""
import dataclasses
import os
import pathlib
import shlex
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET


@dataclasses.dataclass
class Case:
    name: str                  # unique; the JUnit test case name
    args: list                 # arguments after the program; "{work}" is replaced by the case's folder
    named: str                 # text the message must contain (what was wrong)
    files: dict = dataclasses.field(default_factory=dict)  # file name -> text, written into {work} first
    code: int = 2              # the expected exit code
    shell_prefix: str = ""     # e.g. "ulimit -v 300000; " (the case then runs through bash)
    writes: bool = False       # a run that must finish with a correct result: it may write its results
    absent: str = ""           # text the output must not contain (e.g. "diverged" for such a run)


def run_case(program, case, timeout):
    """Returns a list of problems; empty when the case behaved."""
    with tempfile.TemporaryDirectory(prefix="bad_input_") as work:
        work = pathlib.Path(work)
        for name, text in case.files.items():
            (work / name).write_text(text)
        before = {p for p in work.rglob("*")}
        args = [a.replace("{work}", str(work)) for a in case.args]
        command = [program] + args
        if case.shell_prefix:
            command = ["bash", "-c", case.shell_prefix + " ".join(shlex.quote(c) for c in command)]
        start = time.monotonic()
        try:
            result = subprocess.run(command, cwd=work, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return [f"no answer within {timeout} s (hangs?)"], ""
        seconds = time.monotonic() - start
        output = result.stdout + result.stderr
        problems = []
        if result.returncode < 0 or result.returncode > 128:
            problems.append(f"killed by a signal (return code {result.returncode})")
        elif result.returncode != case.code:
            problems.append(f"exit code {result.returncode}, expected {case.code}")
        if case.named not in output:
            problems.append(f"the message does not name {case.named!r}")
        if case.absent and case.absent in output:
            problems.append(f"the output says {case.absent!r}")
        written = sorted(str(p.relative_to(work)) for p in work.rglob("*") if p not in before)
        if written and not case.writes:
            problems.append(f"wrote {', '.join(written)}")
        return problems, f"$ {' '.join(shlex.quote(c) for c in command)}\n{output}({seconds:.2f} s)\n"


def run_cases(program, cases, suite, xunit_path, timeout=30.0):
    """Runs every case, prints a line each, writes the JUnit file; returns the number failed."""
    names = [c.name for c in cases]
    duplicates = {n for n in names if names.count(n) > 1}
    if duplicates:
        raise ValueError(f"case names used twice: {', '.join(sorted(duplicates))}")
    root = ET.Element("testsuite", name=suite, tests=str(len(cases)))
    failed = 0
    start = time.monotonic()
    for case in cases:
        problems, log = run_case(program, case, timeout)
        element = ET.SubElement(root, "testcase", classname=suite, name=case.name)
        if problems:
            failed += 1
            failure = ET.SubElement(element, "failure", message="; ".join(problems))
            failure.text = log
            print(f"FAILED {case.name}: {'; '.join(problems)}\n{log}")
        else:
            ET.SubElement(element, "system-out").text = log
    root.set("failures", str(failed))
    root.set("errors", "0")
    root.set("time", f"{time.monotonic() - start:.2f}")
    if xunit_path:
        os.makedirs(os.path.dirname(os.path.abspath(xunit_path)), exist_ok=True)
        ET.ElementTree(root).write(xunit_path, encoding="utf-8", xml_declaration=True)
    print(f"{suite}: {len(cases) - failed} of {len(cases)} bad inputs refused as expected "
          f"({time.monotonic() - start:.1f} s)")
    return failed


if __name__ == "__main__":
    sys.exit("bad_input_runner.py is a module: run a table such as modal_compare_bad_inputs.py")
