#!/usr/bin/env python3
"""Rostest checker of handles that follow TF frames, on every method in lockstep: the particles of
the handle whose frame moves (move_handle.py) are where the frame's recorded motion takes their start
offsets, a free particle below responds, and the handle whose frame is never broadcast holds its
particle with a warning on /rosout and a note in ~status; ~status names the formulation the node
chose. Parameters: ~moving, ~missing (particle lists), ~formulation (handles_frame.test: every handle
on one frame, the moving frame)."""
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from modal_mass_spring.msg import Status
from rosgraph_msgs.msg import Log
from sensor_msgs import point_cloud2
from sensor_msgs.msg import PointCloud2
from tf2_msgs.msg import TFMessage

NODE = "/modal_mass_spring"
METHODS = ["full", "linear", "physical", "cubature"]
MOVING = [0, 1, 2]  # held by `gripper` (~moving)
MISSING = [3]       # held by `absent`, never broadcast (~missing)
FORMULATION = "constraint_modes"  # the one the node resolves (~formulation)
FREE = 15           # a bottom corner
TOLERANCE = 1e-6    # m; the point clouds are float32 (1.2e-7 relative)


def rotation(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


class Recorder:
    def __init__(self):
        self.lock = threading.Lock()
        self.poses = []  # (R, t) of gripper in world, every one broadcast
        self.clouds = {m: [] for m in METHODS}
        self.warnings = []
        self.status = None
        self.subs = [rospy.Subscriber("/tf", TFMessage, self.on_tf, queue_size=1000),
                     rospy.Subscriber("/rosout", Log, self.on_log, queue_size=1000),
                     rospy.Subscriber(NODE + "/physical/status", Status, self.on_status, queue_size=10)]
        for m in METHODS:
            self.subs.append(rospy.Subscriber(NODE + "/" + m + "/points", PointCloud2,
                                              lambda msg, m=m: self.on_cloud(m, msg), queue_size=1000))

    def on_tf(self, msg):
        for t in msg.transforms:
            if t.child_frame_id == "gripper":
                r = t.transform.rotation
                p = t.transform.translation
                with self.lock:
                    self.poses.append((rotation((r.x, r.y, r.z, r.w)), np.array([p.x, p.y, p.z])))

    def on_cloud(self, method, msg):
        points = np.array(list(point_cloud2.read_points(msg, field_names=("x", "y", "z"))))
        with self.lock:
            self.clouds[method].append(points)

    def on_log(self, msg):
        if msg.level >= Log.WARN:
            with self.lock:
                self.warnings.append(msg.msg)

    def on_status(self, msg):
        self.status = msg


class Handles(unittest.TestCase):
    def test_handles_follow_their_frames(self):
        rec = Recorder()
        time.sleep(12.0)  # the frame holds for 3 s, then moves
        with rec.lock:
            poses = list(rec.poses)
            clouds = {m: list(c) for m, c in rec.clouds.items()}
            warnings = list(rec.warnings)
        self.assertGreater(len(poses), 100)
        spacing = rospy.get_param(NODE + "/method_spacing")
        for k, method in enumerate(METHODS):
            self.assertGreater(len(clouds[method]), 50, method)
            # Each grid is drawn shifted along x; the handles follow the frame in the centre grid's place.
            shift = np.array([(k - 0.5 * (len(METHODS) - 1)) * spacing, 0.0, 0.0])
            start = clouds[method][0] - shift
            r0, t0 = poses[0]  # the frame holds its first pose while the node starts
            offsets = (start[MOVING] - t0) @ r0  # R0^T (p - t0), row by row
            worst, moved = 0.0, 0.0
            for cloud in clouds[method][1:]:
                held = cloud[MOVING] - shift
                # The node takes the latest pose at each tick: the closest recorded one.
                error = min(np.abs(held - (offsets @ r.T + t)).max() for r, t in poses)
                worst = max(worst, error)
                moved = max(moved, np.abs(held - start[MOVING]).max())
                self.assertTrue(np.allclose(cloud[MISSING] - shift, start[MISSING], atol=TOLERANCE, rtol=0.0),
                                "%s: the handle of the missing frame holds" % method)
            print("%s: handle particles within %.3g m of the frame's motion, moved up to %.3g m" % (method, worst, moved))
            self.assertLess(worst, TOLERANCE, "%s: handle particles on the frame's motion" % method)
            self.assertGreater(moved, 0.02, "%s: the frame moved them" % method)
            free_motion = max(np.linalg.norm(c[FREE] - shift - start[FREE]) for c in clouds[method])
            self.assertGreater(free_motion, 1e-3, "%s: a free particle responds" % method)
        self.assertIsNotNone(rec.status)
        self.assertEqual(rec.status.handle_formulation, FORMULATION)
        if MISSING:
            self.assertTrue(any("handle frame 'absent' not available" in w for w in warnings), warnings[:5])
            self.assertEqual(rec.status.handles, "held: frame 'absent' not available")
        else:
            self.assertEqual(rec.status.handles, "")


if __name__ == "__main__":
    rospy.init_node("check_handles")
    MOVING = rospy.get_param("~moving", MOVING)
    MISSING = rospy.get_param("~missing", MISSING)
    FORMULATION = rospy.get_param("~formulation", FORMULATION)
    rostest.rosrun("modal_mass_spring", "check_handles", Handles)
