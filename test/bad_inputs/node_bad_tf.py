#!/usr/bin/env python3
"""Rostest sweep of bad handle frames and live values on a running node (node_bad_tf.test): a 2D grid
held at two corners by the frames `left` and `right` (constraint modes). This script broadcasts the
frames and, phase by phase, makes one of them bad (out of the plane, flipping, stopped, a sample
1e12 m away); each time the node must say so (a WARN on /rosout,
~status's `handles`) and keep a state a user would call good: finite, no particle collapsed onto
another, nothing far from where the handles hold the grid, never DIVERGED."""
import math
import sys
import threading
import time
import unittest

import rospy
import rostest
from dynamic_reconfigure.client import Client
from geometry_msgs.msg import TransformStamped
from modal_mass_spring.msg import Status
from rosgraph_msgs.msg import Log
from sensor_msgs import point_cloud2
from sensor_msgs.msg import PointCloud2
from tf2_msgs.msg import TFMessage

NODE = "/modal_mass_spring"
SPACING = 0.1  # m, the launch file's
SIZE = 0.4     # m, the grid's side
# `left` sits a spacing beside its particle (the top left corner, at the origin): a turn moves it.
LEFT = ((-SPACING, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))


class Broadcaster:
    """Sends `left` and `right` every 10 ms from a thread; `pose(name)` returns (translation, quaternion)
    or None (not sent) and may change between calls."""

    def __init__(self):
        self.lock = threading.Lock()
        self.poses = {"left": LEFT,
                      "right": ((SIZE, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))}
        self.flip = False
        self.pub = rospy.Publisher("/tf", TFMessage, queue_size=100)
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def set(self, name, pose):
        with self.lock:
            self.poses[name] = pose

    def run(self):
        start = time.time()
        while not rospy.is_shutdown():
            msg = TFMessage()
            with self.lock:
                poses = dict(self.poses)
                flip = self.flip
            for name, pose in poses.items():
                if pose is None:
                    continue
                (x, y, z), q = pose
                if flip and name == "left" and int((time.time() - start) / 0.02) % 2:
                    q = (0.0, 1.0, 0.0, 0.0)  # 180 degrees about y, every other 20 ms
                t = TransformStamped()
                t.header.stamp = rospy.Time.now()
                t.header.frame_id = "world"
                t.child_frame_id = name
                t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = x, y, z
                (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
                 t.transform.rotation.w) = q
                msg.transforms.append(t)
            self.pub.publish(msg)
            time.sleep(0.01)


class NodeLog:
    """Every WARN/ERROR of the node on /rosout, subscribed once at the start: a subscription made when
    a phase starts could miss its first (throttled) warning."""

    def __init__(self):
        self.lock = threading.Lock()
        self.warnings = []
        self.sub = rospy.Subscriber("/rosout", Log, self.on_log, queue_size=1000)

    def on_log(self, msg):
        if msg.name == NODE and msg.level >= Log.WARN:
            with self.lock:
                self.warnings.append(msg.msg)

    def since(self, start):
        with self.lock:
            return self.warnings[start:]

    def count(self):
        with self.lock:
            return len(self.warnings)


class Watch:
    """Every status, every WARN/ERROR of the node and every point cloud, from now on."""

    def __init__(self):
        self.lock = threading.Lock()
        self.statuses, self.clouds = [], []
        self.first_warning = LOG.count()
        self.subs = [rospy.Subscriber(NODE + "/status", Status, self.add(self.statuses), queue_size=100),
                     rospy.Subscriber(NODE + "/points", PointCloud2, self.on_cloud, queue_size=10)]
        time.sleep(0.5)  # connected before the phase starts

    def add(self, into):
        def callback(msg):
            with self.lock:
                into.append(msg)
        return callback

    def on_cloud(self, msg):
        points = list(point_cloud2.read_points(msg, field_names=("x", "y", "z")))
        with self.lock:
            self.clouds.append(points)

    def get(self):
        with self.lock:
            return list(self.statuses), LOG.since(self.first_warning), list(self.clouds)

    def close(self):
        for sub in self.subs:
            sub.unregister()


def check_good(test, statuses, clouds, what):
    """Never DIVERGED; every cloud finite, no two particles within a tenth of the spacing, none
    further than two grid sizes from the handles' corner."""
    test.assertTrue(statuses, what + ": no status")
    test.assertTrue(clouds, what + ": no point cloud")
    for status in statuses:
        test.assertNotEqual(status.state, Status.DIVERGED, "%s: %s" % (what, status.message))
    for points in clouds:
        for p in points:
            test.assertTrue(all(math.isfinite(c) for c in p), what)
            test.assertLess(math.dist(p, (0.0, 0.0, 0.0)), 2 * SIZE + 1.0, "%s: a particle at %s" % (what, p))
        closest = min(math.dist(a, b) for i, a in enumerate(points) for b in points[i + 1:])
        test.assertGreater(closest, 0.1 * SPACING, what + ": two particles collapsed onto one point")


class BadFrames(unittest.TestCase):
    def setUp(self):
        self.frames = BROADCASTER
        rospy.wait_for_message(NODE + "/status", Status, timeout=60.0)
        time.sleep(1.0)

    def watch(self, seconds, change):
        watch = Watch()
        change()
        time.sleep(seconds)
        got = watch.get()
        watch.close()
        return got

    def test_1_a_frame_turned_out_of_the_plane_is_refused(self):
        # 60 degrees about z: out of the 2D grid's x-z plane.
        statuses, warnings, clouds = self.watch(2.0, lambda: self.frames.set(
            "left", (LEFT[0], (0.0, 0.0, math.sin(math.pi / 6), math.cos(math.pi / 6)))))
        self.frames.set("left", LEFT)
        check_good(self, statuses, clouds, "out of plane")
        self.assertIn("frame 'left' refused: it turns out of the 2D grid's x-z plane", statuses[-1].handles)
        self.assertTrue(any("'left' refused" in w for w in warnings), warnings)
        time.sleep(1.0)

    def test_2_a_flipping_frame_keeps_a_good_state(self):
        statuses, warnings, clouds = self.watch(3.0, lambda: setattr(self.frames, "flip", True))
        self.frames.flip = False
        check_good(self, statuses, clouds, "flipping")
        self.assertTrue(any("'left' refused: it turned" in w for w in warnings), warnings)
        time.sleep(1.0)

    def test_3_a_frame_that_stops_is_reported_stale(self):
        statuses, warnings, clouds = self.watch(3.0, lambda: self.frames.set("right", None))
        self.frames.set("right", ((SIZE, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)))
        check_good(self, statuses, clouds, "stale")
        self.assertIn("frame 'right' stale", statuses[-1].handles)
        self.assertTrue(any("'right' stale" in w for w in warnings), warnings)
        time.sleep(2.0)
        self.assertEqual(rospy.wait_for_message(NODE + "/status", Status, timeout=10.0).handles, "",
                         "back to following once it is broadcast again")

    def test_4_a_frame_sample_far_away_is_refused(self):
        # One glitching TF sample 1e12 m away (about a tick long), then back: refused and held, never
        # followed (it would throw the cloth 1e12 m and end the run).
        def glitch():
            self.frames.set("right", ((1e12, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)))
            time.sleep(0.04)
            self.frames.set("right", ((SIZE, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)))
        statuses, warnings, clouds = self.watch(2.0, glitch)
        check_good(self, statuses, clouds, "a sample 1e12 m away")
        self.assertTrue(any("'right' refused: it jumped" in w for w in warnings), warnings)
        time.sleep(1.0)

    def test_5_a_large_live_alpha_on_a_moving_cloth(self):
        client = Client(NODE, timeout=30)
        start = client.get_configuration(timeout=30)
        # Swing the cloth: move `right` in and out for a second.
        for k in range(50):
            self.frames.set("right", ((SIZE - 0.1 * math.sin(k / 5.0), 0.0, 0.05 * math.sin(k / 3.0)),
                                      (0.0, 0.0, 0.0, 1.0)))
            time.sleep(0.02)
        watch = Watch()
        result = client.update_configuration({"alpha": 1e6})
        time.sleep(4.0)
        statuses, warnings, clouds = watch.get()
        watch.close()
        check_good(self, statuses, clouds, "alpha 1e6")
        final = client.get_configuration(timeout=30)
        # Applied (the cloth comes to rest) or refused by name (nothing changed): never diverged.
        if result["alpha"] != 1e6:
            self.assertEqual(final["alpha"], start["alpha"])
            self.assertTrue(any("alpha" in w for w in warnings), warnings)


if __name__ == "__main__":
    rospy.init_node("node_bad_tf", anonymous=True)
    LOG = NodeLog()
    BROADCASTER = Broadcaster()
    rostest.rosrun("modal_mass_spring", "node_bad_tf", BadFrames, sys.argv)
