#!/usr/bin/env python3
"""Rostest checker: records the node's markers and its gripper and table wrenches with rosbag, reads
the bag back and checks the colliders are drawn, the wrenches are finite geometry_msgs/WrenchStamped,
and the gripper holding the hanging cloth still (the first seconds of scripts/gripper.py, motion drag) carries
its weight."""
import math
import os
import subprocess
import sys
import tempfile
import time
import unittest

import rosbag
import rospy
import rostest


class RecordsCollidersAndWrenches(unittest.TestCase):
    def test_bag_holds_colliders_and_wrenches(self):
        node = rospy.get_param("~node", "/modal_mass_spring")
        duration = float(rospy.get_param("~duration", 5.0))
        weight = (rospy.get_param(node + "/rows") * rospy.get_param(node + "/cols") * rospy.get_param(node + "/mass")
                  * 9.81)
        handle, table = node + "/handle_force/handle_0", node + "/contact_force/collider_0"
        topics = [node + "/markers", handle, table]
        rospy.wait_for_message(node + "/status", rospy.AnyMsg, timeout=60.0)
        with tempfile.TemporaryDirectory() as folder:
            path = os.path.join(folder, "contact.bag")
            record = subprocess.run(["rosbag", "record", "--quiet", "-O", path, "--duration=%g" % duration] + topics,
                                    capture_output=True, text=True, timeout=duration + 60)
            self.assertEqual(record.returncode, 0, record.stderr)
            for _ in range(100):
                if os.path.exists(path):
                    break
                time.sleep(0.1)
            with rosbag.Bag(path) as bag:
                info = bag.get_type_and_topic_info().topics
                for topic in topics:
                    self.assertIn(topic, info, "bag has no " + topic)
                self.assertEqual(info[handle].msg_type, "geometry_msgs/WrenchStamped")
                self.assertEqual(info[table].msg_type, "geometry_msgs/WrenchStamped")
                namespaces = {m.ns for _, msg, _ in bag.read_messages(topics=[node + "/markers"]) for m in msg.markers}
                self.assertTrue(any(ns.endswith("colliders") for ns in namespaces), namespaces)
                forces = [msg.wrench.force for _, msg, _ in bag.read_messages(topics=[handle])]
                self.assertGreater(len(forces), 10)
                for f in forces:
                    self.assertTrue(all(math.isfinite(v) for v in (f.x, f.y, f.z)))
                # In the gripper's frame once it is found (its axes are world's: the weight is still along -z).
                frames = {msg.header.frame_id for _, msg, _ in bag.read_messages(topics=[handle])}
                self.assertIn("gripper", frames)
                self.assertTrue(frames <= {"gripper", "world"}, frames)
                # Held still at the start (a hanging cloth at rest, lightly damped): its weight, downwards.
                self.assertAlmostEqual(forces[0].z, -weight, delta=0.1 * weight)
                for _, msg, _ in bag.read_messages(topics=[table]):
                    f = msg.wrench.force
                    self.assertTrue(all(math.isfinite(v) for v in (f.x, f.y, f.z)))


if __name__ == "__main__":
    rospy.init_node("check_contact", anonymous=True)
    rostest.rosrun("modal_mass_spring", "check_contact", RecordsCollidersAndWrenches, sys.argv)
