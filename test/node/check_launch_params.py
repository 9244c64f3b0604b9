#!/usr/bin/env python3
"""Rostest checker: one launch's parameters do not leak into the next on the same master. Runs
simulation.launch on the cloth config, stops it, runs it on the default config and checks that the
node's parameters are exactly the default config's (before clear_params, the cloth's linearization,
integrator, bending springs ... stayed and were used). Also: every node of every launch file clears
its parameters."""
import glob
import os
import signal
import subprocess
import sys
import time
import unittest
import xml.etree.ElementTree as ElementTree

import rospkg
import rospy
import rostest
from modal_mass_spring.cfg import SimulationConfig
import yaml

NODE = "/modal_mass_spring"


def launch(*args):
    return subprocess.Popen(["roslaunch", "modal_mass_spring", "simulation.launch", "rviz:=false"] + list(args),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace",
                            start_new_session=True)


def wait_for_start_up(process, timeout=90.0):
    """The node's output up to its linearization line (the second start-up line)."""
    lines = []
    end = time.time() + timeout
    while time.time() < end:
        line = process.stdout.readline()
        if not line:
            break
        lines.append(line)
        if "linearization " in line and "integrator " in line:
            return "".join(lines)
    return None


def stop(process):
    os.killpg(process.pid, signal.SIGINT)
    try:
        process.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.communicate()


class LaunchParameters(unittest.TestCase):
    def test_every_node_clears_its_parameters(self):
        package = rospkg.RosPack().get_path("modal_mass_spring")
        files = glob.glob(os.path.join(package, "launch", "*.launch"))
        self.assertGreaterEqual(len(files), 2)
        for path in files:
            for node in ElementTree.parse(path).getroot().iter("node"):
                self.assertEqual(node.get("clear_params"), "true",
                                 "%s: node %s does not clear its parameters" % (path, node.get("name")))

    def test_no_parameter_leaks_from_one_launch_into_the_next(self):
        package = rospkg.RosPack().get_path("modal_mass_spring")
        cloth = launch("config:=" + os.path.join(package, "config", "cloth.yaml"))
        output = wait_for_start_up(cloth)
        stop(cloth)
        self.assertIsNotNone(output, "the cloth did not come up")
        self.assertIn("linearization equilibrium, integrator implicit", output)

        default = launch()
        output = wait_for_start_up(default)
        try:
            self.assertIsNotNone(output, "the default config did not come up")
            self.assertIn("linearization rest, integrator explicit", output)
            self.assertIn("5 x 5 grid (2D", output)
            with open(os.path.join(package, "config", "paper_2d.yaml")) as config:
                expected = set(yaml.safe_load(config))
            required = set(expected)
            expected.add("diagnostic_period")  # the node sets the checked value for diagnostic_updater
            # dynamic_reconfigure writes its values there once its server is up (maybe after this read).
            expected |= set(SimulationConfig.defaults)
            present = {name[len(NODE) + 1:].split("/")[0] for name in rospy.get_param_names()
                       if name.startswith(NODE + "/")}
            self.assertEqual(present - expected, set(), "left over from the cloth launch")
            self.assertEqual(required - present, set())
        finally:
            stop(default)


if __name__ == "__main__":
    rospy.init_node("check_launch_params", anonymous=True)
    rostest.rosrun("modal_mass_spring", "check_launch_params", LaunchParameters, sys.argv)
