#!/usr/bin/env python3
"""Rostest checker: records a few seconds of the node's markers, status and TF with rosbag, then reads
the bag back and checks it holds them at the configured rate, with the particle frames on /tf (never
the same stamp twice for a frame) and the grid frame on /tf_static."""
import os
import subprocess
import sys
import tempfile
import time
import unittest

import rosbag
import rospy
import rostest


class RecordsMarkersTfAndStatus(unittest.TestCase):
    def test_bag_holds_them_at_the_rate(self):
        node = rospy.get_param("~node", "/modal_mass_spring")
        duration = float(rospy.get_param("~duration", 4.0))
        rate = float(rospy.get_param(node + "/publish_rate"))
        grid_frame = rospy.get_param(node + "/grid_frame")
        particles = rospy.get_param(node + "/tf_particles")
        topics = [node + "/markers", node + "/status", "/tf", "/tf_static"]

        # Wait until the node publishes, so the recording covers a running node.
        rospy.wait_for_message(node + "/status", rospy.AnyMsg, timeout=30.0)
        with tempfile.TemporaryDirectory() as folder:
            path = os.path.join(folder, "node.bag")
            record = subprocess.run(["rosbag", "record", "--quiet", "-O", path, "--duration=%g" % duration] + topics,
                                    capture_output=True, text=True, timeout=duration + 60)
            self.assertEqual(record.returncode, 0, record.stderr)
            for _ in range(100):  # the bag is renamed from .active when closed
                if os.path.exists(path):
                    break
                time.sleep(0.1)
            with rosbag.Bag(path) as bag:
                info = bag.get_type_and_topic_info().topics
                for topic in topics:
                    self.assertIn(topic, info, "bag has no " + topic)
                self.assertEqual(info[node + "/markers"].msg_type, "visualization_msgs/MarkerArray")
                self.assertEqual(info[node + "/status"].msg_type, "modal_mass_spring/Status")

                for topic in (node + "/markers", node + "/status"):
                    times = [t.to_sec() for _, _, t in bag.read_messages(topics=[topic])]
                    self.assertGreaterEqual(len(times), 0.5 * rate * duration, topic)
                    measured = (len(times) - 1) / (times[-1] - times[0])
                    self.assertAlmostEqual(measured, rate, delta=0.25 * rate,
                                           msg="%s recorded at %.2f Hz, configured %.2f Hz" % (topic, measured, rate))

                static_frames = {tf.child_frame_id for _, msg, _ in bag.read_messages(topics=["/tf_static"])
                                 for tf in msg.transforms}
                self.assertIn(grid_frame, static_frames)

                stamps = {}
                tf_messages = 0
                for _, msg, _ in bag.read_messages(topics=["/tf"]):
                    tf_messages += 1
                    children = [tf.child_frame_id for tf in msg.transforms]
                    # One batched message per tick with every configured particle.
                    self.assertEqual(sorted(children), sorted("%s/particle_%d" % (grid_frame, p) for p in particles))
                    for tf in msg.transforms:
                        previous = stamps.get(tf.child_frame_id)
                        if previous is not None:
                            self.assertGreater(tf.header.stamp, previous, "the same stamp twice for " + tf.child_frame_id)
                        stamps[tf.child_frame_id] = tf.header.stamp
                self.assertGreaterEqual(tf_messages, 0.5 * rate * duration)


if __name__ == "__main__":
    rospy.init_node("check_bag", anonymous=True)
    rostest.rosrun("modal_mass_spring", "check_bag", RecordsMarkersTfAndStatus, sys.argv)
