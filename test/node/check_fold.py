#!/usr/bin/env python3
"""Rostest checker of self-collision in the node (fold.test): while the grippers fold the towel,
~status reports self-collision's cost and the pairs it corrects, with the folded half kept a
thickness over the lower one (~points); a thickness above the spacing is refused live with nothing
changed, and self_collision turned off live stops its cost."""
import math
import sys
import time
import unittest

import rospy
import rostest
from dynamic_reconfigure.client import Client
from modal_mass_spring.msg import Status
from sensor_msgs import point_cloud2
from sensor_msgs.msg import PointCloud2

NODE = "/modal_mass_spring"
ROWS = COLS = 20


def status():
    return rospy.wait_for_message(NODE + "/status", Status, timeout=30.0)


def separated(p, q):
    return max(abs(p // COLS - q // COLS), abs(p % COLS - q % COLS)) > 2


class Fold(unittest.TestCase):
    def test_fold_cost_and_live_tuning(self):
        client = Client(NODE, timeout=30.0)
        thickness = client.get_configuration(timeout=30.0)["self_collision_thickness"]
        self.assertAlmostEqual(thickness, 0.008)
        # The grippers wait 1 s, then fold over 4 s: by 8 s of simulated time the halves touch.
        contacts = 0
        deadline = time.time() + 120.0
        while time.time() < deadline:
            s = status()
            if s.sim_time > 8.0:
                contacts = max(contacts, s.self_collision_contacts)
                if contacts > 0:
                    break
        self.assertGreater(contacts, 0, "no pair corrected after the fold")
        s = status()
        self.assertGreater(s.self_collision_seconds, 0.0)
        self.assertEqual(s.state, Status.RUNNING)
        # Every pair more than two springs apart at least the thickness less 1 mm apart (the held
        # corners, 380 and 399, take no part).
        cloud = rospy.wait_for_message(NODE + "/points", PointCloud2, timeout=30.0)
        pts = list(point_cloud2.read_points(cloud, field_names=("x", "y", "z")))
        self.assertEqual(len(pts), ROWS * COLS)
        closest = float("inf")
        for p in range(len(pts)):
            for q in range(p + 1, len(pts)):
                if p in (380, 399) or q in (380, 399) or not separated(p, q):
                    continue
                closest = min(closest, math.dist(pts[p], pts[q]))
        self.assertGreater(closest, thickness - 1e-3)
        # Refused live: a thickness above the spacing (0.025 m); nothing changes.
        result = client.update_configuration({"self_collision_thickness": 0.1})
        self.assertAlmostEqual(result["self_collision_thickness"], thickness)
        # Off live: no cost from the next step on.
        client.update_configuration({"self_collision": False})
        time.sleep(1.0)
        self.assertEqual(status().self_collision_seconds, 0.0)
        self.assertEqual(status().self_collision_contacts, 0)


if __name__ == "__main__":
    rospy.init_node("check_fold")
    rostest.rosrun("modal_mass_spring", "fold", Fold, sys.argv)
