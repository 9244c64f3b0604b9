#!/usr/bin/env python3
"""Rostest checker of the main job: scripts/run.sh exits non-zero when the node refuses its parameters
(roslaunch itself exits 0 when a required node dies), and 0 when it ran for the whole duration.
Runs run.sh with BUILD=0 against the workspace this test was built in, on the rostest master."""
import os
import subprocess
import sys
import unittest

import rospkg
import rospy
import rostest
from roslib.packages import find_node


def run_sh(*args):
    repo = rospkg.RosPack().get_path("modal_mass_spring")
    node = find_node("modal_mass_spring", "modal_mass_spring_node")[0]
    workspace = os.path.abspath(os.path.join(os.path.dirname(node), "..", "..", ".."))
    env = dict(os.environ, BUILD="0", MODAL_WS=workspace)
    env.pop("DISPLAY", None)
    env.pop("DURATION", None)
    return subprocess.run(["bash", os.path.join(repo, "scripts", "run.sh")] + list(args), env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace",
                          timeout=120)


class RunSh(unittest.TestCase):
    def test_a_bad_parameter_fails_the_job(self):
        run = run_sh("30", "method:=bogus")
        self.assertEqual(run.returncode, 1, run.stdout)
        self.assertIn("the simulation node failed", run.stdout)
        self.assertIn("invalid parameter 'method' = 'bogus'", run.stdout)
        self.assertNotIn("stopped after", run.stdout, "it did not run for the whole duration")

    def test_a_good_run_ends_with_zero(self):
        run = run_sh("4")
        self.assertEqual(run.returncode, 0, run.stdout)
        self.assertIn("grid (2D, 25 particles", run.stdout)
        self.assertIn("stopped after 4 s", run.stdout)


if __name__ == "__main__":
    rospy.init_node("check_run_sh", anonymous=True)
    rostest.rosrun("modal_mass_spring", "check_run_sh", RunSh, sys.argv)
