#!/usr/bin/env python3
"""Rostest checker: starts modal_mass_spring_node on parameters already loaded under ~node_name and
asserts that it refuses to come up: it exits by itself, non-zero, with one FATAL line that contains
~expect (the parameter, its value and what is allowed)."""
import os
import subprocess
import sys
import unittest

import rospy
import rostest
from roslib.packages import find_node


class RefusesBadParameter(unittest.TestCase):
    def test_exits_non_zero_with_its_message(self):
        node_name = rospy.get_param("~node_name")
        expected = rospy.get_param("~expect")
        executable = find_node("modal_mass_spring", "modal_mass_spring_node")
        self.assertTrue(executable, "modal_mass_spring_node not found")
        env = dict(os.environ, ROSCONSOLE_FORMAT="[${severity}] ${message}")
        try:
            run = subprocess.run([executable[0], "__name:=" + node_name], env=env, capture_output=True,
                                 text=True, timeout=60)
        except subprocess.TimeoutExpired:
            self.fail("the node did not exit within 60 s: it came up on a bad parameter")
        output = run.stdout + run.stderr
        self.assertNotEqual(run.returncode, 0, "exit code 0; output:\n" + output)
        fatal = [line for line in output.splitlines() if "[FATAL]" in line]
        self.assertEqual(len(fatal), 1, "expected one FATAL line; output:\n" + output)
        self.assertIn(expected, fatal[0])
        self.assertNotIn("grid (", output, "the node built a simulation before refusing")


if __name__ == "__main__":
    rospy.init_node("check_refuses", anonymous=True)
    rostest.rosrun("modal_mass_spring", "check_refuses", RefusesBadParameter, sys.argv)
