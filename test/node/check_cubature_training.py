#!/usr/bin/env python3
"""Rostest checker of ~set_method to a cubature not trained yet (cubature_training.test): the service
answers at once, the training runs in the background while the current method steps on and everything
keeps being published (~status REBUILDING with the training's progress in its message, /diagnostics,
~points), no gap above a second, and the method switches to cubature once the training is done."""
import sys
import threading
import time
import unittest

import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticArray
from modal_mass_spring.msg import Status
from modal_mass_spring.srv import SetMethod
from sensor_msgs.msg import PointCloud2

NODE = "/modal_mass_spring"
LONGEST_GAP = 1.0  # s: the node is never silent longer


class Recorder:
    """Every message of a topic with its wall arrival time."""

    def __init__(self, topic, kind):
        self.lock = threading.Lock()
        self.messages = []
        self.sub = rospy.Subscriber(topic, kind, self.add, queue_size=1000)

    def add(self, msg):
        with self.lock:
            self.messages.append((time.time(), msg))

    def get(self):
        with self.lock:
            return list(self.messages)


def longest_gap(messages, start, end):
    """The longest wait between start, the messages' arrivals and end."""
    times = [start] + [t for t, _ in messages if start < t < end] + [end]
    return max(b - a for a, b in zip(times, times[1:]))


class CubatureTraining(unittest.TestCase):
    def test_training_in_the_background_keeps_the_node_publishing(self):
        status = Recorder(NODE + "/status", Status)
        points = Recorder(NODE + "/points", PointCloud2)
        diagnostics = Recorder("/diagnostics", DiagnosticArray)
        set_method = rospy.ServiceProxy(NODE + "/set_method", SetMethod)
        set_method.wait_for_service(timeout=60.0)
        end = time.time() + 30.0
        while time.time() < end and len(status.get()) < 10:
            time.sleep(0.1)
        self.assertEqual(status.get()[-1][1].method, "physical")

        start = time.time()
        reply = set_method("cubature")
        answered = time.time() - start
        print("~set_method cubature answered in %.3f s: %s" % (answered, reply.message))
        self.assertTrue(reply.success, reply.message)
        self.assertIn("training the cubature in the background", reply.message)
        self.assertLess(answered, LONGEST_GAP, "the service answers at once")
        # A second request while it trains is told so.
        again = set_method("cubature")
        self.assertTrue(again.success, again.message)
        self.assertIn("is being trained", again.message)

        end = time.time() + 90.0
        switched = None
        while time.time() < end and switched is None:
            time.sleep(0.1)
            switched = next((t for t, s in status.get() if t > start and s.method == "cubature"), None)
        self.assertIsNotNone(switched, "switched to cubature once trained")
        during = [s for t, s in status.get() if start < t < switched]
        print("%d statuses in %.1f s of training; the last: %s" % (len(during), switched - start,
                                                                   during[-1].message if during else "none"))
        # The training took long enough for the test to mean something, and the node spoke throughout.
        self.assertGreater(switched - start, 2.0, "a training of a few seconds (a larger sheet if it got faster)")
        for name, recorder in (("~status", status), ("~points", points), ("/diagnostics", diagnostics)):
            gap = longest_gap(recorder.get(), start, switched)
            print("%s: longest gap %.3f s" % (name, gap))
            self.assertLess(gap, LONGEST_GAP + (1.0 if name == "/diagnostics" else 0.0),
                            "%s kept arriving during the training" % name)
        rebuilding = [s for s in during if s.state == Status.REBUILDING]
        self.assertGreater(len(rebuilding), 0.8 * len(during), "REBUILDING while it trains")
        self.assertTrue(all(s.method == "physical" for s in during), "the current method runs on meanwhile")
        self.assertGreater(during[-1].step_count, during[0].step_count, "and steps")
        progress = [s.message for s in rebuilding if "springs" in s.message]
        self.assertTrue(progress, "the training's progress in ~status")
        self.assertIn("training the cubature", progress[-1])
        said = [s.values for _, d in diagnostics.get() for s in d.status if "modal_mass_spring" in s.name]
        self.assertTrue(any(v.key == "cubature training" for values in said for v in values),
                        "the diagnostics say it trains")

        # Switched: the cubature runs, its report in ~status.
        time.sleep(0.5)
        latest = status.get()[-1][1]
        self.assertEqual(latest.method, "cubature")
        self.assertEqual(latest.state, Status.RUNNING, latest.message)
        self.assertGreater(latest.cubature_springs, 0)
        self.assertGreater(latest.step_count, during[-1].step_count)


if __name__ == "__main__":
    rospy.init_node("check_cubature_training")
    rostest.rosrun("modal_mass_spring", "check_cubature_training", CubatureTraining, sys.argv)
