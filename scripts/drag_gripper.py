#!/usr/bin/env python3
"""Broadcasts a gripper frame (~frame, child of ~parent) with tf2_ros for launch/cloth_table.launch
(scenario drag), in a loop: held at ~start for ~hold seconds; lowered by ~lower metres in ~seconds;
dragged by ~drag metres along y in ~seconds; held; dragged back, raised back. Every move starts and
ends at rest (smoothstep), so the handles the frame holds never jerk."""
import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped


def smoothstep(u):
    u = min(1.0, max(0.0, u))
    return u * u * (3.0 - 2.0 * u)


def offset(t, lower, drag, seconds, hold):
    """(y, z) offsets from ~start at t seconds of the loop."""
    period = 2.0 * hold + 4.0 * seconds
    t = t % period - hold
    if t < 0.0:
        return 0.0, 0.0
    if t < seconds:
        return 0.0, -lower * smoothstep(t / seconds)
    t -= seconds
    if t < seconds:
        return drag * smoothstep(t / seconds), -lower
    t -= seconds
    if t < hold:
        return drag, -lower
    t -= hold
    if t < seconds:
        return drag * (1.0 - smoothstep(t / seconds)), -lower
    t -= seconds
    return 0.0, -lower * (1.0 - smoothstep(t / seconds))


def main():
    rospy.init_node("drag_gripper")
    frame = rospy.get_param("~frame", "gripper")
    parent = rospy.get_param("~parent", "world")
    start = rospy.get_param("~start", [0.0, 0.0, 0.0])
    lower, drag = rospy.get_param("~lower", 0.3), rospy.get_param("~drag", 0.5)
    seconds, hold = rospy.get_param("~seconds", 4.0), rospy.get_param("~hold", 2.0)
    rate = rospy.Rate(rospy.get_param("~rate", 50.0))
    broadcaster = tf2_ros.TransformBroadcaster()
    begin = rospy.Time.now()
    last = None
    while not rospy.is_shutdown():
        now = rospy.Time.now()
        if now != last:  # tf2 refuses a frame twice at one stamp
            y, z = offset((now - begin).to_sec(), lower, drag, seconds, hold)
            t = TransformStamped()
            t.header.stamp = now
            t.header.frame_id = parent
            t.child_frame_id = frame
            t.transform.translation.x = start[0]
            t.transform.translation.y = start[1] + y
            t.transform.translation.z = start[2] + z
            t.transform.rotation.w = 1.0
            broadcaster.sendTransform(t)
            last = now
        try:
            rate.sleep()
        except rospy.ROSInterruptException:
            break


if __name__ == "__main__":
    main()
