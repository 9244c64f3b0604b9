#!/usr/bin/env python3
"""Rostest checker: one launch's parameters do not leak into the next on the same master. Runs
simulation.launch on the cloth config, stops it, runs it on the default config and checks that the
node's parameters are exactly the default config's (before clear_params, the cloth's linearization,
integrator, bending springs ... stayed and were used). Also: every node of every launch file clears
its parameters; rviz is started only where it is installed and a display exists, and the default
launch runs headless without an error, saying why rviz is left out; the basis argument starts the
skinning span with its default weights."""
import glob
import os
import signal
import subprocess
import sys
import tempfile
import time
import unittest
import xml.etree.ElementTree as ElementTree

import rospkg
import rospy
import rostest
from modal_mass_spring.cfg import SimulationConfig
import yaml

NODE = "/modal_mass_spring"


def launch(*args, env=None):
    return subprocess.Popen(["roslaunch", "modal_mass_spring", "simulation.launch"] + list(args),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace",
                            start_new_session=True, env=env)


def read_until(process, done, timeout=90.0):
    """The output read until done(output so far) holds (None if it never does)."""
    lines = []
    end = time.time() + timeout
    while time.time() < end:
        line = process.stdout.readline()
        if not line:
            break
        lines.append(line)
        if done("".join(lines)):
            return "".join(lines)
    return None


def rviz_if_available(args, **env):
    """Runs scripts/rviz_if_available.py with `env` over the environment (None: unset)."""
    environ = dict(os.environ)
    for name, value in env.items():
        if value is None:
            environ.pop(name, None)
        else:
            environ[name] = value
    script = os.path.join(rospkg.RosPack().get_path("modal_mass_spring"), "scripts", "rviz_if_available.py")
    return subprocess.run([script] + args, env=environ, capture_output=True, text=True, timeout=30)


def wait_for_start_up(process, timeout=90.0):
    """The node's output up to its linearization line (the second start-up line)."""
    return read_until(process, lambda out: "linearization " in out and "integrator " in out, timeout)


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
        cloth = launch("rviz:=false", "config:=" + os.path.join(package, "config", "cloth.yaml"))
        output = wait_for_start_up(cloth)
        stop(cloth)
        self.assertIsNotNone(output, "the cloth did not come up")
        self.assertIn("linearization equilibrium, integrator implicit", output)

        default = launch("rviz:=false")
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

    def test_rviz_starts_only_where_it_is_installed_and_a_display_exists(self):
        with tempfile.TemporaryDirectory() as empty:
            headless = rviz_if_available(["-d", "x.rviz"], DISPLAY=None, WAYLAND_DISPLAY=None)
            self.assertEqual(headless.returncode, 0, headless.stderr)
            self.assertIn("rviz not started: no display", headless.stderr)
            missing = rviz_if_available(["-d", "x.rviz"], DISPLAY=":99", ROS_PACKAGE_PATH=empty)
            self.assertEqual(missing.returncode, 0, missing.stderr)
            self.assertIn("rviz not started: rviz is not installed", missing.stderr)
        # Installed (a package rviz on the path) and a display: rviz is run with every argument.
        with tempfile.TemporaryDirectory() as root:
            os.makedirs(os.path.join(root, "rviz"))
            with open(os.path.join(root, "rviz", "package.xml"), "w") as manifest:
                manifest.write("<package><name>rviz</name><version>0.0.0</version></package>")
            os.makedirs(os.path.join(root, "bin"))
            rosrun = os.path.join(root, "bin", "rosrun")
            with open(rosrun, "w") as fake:
                fake.write('#!/bin/sh\necho "rosrun $*"\n')
            os.chmod(rosrun, 0o755)
            started = rviz_if_available(["-d", "x.rviz", "__name:=rviz"], DISPLAY=":99", ROS_PACKAGE_PATH=root,
                                        PATH=os.path.join(root, "bin") + os.pathsep + os.environ["PATH"])
            self.assertEqual(started.returncode, 0, started.stderr)
            self.assertEqual(started.stdout.strip(), "rosrun rviz rviz -d x.rviz __name:=rviz")

    def test_the_default_launch_runs_headless_and_says_why_rviz_is_left_out(self):
        environ = dict(os.environ)
        environ.pop("DISPLAY", None)
        environ.pop("WAYLAND_DISPLAY", None)
        default = launch(env=environ)  # rviz:=true, the default
        try:
            output = read_until(default, lambda out: "rviz not started" in out and "linearization " in out)
            self.assertIsNotNone(output, "no start-up line, or no word about rviz")
            self.assertIn("rviz not started: no display", output)
            self.assertNotIn("cannot launch node", output)
        finally:
            stop(default)

    def test_the_basis_argument_starts_the_skinning_span_with_24_weights(self):
        package = rospkg.RosPack().get_path("modal_mass_spring")
        held = launch("rviz:=false", "basis:=skinning", "config:=" + os.path.join(package, "config", "held_cloth.yaml"))
        try:
            output = read_until(held, lambda out: "basis skinning" in out or "FATAL" in out)
            self.assertIsNotNone(output, "no basis line")
            self.assertNotIn("FATAL", output)
            self.assertIn("basis skinning (skinning: 24 weights, 288 coordinates", output)
        finally:
            stop(held)


if __name__ == "__main__":
    rospy.init_node("check_launch_params", anonymous=True)
    rostest.rosrun("modal_mass_spring", "check_launch_params", LaunchParameters, sys.argv)
