#!/usr/bin/env python3
"""Rostest checker of ~set_colliders (set_colliders.test): a cloth lying on a box table; the bad
requests are refused by name with what is allowed and change nothing; the table replaced live by a
higher, shifted box and then by a sphere, each with the cloth inside it when it appears, leaves no
free particle more than 1 mm inside any collider once it has been pushed out; a collider removed."""
import math
import sys
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
import sensor_msgs.point_cloud2 as point_cloud2
from dynamic_reconfigure.client import Client
from geometry_msgs.msg import Pose
from modal_mass_spring.msg import PlacedCollider
from modal_mass_spring.srv import GetState, SetColliders, SetCollidersRequest, SetState
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import PointCloud2
from shape_msgs.msg import SolidPrimitive

NODE = "/modal_mass_spring"
COLS = 10
FLOOR = -0.5


class Points:
    def __init__(self):
        self.lock = threading.Lock()
        self.clouds = []  # (wall time, free particles as an n x 3 array)
        self.sub = rospy.Subscriber(NODE + "/points", PointCloud2, self.on_points, queue_size=10)

    def on_points(self, msg):
        xyz = np.array(list(point_cloud2.read_points(msg, field_names=("x", "y", "z"))), dtype=float)
        with self.lock:
            self.clouds.append((time.time(), xyz[COLS:]))  # row 0 is fixed

    def latest(self):
        with self.lock:
            return self.clouds[-1][1]

    def since(self, start):
        with self.lock:
            return [c for t, c in self.clouds if t >= start]


def placed(id, kind, dimensions, position, friction=0.5):
    c = PlacedCollider(id=id, friction=friction)
    c.shape = SolidPrimitive(type=kind, dimensions=list(dimensions))
    c.pose = Pose()
    c.pose.position.x, c.pose.position.y, c.pose.position.z = position
    c.pose.orientation.w = 1.0
    return c


def box_depth(points, position, dimensions):
    """How far each point is inside an axis-aligned box (<= 0 outside)."""
    inside = 0.5 * np.array(dimensions) - np.abs(points - np.array(position))
    return inside.min(axis=1)


def sphere_depth(points, position, radius):
    return radius - np.linalg.norm(points - np.array(position), axis=1)


class SetsCollidersLive(unittest.TestCase):
    def setUp(self):
        rospy.wait_for_service(NODE + "/set_colliders", timeout=60.0)
        self.call = rospy.ServiceProxy(NODE + "/set_colliders", SetColliders)
        self.points = Points()
        self.log = []
        self.log_sub = rospy.Subscriber("/rosout", Log, lambda m: self.log.append(m.msg), queue_size=1000)
        deadline = time.time() + 30.0
        while not self.points.since(0.0) and time.time() < deadline:
            time.sleep(0.1)
        self.assertTrue(self.points.since(0.0), "no ~points")

    def request(self, operation, colliders=(), remove=()):
        return self.call(SetCollidersRequest(operation=operation, colliders=list(colliders), remove=list(remove)))

    def deepest_after(self, depth, settle=1.0, watch=1.0):
        """The deepest a free particle is inside, over `watch` s of clouds after `settle` s."""
        time.sleep(settle)
        start = time.time()
        time.sleep(watch)
        clouds = self.points.since(start)
        self.assertGreater(len(clouds), 5)
        return max(max(depth(c).max(), (FLOOR - c[:, 2]).max()) for c in clouds)

    def test_replaced_live_while_the_cloth_lies_on_them(self):
        time.sleep(1.0)  # lying on the table
        lying = np.median(self.points.latest()[:, 2])
        saved = rospy.ServiceProxy(NODE + "/get_state", GetState)().state
        good = placed("table", SolidPrimitive.BOX, [0.8, 0.55, 0.2], (0.25, 0.36, -0.08))
        ids = ["table", "collider_1"]

        # Every bad request: refused by name with what is allowed, nothing changed.
        def spoiled(**change):
            c = placed("table", SolidPrimitive.BOX, [0.8, 0.55, 0.2], (0.25, 0.36, -0.08))
            for key, value in change.items():
                if key == "x":
                    c.pose.position.x = value
                elif key == "qw":
                    c.pose.orientation.w = value
                elif key == "dimensions":
                    c.shape.dimensions = value
                elif key == "type":
                    c.shape.type = value
                else:
                    setattr(c, key, value)
            return c
        bad = [
            ([spoiled(x=float("nan"))], [], "colliders[0] ('table').pose.position"),
            ([spoiled(qw=0.0)], [], "must be a unit quaternion"),
            ([spoiled(dimensions=[0.8, -0.55, 0.2])], [], "each must be a number > 0"),
            ([spoiled(dimensions=[0.8, float("nan"), 0.2])], [], ".shape.dimensions"),
            ([spoiled(dimensions=[0.8, 0.55])], [], "needs 3 numbers"),
            ([spoiled(type=SolidPrimitive.CONE)], [], "CONE is refused"),
            ([spoiled(type=7)], [], ".shape.type = 7"),
            ([spoiled(friction=-0.1)], [], ".friction = -0.1: must be a finite Coulomb coefficient >= 0"),
            ([spoiled(friction=float("nan"))], [], ".friction = nan"),
            ([good, spoiled(id="table")], [], "colliders[1].id = 'table': is also the id of colliders[0]"),
            ([], ["chair"], "remove[0] = 'chair': is not a collider's id (the colliders: 'table', 'collider_1')"),
        ]
        for colliders, remove, said in bad:
            reply = self.request(SetCollidersRequest.UPDATE, colliders, remove)
            self.assertFalse(reply.success, said)
            self.assertIn(said, reply.message)
            self.assertIn("nothing changed", reply.message)
            self.assertEqual(list(reply.ids), ids)
        reply = self.request(SetCollidersRequest.SET, [good], ["table"])
        self.assertFalse(reply.success)
        self.assertIn("must be empty with SET", reply.message)
        reply = self.request(9)
        self.assertFalse(reply.success)
        self.assertIn("operation = 9", reply.message)
        time.sleep(0.5)
        # Nothing changed: the cloth still lies at the old table's height.
        self.assertLess(abs(np.median(self.points.latest()[:, 2]) - lying), 0.005)

        # A higher (2 cm), shifted table: the cloth is inside it when it appears, then on it.
        higher = (0.25, 0.36, -0.08), [0.8, 0.55, 0.2]
        self.assertGreater(box_depth(self.points.latest(), *higher).max(), 0.015)
        reply = self.request(SetCollidersRequest.UPDATE, [good])
        self.assertTrue(reply.success, reply.message)
        self.assertEqual(list(reply.ids), ids)
        deepest = self.deepest_after(lambda c: box_depth(c, *higher))
        self.assertLess(deepest, 1e-3)
        self.assertGreater(np.median(self.points.latest()[:, 2]), 0.015, "the cloth lies on the higher table")

        # A state saved before the change, put back: the cloth inside the table again, which stays where
        # it was set (not where the state's colliders stood), and is pushed out once more.
        reply = rospy.ServiceProxy(NODE + "/set_state", SetState)(saved)
        self.assertTrue(reply.success, reply.message)
        self.assertLess(self.deepest_after(lambda c: box_depth(c, *higher)), 1e-3)
        self.assertAlmostEqual(np.median(self.points.latest()[2 * COLS:, 2]), 0.025, delta=0.003)

        # contact_thickness live: 1 cm from the next step, the cloth lifted to it on the table.
        client = Client(NODE, timeout=30)
        client.update_configuration({"contact_thickness": 0.01})
        time.sleep(1.5)
        on_top = self.points.latest()[2 * COLS:, 2]  # the rows over the table
        self.assertAlmostEqual(np.median(on_top), 0.03, delta=0.002)
        # A rebuild builds with the colliders set live, though the grid's start is inside the table now.
        client.update_configuration({"structural_stiffness": 60.0})
        deadline = time.time() + 90.0
        while time.time() < deadline and not any("rebuilt model swapped in" in m or "rebuild failed" in m for m in self.log):
            time.sleep(0.2)
        self.assertTrue(any("rebuilt model swapped in" in m for m in self.log), [m for m in self.log if "rebuil" in m])
        client.update_configuration({"contact_thickness": 0.0})
        self.assertLess(self.deepest_after(lambda c: box_depth(c, *higher)), 1e-3)

        # The table replaced by a ball under the cloth's middle, its top 2.5 cm above the cloth.
        ball = (0.225, 0.3, -0.1), 0.15
        self.assertGreater(sphere_depth(self.points.latest(), *ball).max(), 0.015)
        reply = self.request(SetCollidersRequest.UPDATE, [placed("table", SolidPrimitive.SPHERE, [0.15], ball[0])])
        self.assertTrue(reply.success, reply.message)
        # Watched from a few steps on, while it lies over the ball, until it has slid off the far side.
        start = time.time()
        deepest = self.deepest_after(lambda c: sphere_depth(c, *ball), settle=0.2, watch=1.5)
        self.assertLess(deepest, 1e-3)
        self.assertGreater(max(c[:, 2].max() for c in self.points.since(start)), 0.04, "the ball lifted the cloth")

        # Removed: the cloth falls off where the ball was, onto nothing but the floor.
        reply = self.request(SetCollidersRequest.UPDATE, remove=["table"])
        self.assertTrue(reply.success, reply.message)
        self.assertEqual(list(reply.ids), ["collider_1"])
        start = time.time()
        time.sleep(1.5)
        lowest = min(c[:, 2].min() for c in self.points.since(start))
        self.assertLess(lowest, -0.1, "the cloth falls where the ball was")


if __name__ == "__main__":
    rospy.init_node("check_set_colliders", anonymous=True)
    rostest.rosrun("modal_mass_spring", "check_set_colliders", SetsCollidersLive, sys.argv)
