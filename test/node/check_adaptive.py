#!/usr/bin/env python3
"""Rostest checker of method adaptive in the node (adaptive.test): the switch to full where the error
estimate is above error_tolerance, logged once per switch; a run that stays reduced; the /diagnostics
warning of a plain reduced method above its tolerance; ~set_method to adaptive and its refusals."""
import math
import sys
import threading
import time
import unittest

import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from modal_mass_spring.msg import Status
from modal_mass_spring.srv import SetMethod
from rosgraph_msgs.msg import Log
from std_srvs.srv import Trigger


class Logs:
    """Every /rosout message from the start, by node name."""

    def __init__(self):
        self.lock = threading.Lock()
        self.messages = []
        self.sub = rospy.Subscriber("/rosout", Log, self.add, queue_size=1000)

    def add(self, log):
        with self.lock:
            self.messages.append((log.name, log.msg))

    def of(self, node, text):
        with self.lock:
            return [m for name, m in self.messages if name == node and text in m]


LOGS = None


def status(node, accept=lambda s: True, timeout=30.0):
    """The first ~status of `node` that `accept` takes, or None."""
    end = time.time() + timeout
    while time.time() < end and not rospy.is_shutdown():
        try:
            s = rospy.wait_for_message(node + "/status", Status, timeout=max(0.1, end - time.time()))
        except rospy.ROSException:
            return None
        if accept(s):
            return s
    return None


def finite(s):
    return all(math.isfinite(v) for v in (s.error_estimate, s.reduced_share, s.rms_distance, s.total_energy))


def warning(node):
    """The first WARN naming error_tolerance that `node` puts in /diagnostics within 20 s, or a failure."""
    found = []

    def take(array):
        for d in array.status:
            if d.name.lstrip("/").startswith(node + ":") and d.level == DiagnosticStatus.WARN and "above error_tolerance" in d.message:
                found.append(d)

    sub = rospy.Subscriber("/diagnostics", DiagnosticArray, take)
    end = time.time() + 20.0
    while not found and time.time() < end:
        time.sleep(0.1)
    sub.unregister()
    if not found:
        raise AssertionError("no WARN naming error_tolerance from /" + node)
    return found[0]


class Adaptive(unittest.TestCase):
    def test_a_tolerance_it_cannot_meet_falls_back_to_full_and_logs_each_switch_once(self):
        # Its first switch came before this checker listened: a reset starts the stepper again.
        status("/tight")
        rospy.wait_for_service("/tight/reset", timeout=30.0)
        reset_at = len(LOGS.of("/tight", "adaptive: to "))
        reply = rospy.ServiceProxy("/tight/reset", Trigger)()
        self.assertTrue(reply.success, reply.message)
        self.assertIn("method adaptive", reply.message)
        s = status("/tight", lambda s: s.switches >= 1 and s.step_count > 500)
        self.assertIsNotNone(s, "no switch to full within 30 s of the reset")
        self.assertEqual(s.method, "adaptive")
        self.assertEqual(s.active_method, "full")
        self.assertLess(s.reduced_share, 1.0)
        self.assertTrue(finite(s), s)
        # Under full its estimate is the distance to the span, which never comes within 0.1 mm here.
        self.assertGreater(s.error_estimate, 1e-4)
        time.sleep(1.0)  # the switches' lines reach /rosout
        later = status("/tight")
        self.assertIsNotNone(later)
        switches = LOGS.of("/tight", "adaptive: to ")[reset_at:]
        self.assertEqual(len(switches), later.switches, switches)
        self.assertIn("above error_tolerance 0.0001 m", switches[0])

    def test_a_loose_tolerance_stays_reduced(self):
        s = status("/loose", lambda s: s.step_count > 2000)
        self.assertIsNotNone(s)
        self.assertEqual((s.method, s.active_method, s.switches), ("adaptive", "physical", 0))
        self.assertEqual(s.reduced_share, 1.0)
        self.assertTrue(finite(s), s)
        self.assertGreater(s.error_estimate, 0.0, "the indicator sees the swing outside the modes")
        self.assertEqual(LOGS.of("/loose", "adaptive: to "), [])

    def test_a_plain_reduced_method_above_its_tolerance_warns_in_diagnostics(self):
        s = status("/plain", lambda s: s.error_estimate > 0.0)
        self.assertIsNotNone(s, "no error estimate in ~status")
        self.assertEqual((s.method, s.active_method, s.switches, s.reduced_share), ("physical", "physical", 0, 1.0))
        self.assertIn("method adaptive falls back to full", warning("plain").message)

    def test_the_coarse_grid_falls_back_and_warns_as_the_modes_do(self):
        s = status("/coarse", lambda s: s.switches >= 1)
        self.assertIsNotNone(s, "adaptive on the coarse grid did not fall back to full within 30 s")
        self.assertEqual((s.method, s.active_method), ("adaptive", "full"))
        self.assertTrue(finite(s), s)
        s = status("/plain_coarse", lambda s: s.error_estimate > 0.0)
        self.assertIsNotNone(s, "no error estimate of the coarse grid in ~status")
        self.assertEqual((s.method, s.active_method), ("coarse", "coarse"))
        warning("plain_coarse")

    def test_z_set_method_takes_adaptive_and_names_it_among_the_methods(self):
        rospy.wait_for_service("/plain/set_method", timeout=30.0)
        set_method = rospy.ServiceProxy("/plain/set_method", SetMethod)
        # From the start again, where the swing the tolerance cannot follow is ahead.
        self.assertTrue(rospy.ServiceProxy("/plain/reset", Trigger)().success)
        bad = set_method("adaptiv")
        self.assertFalse(bad.success)
        self.assertIn("must be one of full, linear, physical, cubature, coarse, adaptive", bad.message)
        reply = set_method("adaptive")
        self.assertTrue(reply.success, reply.message)
        self.assertIn("from physical to adaptive", reply.message)
        s = status("/plain", lambda s: s.method == "adaptive" and s.switches >= 1)
        self.assertIsNotNone(s, "adaptive after ~set_method did not fall back to full within 30 s")
        self.assertEqual(s.active_method, "full")
        back = set_method("physical")
        self.assertTrue(back.success, back.message)
        s = status("/plain", lambda s: s.method == "physical")
        self.assertIsNotNone(s)
        self.assertEqual((s.active_method, s.switches), ("physical", 0))


if __name__ == "__main__":
    rospy.init_node("check_adaptive")
    LOGS = Logs()
    rostest.rosrun("modal_mass_spring", "adaptive", Adaptive, sys.argv)
