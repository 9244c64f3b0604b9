#!/usr/bin/env python3
"""Broadcasts a gripper frame (~frame, child of ~parent) with tf2_ros for launch/held_cloth.launch, in
a loop: held at ~start for ~hold seconds; a slow wave, ~waves swings of ~amplitude metres along x,
~wave_period seconds each; a turn of ~turn_deg degrees about the vertical axis (z) in ~turn_seconds,
held for ~hold seconds, and back; then the loop starts again. Every move starts and ends at rest (smoothstep), so the handles
the frame holds never jerk."""
import math

import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped


def smoothstep(u):
    u = min(1.0, max(0.0, u))
    return u * u * (3.0 - 2.0 * u)


class Motion:
    def __init__(self, amplitude, wave_period, waves, turn, turn_seconds, hold):
        self.amplitude, self.wave_period, self.waves = amplitude, wave_period, waves
        self.turn, self.turn_seconds, self.hold = turn, turn_seconds, hold
        self.wave_seconds = waves * wave_period
        self.period = 2.0 * hold + self.wave_seconds + 2.0 * turn_seconds

    def at(self, t):
        """(x offset in m, yaw in rad) at t seconds."""
        t = math.fmod(max(0.0, t), self.period)
        t -= self.hold
        if t < 0.0:
            return 0.0, 0.0
        if t < self.wave_seconds:
            # The swing fades in over the first half wave and out over the last.
            half = 0.5 * self.wave_period
            envelope = smoothstep(t / half) * smoothstep((self.wave_seconds - t) / half)
            return self.amplitude * envelope * math.sin(2.0 * math.pi * t / self.wave_period), 0.0
        t -= self.wave_seconds
        if t < self.turn_seconds:
            return 0.0, self.turn * smoothstep(t / self.turn_seconds)
        t -= self.turn_seconds
        if t < self.hold:
            return 0.0, self.turn
        t -= self.hold
        return 0.0, self.turn * (1.0 - smoothstep(t / self.turn_seconds))


def main():
    rospy.init_node("wave_gripper")
    frame = rospy.get_param("~frame", "gripper")
    parent = rospy.get_param("~parent", "world")
    start = rospy.get_param("~start", [0.0, 0.0, 0.0])
    motion = Motion(rospy.get_param("~amplitude", 0.15), rospy.get_param("~wave_period", 3.0),
                    rospy.get_param("~waves", 2), math.radians(rospy.get_param("~turn_deg", 90.0)),
                    rospy.get_param("~turn_seconds", 3.0), rospy.get_param("~hold", 2.0))
    rate = rospy.Rate(rospy.get_param("~rate", 50.0))
    broadcaster = tf2_ros.TransformBroadcaster()
    begin = rospy.Time.now()
    last = None
    while not rospy.is_shutdown():
        now = rospy.Time.now()
        if now != last:  # tf2 refuses a second transform at the same stamp
            last = now
            x, yaw = motion.at((now - begin).to_sec())
            t = TransformStamped()
            t.header.stamp = now
            t.header.frame_id = parent
            t.child_frame_id = frame
            t.transform.translation.x = start[0] + x
            t.transform.translation.y = start[1]
            t.transform.translation.z = start[2]
            t.transform.rotation.z = math.sin(0.5 * yaw)
            t.transform.rotation.w = math.cos(0.5 * yaw)
            broadcaster.sendTransform(t)
        try:
            rate.sleep()
        except rospy.ROSInterruptException:
            break


if __name__ == "__main__":
    main()
