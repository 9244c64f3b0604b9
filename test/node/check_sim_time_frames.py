#!/usr/bin/env python3
"""Rostest checker of handles on TF frames under simulated time (sim_time_frames.test). The node is the
clock and steps slower than real time; the gripper's broadcaster moves on that clock. Checked: every
pose of the frame is stamped with a time the node's clock took (the broadcaster is on /clock), simulated
time runs at the node's pace (not wall time's), and after each tick the held particles are where the
frame's pose at the previous tick's clock takes them: the node sees the motion at its pace, one tick late."""
import sys
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from tf2_msgs.msg import TFMessage

from check_handles import rotation

HELD = [0, 1, 2]
TOLERANCE = 1e-9  # m: the TF frames carry float64


class Recorder:
    def __init__(self):
        self.lock = threading.Lock()
        self.poses = {}  # stamp (ns) -> (R, t) of `gripper`
        self.ticks = []  # (stamp (ns), held particles as rows)
        self.sub = rospy.Subscriber("/tf", TFMessage, self.on_tf, queue_size=1000)

    def on_tf(self, msg):
        held = {}
        stamp = None
        for t in msg.transforms:
            p = t.transform.translation
            if t.child_frame_id == "gripper":
                r = t.transform.rotation
                with self.lock:
                    self.poses[t.header.stamp.to_nsec()] = (rotation((r.x, r.y, r.z, r.w)), np.array([p.x, p.y, p.z]))
            elif t.child_frame_id.startswith("grid/particle_"):
                held[int(t.child_frame_id.rpartition("_")[2])] = np.array([p.x, p.y, p.z])
                stamp = t.header.stamp.to_nsec()
        if all(i in held for i in HELD):
            with self.lock:
                self.ticks.append((stamp, np.array([held[i] for i in HELD])))


class SimTimeFrames(unittest.TestCase):
    def test_the_frame_moves_on_the_node_clock(self):
        rec = Recorder()
        wall_start = time.time()
        time.sleep(16.0)
        wall = time.time() - wall_start
        with rec.lock:
            poses = dict(rec.poses)
            ticks = list(rec.ticks)
        self.assertGreater(len(ticks), 100)
        self.assertGreater(len(poses), 50)
        clock = set(stamp for stamp, _ in ticks)
        off_clock = [s for s in poses if s not in clock and s > min(clock)]
        self.assertFalse(off_clock, "every pose of the frame is stamped with a time of the node's clock")
        simulated = (ticks[-1][0] - ticks[0][0]) * 1e-9
        print("%.2f simulated s in %.2f wall s" % (simulated, wall))
        self.assertLess(simulated, 0.5 * wall, "the node steps at a quarter of real time")
        self.assertGreater(simulated, 0.1 * wall)

        first = min(poses)
        r0, t0 = poses[first]  # held through the circle's start: the pose the offsets were taken at
        offsets = (ticks[0][1] - t0) @ r0
        checked, worst, moved = 0, 0.0, 0.0
        for (before, _), (stamp, held) in zip(ticks, ticks[1:]):
            if before not in poses:
                continue
            r, t = poses[before]
            worst = max(worst, np.abs(held - (offsets @ r.T + t)).max())
            moved = max(moved, np.abs(held - ticks[0][1]).max())
            checked += 1
        print("%d of %d ticks checked: held particles within %.3g m of the frame's pose at the previous "
              "tick's clock; moved up to %.3g m" % (checked, len(ticks) - 1, worst, moved))
        self.assertGreater(checked, 0.8 * (len(ticks) - 1))
        self.assertLess(worst, TOLERANCE)
        self.assertGreater(moved, 0.02, "the frame moved them")


if __name__ == "__main__":
    rospy.init_node("check_sim_time_frames")
    rostest.rosrun("modal_mass_spring", "check_sim_time_frames", SimTimeFrames, sys.argv)
