#!/usr/bin/env python3
"""Measures what dragging costs a running node (not a test: a number for docs/benchmarks.md). Resets the node,
reads ~status for S seconds with nothing by hand, then resets it again, grabs the free particle under the drag marker's start
(the particle nearest the middle of the bottom row) by sending its feedback as rviz does, pulls it
`pull` m along +y for S seconds, lets go, and prints the median step cost and stepping per tick of
both, and the largest strain of the cloth at rest (from ~points). With pull 0 the spring holds the
particle where it is: on a config that starts at rest (initial_state: equilibrium) nothing moves and
the difference is the drag's own cost (a force set before every step, the particle's state read).
Usage: measure_drag_cost.py [node name, default /modal_mass_spring] [seconds, default 10] [pull m, default 0.2]"""
import statistics
import sys
import time

import rospy
from modal_mass_spring.msg import Status
from sensor_msgs import point_cloud2
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger
from visualization_msgs.msg import InteractiveMarkerFeedback, InteractiveMarkerInit


def record(node, seconds):
    statuses = []
    sub = rospy.Subscriber(node + "/status", Status, statuses.append, queue_size=1000)
    time.sleep(seconds)
    sub.unregister()
    return ([s.step_seconds for s in statuses if s.tick_steps > 0],
            [s.tick_step_seconds for s in statuses if s.tick_steps > 0])


def main():
    node = sys.argv[1] if len(sys.argv) > 1 else "/modal_mass_spring"
    seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 10.0
    pull = float(sys.argv[3]) if len(sys.argv) > 3 else 0.2
    rospy.init_node("measure_drag_cost", anonymous=True)
    cloud = rospy.wait_for_message(node + "/points", PointCloud2, timeout=120)
    strain = max(p[0] for p in point_cloud2.read_points(cloud, field_names=("strain",)))
    # Where the marker is: the server's latched full state.
    pose = rospy.wait_for_message(node + "/drag/update_full", InteractiveMarkerInit, timeout=30).markers[0].pose
    publisher = rospy.Publisher(node + "/drag/feedback", InteractiveMarkerFeedback, queue_size=10)
    time.sleep(1.0)

    def feedback(event, dy):
        message = InteractiveMarkerFeedback()
        message.header.frame_id = rospy.get_param(node + "/fixed_frame", "world")
        message.client_id = "/measure_drag_cost"
        message.marker_name = "drag"
        message.control_name = "pull"
        message.event_type = event
        message.pose.position.x = pose.position.x
        message.pose.position.y = pose.position.y + dy
        message.pose.position.z = pose.position.z
        message.pose.orientation.w = 1.0
        publisher.publish(message)

    reset = rospy.ServiceProxy(node + "/reset", Trigger)
    reset()
    free_steps, free_ticks = record(node, seconds)
    reset()
    feedback(InteractiveMarkerFeedback.MOUSE_DOWN, 0.0)
    feedback(InteractiveMarkerFeedback.POSE_UPDATE, pull)
    drag_steps, drag_ticks = record(node, seconds)
    feedback(InteractiveMarkerFeedback.MOUSE_UP, pull)
    median = statistics.median
    print("%s, largest strain at the start %.3f; over %g s each (medians): without a drag %.3f ms a step, %.2f ms of "
          "stepping a tick; pulling %.2f m %.3f ms a step, %.2f ms a tick: x %.2f"
          % (node, strain, seconds, 1e3 * median(free_steps), 1e3 * median(free_ticks), pull,
             1e3 * median(drag_steps), 1e3 * median(drag_ticks), median(drag_ticks) / median(free_ticks)))


if __name__ == "__main__":
    main()
