#!/usr/bin/env python3
"""Rostest checker of colliders that follow TF frames (contact_frames.test). It broadcasts `gripper`
(the cloth's top row, turned 90 degrees about x, still) and `pusher` (a sphere collider's frame):
held 0.07 m off the hanging cloth, moved 0.2 m along -y through the cloth's plane, held. Checked: the
sphere's marker is where the frame is, at rest and along the motion; the cloth is pushed away and no
particle is more than 1 mm inside the sphere at any tick; the collider on `never` (not broadcast) is
warned about on /rosout, its marker deleted, and the node keeps RUNNING; ~handle_force/handle_0 comes
in the gripper's frame: the cloth's weight along the gripper's -y while the pusher is off, with no
torque about the gripper's origin (the middle of the row the cloth hangs from)."""
import math
import sys
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import TransformStamped, WrenchStamped
from modal_mass_spring.msg import Status
from rosgraph_msgs.msg import Log
from sensor_msgs import point_cloud2
from sensor_msgs.msg import PointCloud2
from visualization_msgs.msg import Marker, MarkerArray

NODE = "/modal_mass_spring"
RADIUS = 0.05                 # m, the sphere's (the launch file's)
X, Z = 0.175, -0.2            # the pusher's line: the middle of the cloth's width, row 4
Y_START, Y_END = 0.12, -0.08  # m: 0.07 m off the cloth at y = 0, then 0.08 m past it
HOLD, MOVE = 3.0, 2.0         # s: held, moved (smoothstep), held again
GRIPPER = (0.175, 0.0, 0.0)
GRIPPER_Q = (math.sin(math.pi / 4), 0.0, 0.0, math.cos(math.pi / 4))  # x, y, z, w: 90 degrees about x
WEIGHT = 64 * 0.01 * 9.81     # N


def smoothstep(u):
    u = min(1.0, max(0.0, u))
    return u * u * (3.0 - 2.0 * u)


class Recorder:
    def __init__(self):
        self.lock = threading.Lock()
        self.markers = {}    # stamp -> {id: Marker} of ns colliders
        self.clouds = {}     # stamp -> N x 3 array
        self.contacts = {}   # stamp -> N: the collider each particle touched, -1 none
        self.wrenches = []   # (wall time, WrenchStamped)
        self.warnings = []
        self.states = []
        self.frames = []     # (wall time, y of the broadcast pusher)
        self.subs = [rospy.Subscriber(NODE + "/markers", MarkerArray, self.on_markers, queue_size=100),
                     rospy.Subscriber(NODE + "/points", PointCloud2, self.on_points, queue_size=100),
                     rospy.Subscriber(NODE + "/handle_force/handle_0", WrenchStamped, self.on_wrench, queue_size=100),
                     rospy.Subscriber(NODE + "/status", Status, self.on_status, queue_size=100),
                     rospy.Subscriber("/rosout", Log, self.on_log, queue_size=1000)]

    def on_markers(self, msg):
        with self.lock:
            for m in msg.markers:
                if m.ns == "colliders":
                    self.markers.setdefault(m.header.stamp.to_sec(), {})[m.id] = m

    def on_points(self, msg):
        points = np.array(list(point_cloud2.read_points(msg, field_names=("x", "y", "z"))))
        contacts = np.array([c for (c,) in point_cloud2.read_points(msg, field_names=("contact",))])
        with self.lock:
            self.clouds[msg.header.stamp.to_sec()] = points
            self.contacts[msg.header.stamp.to_sec()] = contacts

    def on_wrench(self, msg):
        with self.lock:
            self.wrenches.append((time.time(), msg))

    def on_status(self, msg):
        with self.lock:
            self.states.append(msg.state)

    def on_log(self, msg):
        if msg.level >= Log.WARN and msg.name == NODE:
            with self.lock:
                self.warnings.append(msg.msg)


class CollidersFollowTheirFrames(unittest.TestCase):
    def test_pusher_moves_the_cloth_and_a_missing_frame_is_warned(self):
        recorder = Recorder()
        broadcaster = tf2_ros.TransformBroadcaster()
        rospy.wait_for_message(NODE + "/status", Status, timeout=60.0)

        def send(y):
            stamp = rospy.Time.now()
            frames = []
            for child, (x_, y_, z_), q in (("gripper", GRIPPER, GRIPPER_Q), ("pusher", (X, y, Z), (0.0, 0.0, 0.0, 1.0))):
                t = TransformStamped()
                t.header.stamp = stamp
                t.header.frame_id = "world"
                t.child_frame_id = child
                t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = x_, y_, z_
                (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
                 t.transform.rotation.w) = q
                frames.append(t)
            broadcaster.sendTransform(frames)
            with recorder.lock:
                recorder.frames.append((time.time(), y))

        start = time.time()
        moving_from = start + HOLD
        while time.time() < start + 2 * HOLD + MOVE and not rospy.is_shutdown():
            now = time.time()
            send(Y_START + (Y_END - Y_START) * smoothstep((now - moving_from) / MOVE))
            time.sleep(0.02)
        # Wait for the (throttled, after its grace) warning about `never`, the pusher still sent.
        deadline = time.time() + 15.0
        while time.time() < deadline and not any("'never'" in w for w in recorder.warnings):
            send(Y_END)
            time.sleep(0.02)
        send(Y_END)
        time.sleep(0.5)

        with recorder.lock:
            markers = dict(recorder.markers)
            clouds = dict(recorder.clouds)
            contacts = dict(recorder.contacts)
            wrenches = list(recorder.wrenches)
            warnings = list(recorder.warnings)
            states = list(recorder.states)

        # The sphere's marker (id 0) follows the frame: at its start, along the motion, at its end.
        ys = [markers[s][0].pose.position.y for s in sorted(markers)
              if 0 in markers[s] and markers[s][0].action == Marker.ADD]
        self.assertGreater(len(ys), 30)
        self.assertAlmostEqual(ys[0], Y_START, delta=1e-9)
        self.assertAlmostEqual(ys[-1], Y_END, delta=1e-9)
        between = [y for y in ys if Y_END + 0.01 < y < Y_START - 0.01]
        self.assertGreater(len(between), 5, "the marker jumped instead of moving with the frame")
        self.assertTrue(all(b <= a + 1e-9 for a, b in zip(ys, ys[1:])), "the marker went back")
        last = markers[max(markers)][0]
        self.assertAlmostEqual(last.pose.position.x, X, delta=1e-9)
        self.assertAlmostEqual(last.pose.position.z, Z, delta=1e-9)
        # The box on `never` is not drawn (DELETE), at every tick.
        self.assertTrue(all(m[1].action == Marker.DELETE for m in markers.values() if 1 in m))

        # No particle deeper than 1 mm inside the sphere where it is at the same tick; pushed away.
        checked, deepest = 0, -1.0
        for stamp, points in clouds.items():
            if stamp not in markers or 0 not in markers[stamp] or markers[stamp][0].action != Marker.ADD:
                continue  # before the frame was found
            p = markers[stamp][0].pose.position
            depth = RADIUS - np.linalg.norm(points - np.array([p.x, p.y, p.z]), axis=1).min()
            self.assertLess(depth, 1e-3, "a particle %.4f m inside the sphere at %.2f" % (depth, stamp))
            checked += 1
            deepest = max(deepest, depth)
        self.assertGreater(checked, 30)
        end = clouds[max(clouds)]
        print("%d ticks with the sphere: the deepest particle %.2f mm inside it (negative: outside), the cloth's "
              "smallest y at the end %.4f m, %d markers along the motion" % (checked, 1e3 * deepest, end[:, 1].min(),
                                                                               len(between)))
        self.assertLess(end[:, 1].min(), Y_END - 0.02, "the cloth was not pushed along -y")

        # ~points' contact field: the particles the sphere (collider 0) touched lie at its surface; no
        # particle names the box on `never`, which is inactive.
        touching_ticks = 0
        for stamp, touched in contacts.items():
            if stamp not in markers or 0 not in markers[stamp] or stamp not in clouds:
                continue
            p = markers[stamp][0].pose.position
            reach = np.linalg.norm(clouds[stamp] - np.array([p.x, p.y, p.z]), axis=1)
            self.assertTrue(np.all(reach[touched == 0] < RADIUS + 0.02), "a touching particle away from the sphere")
            self.assertFalse(np.any(touched == 1), "a particle touched the inactive box")
            touching_ticks += np.any(touched == 0)
        self.assertGreater(touching_ticks, 5, "no tick said which particles the sphere touched")

        # The missing frame: warned, the node running on.
        self.assertTrue(any("collider 1 frame 'never'" in w and "inactive" in w for w in warnings), warnings)
        self.assertNotIn(Status.DIVERGED, states)
        self.assertEqual(states[-1], Status.RUNNING)

        # The handle's wrench in the gripper's axes: hanging still, the weight along the gripper's -y
        # (world -z turned by -90 degrees about x).
        framed = [w for t, w in wrenches if w.header.frame_id == "gripper" and t < moving_from]
        self.assertGreater(len(framed), 10, {w.header.frame_id for _, w in wrenches})
        f = framed[-1].wrench.force
        self.assertAlmostEqual(f.y, -WEIGHT, delta=0.05 * WEIGHT)
        self.assertAlmostEqual(f.x, 0.0, delta=0.05 * WEIGHT)
        self.assertAlmostEqual(f.z, 0.0, delta=0.05 * WEIGHT)
        # Its torque about the gripper's origin, the middle of the row the cloth hangs from
        # symmetrically: none (about the grid's origin, the row's end, it would be 0.175 m x WEIGHT).
        t = framed[-1].wrench.torque
        self.assertLess(math.sqrt(t.x ** 2 + t.y ** 2 + t.z ** 2), 0.02 * GRIPPER[0] * WEIGHT, t)
        self.assertTrue(all(w.header.frame_id in ("gripper", "world") for _, w in wrenches))


if __name__ == "__main__":
    rospy.init_node("check_contact_frames", anonymous=True)
    rostest.rosrun("modal_mass_spring", "check_contact_frames", CollidersFollowTheirFrames, sys.argv)
