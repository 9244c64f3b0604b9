#!/usr/bin/env python3
"""Broadcasts a handle frame (~frame, child of ~parent) with tf2_ros: held at ~start for ~hold
seconds, then moving on a circle of ~radius in the x-z plane once every ~period seconds while turning
about z by up to ~angle radians. A demo for config/held_cloth.yaml and the motion of the handles test."""
import math

import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped


def main():
    rospy.init_node("move_handle")
    frame = rospy.get_param("~frame", "gripper")
    parent = rospy.get_param("~parent", "world")
    start = rospy.get_param("~start", [0.0, 0.0, 0.0])
    radius = rospy.get_param("~radius", 0.1)
    period = rospy.get_param("~period", 4.0)
    angle = rospy.get_param("~angle", 0.3)
    hold = rospy.get_param("~hold", 1.0)
    rate = rospy.Rate(rospy.get_param("~rate", 50.0))
    broadcaster = tf2_ros.TransformBroadcaster()
    begin = rospy.Time.now()
    while not rospy.is_shutdown():
        now = rospy.Time.now()
        phase = 2.0 * math.pi * max(0.0, (now - begin).to_sec() - hold) / period
        t = TransformStamped()
        t.header.stamp = now
        t.header.frame_id = parent
        t.child_frame_id = frame
        t.transform.translation.x = start[0] + radius * math.sin(phase)
        t.transform.translation.y = start[1]
        t.transform.translation.z = start[2] + radius * (1.0 - math.cos(phase))
        yaw = angle * math.sin(phase)
        t.transform.rotation.z = math.sin(0.5 * yaw)
        t.transform.rotation.w = math.cos(0.5 * yaw)
        broadcaster.sendTransform(t)
        try:
            rate.sleep()
        except rospy.ROSInterruptException:
            break


if __name__ == "__main__":
    main()
