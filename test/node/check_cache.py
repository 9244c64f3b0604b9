#!/usr/bin/env python3
"""Rostest checker of what ~status says about the precomputation cache: the node of cache.test, whose
cache directory cannot be written, computed its basis and cubature and says so; a node started twice
here with a fresh cache directory computes and stores them the first time and loads them the second."""
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import unittest

import rospy
import rostest
from modal_mass_spring.msg import Status

NODE = "/modal_mass_spring"
PROBE = "/cache_probe"


def status(node):
    return rospy.wait_for_message(node + "/status", Status, timeout=60.0)


class CacheStatus(unittest.TestCase):
    def test_an_unwritable_cache_is_reported_as_computed(self):
        s = status(NODE)
        self.assertEqual(s.method, "cubature")
        self.assertFalse(s.basis_from_cache)
        self.assertFalse(s.cubature_from_cache)
        self.assertIn("basis computed and NOT stored in /proc/modal_mass_spring_cache", s.cache)
        self.assertIn("cubature trained and NOT stored in", s.cache)

    def test_a_second_start_loads_what_the_first_stored(self):
        for key, value in rospy.get_param(NODE).items():
            rospy.set_param(PROBE + "/" + key, value)
        directory = tempfile.mkdtemp(prefix="modal_cache_test_")
        rospy.set_param(PROBE + "/cache_dir", directory)
        seen = []
        try:
            for _ in range(2):
                node = subprocess.Popen(["rosrun", "modal_mass_spring", "modal_mass_spring_node", "__name:=cache_probe"],
                                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                try:
                    seen.append(status(PROBE))
                finally:
                    node.send_signal(signal.SIGINT)
                    node.wait(30)
        finally:
            shutil.rmtree(directory, ignore_errors=True)
        first, second = seen
        self.assertFalse(first.basis_from_cache)
        self.assertFalse(first.cubature_from_cache)
        self.assertIn("basis computed and stored in " + directory, first.cache)
        self.assertIn("cubature trained and stored in " + directory, first.cache)
        self.assertTrue(second.basis_from_cache)
        self.assertTrue(second.cubature_from_cache)
        self.assertIn("basis loaded from the cache " + directory, second.cache)
        self.assertIn("cubature loaded from " + directory, second.cache)


if __name__ == "__main__":
    rospy.init_node("check_cache")
    rostest.rosrun("modal_mass_spring", "check_cache", CacheStatus, sys.argv)
