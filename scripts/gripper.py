#!/usr/bin/env python3
"""Broadcasts a gripper frame (~frame, child of ~parent) with tf2_ros at ~rate Hz: at ~start plus
the offset and the turn about the vertical axis (z) of the motion ~motion, which holds it at ~start
for ~hold seconds first. Every move of wave and drag starts and ends at rest (smoothstep), so the
handles the frame holds never jerk. Its time is rospy's: under /use_sim_time (the launch files'
use_sim_time:=true) it moves on the node's /clock and stamps the frame with it, so a node slower than
real time sees the motion at its own pace.

wave (the default; launch/held_cloth.launch), in a loop: a slow wave, ~waves swings of ~amplitude
    metres along x, ~wave_period seconds each; a turn of ~turn_deg degrees in ~turn_seconds, held
    for ~hold seconds, and back.
drag (launch/cloth_table.launch scenario:=drag), in a loop: lowered by ~lower metres in ~seconds;
    dragged by ~drag metres along y in ~seconds; held; dragged back, raised back.
fold (launch/fold.launch), once: after ~hold seconds, over a half circle of ~radius metres in the
    y-z plane towards -y in ~seconds (a corner of a towel lying on a table carried over its middle
    onto the other half), ending ~clearance metres above where it started; then held there.
hold (launch/rollout_demo.launch): still at ~start (a planner's rollouts move the frame in simulation only).
circle (test/node/handles*.test): on a circle of ~radius metres in the x-z plane once every
    ~period seconds, turning by up to ~angle radians.

rosrun modal_mass_spring gripper.py _motion:=circle _radius:=0.1 _period:=4"""
import math
import sys

import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped


def smoothstep(u):
    u = min(1.0, max(0.0, u))
    return u * u * (3.0 - 2.0 * u)


class Wave:
    def __init__(self, amplitude, wave_period, waves, turn, turn_seconds, hold):
        self.amplitude, self.wave_period, self.waves = amplitude, wave_period, waves
        self.turn, self.turn_seconds, self.hold = turn, turn_seconds, hold
        self.wave_seconds = waves * wave_period
        self.period = 2.0 * hold + self.wave_seconds + 2.0 * turn_seconds

    def at(self, t):
        """((x, y, z) offset in m, yaw in rad) at t seconds."""
        t = math.fmod(max(0.0, t), self.period)
        t -= self.hold
        if t < 0.0:
            return (0.0, 0.0, 0.0), 0.0
        if t < self.wave_seconds:
            # The swing fades in over the first half wave and out over the last.
            half = 0.5 * self.wave_period
            envelope = smoothstep(t / half) * smoothstep((self.wave_seconds - t) / half)
            return (self.amplitude * envelope * math.sin(2.0 * math.pi * t / self.wave_period), 0.0, 0.0), 0.0
        t -= self.wave_seconds
        if t < self.turn_seconds:
            return (0.0, 0.0, 0.0), self.turn * smoothstep(t / self.turn_seconds)
        t -= self.turn_seconds
        if t < self.hold:
            return (0.0, 0.0, 0.0), self.turn
        t -= self.hold
        return (0.0, 0.0, 0.0), self.turn * (1.0 - smoothstep(t / self.turn_seconds))


class Drag:
    def __init__(self, lower, drag, seconds, hold):
        self.lower, self.drag, self.seconds, self.hold = lower, drag, seconds, hold

    def at(self, t):
        """((x, y, z) offset in m, yaw in rad) at t seconds of the loop."""
        lower, drag, seconds, hold = self.lower, self.drag, self.seconds, self.hold
        t = t % (2.0 * hold + 4.0 * seconds) - hold
        if t < 0.0:
            return (0.0, 0.0, 0.0), 0.0
        if t < seconds:
            return (0.0, 0.0, -lower * smoothstep(t / seconds)), 0.0
        t -= seconds
        if t < seconds:
            return (0.0, drag * smoothstep(t / seconds), -lower), 0.0
        t -= seconds
        if t < hold:
            return (0.0, drag, -lower), 0.0
        t -= hold
        if t < seconds:
            return (0.0, drag * (1.0 - smoothstep(t / seconds)), -lower), 0.0
        t -= seconds
        return (0.0, 0.0, -lower * (1.0 - smoothstep(t / seconds))), 0.0


class Fold:
    def __init__(self, radius, seconds, clearance, hold):
        self.radius, self.seconds, self.clearance, self.hold = radius, seconds, clearance, hold

    def at(self, t):
        """((x, y, z) offset in m, yaw in rad) at t seconds."""
        u = smoothstep((t - self.hold) / self.seconds)
        phi = math.pi * u
        return (0.0, -self.radius * (1.0 - math.cos(phi)), self.radius * math.sin(phi) + self.clearance * u), 0.0


class Circle:
    def __init__(self, radius, period, angle, hold):
        self.radius, self.period, self.angle, self.hold = radius, period, angle, hold

    def at(self, t):
        """((x, y, z) offset in m, yaw in rad) at t seconds."""
        phase = 2.0 * math.pi * max(0.0, t - self.hold) / self.period
        offset = (self.radius * math.sin(phase), 0.0, self.radius * (1.0 - math.cos(phase)))
        return offset, self.angle * math.sin(phase)


def is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def param(name, default, positive=False):
    value = rospy.get_param("~" + name, default)
    if not is_number(value) or (positive and value <= 0.0):
        fail("~%s = %r: must be a finite number%s" % (name, value, " > 0" if positive else ""))
    return value


def fail(message):
    rospy.logfatal("gripper: " + message)
    sys.exit(1)


class Hold:
    def at(self, t):
        return (0.0, 0.0, 0.0), 0.0


def motion_from_params():
    name = rospy.get_param("~motion", "wave")
    if name == "wave":
        return Wave(param("amplitude", 0.15), param("wave_period", 3.0, True), param("waves", 2),
                    math.radians(param("turn_deg", 90.0)), param("turn_seconds", 3.0, True), param("hold", 2.0))
    if name == "drag":
        return Drag(param("lower", 0.3), param("drag", 0.5), param("seconds", 4.0, True), param("hold", 2.0))
    if name == "circle":
        return Circle(param("radius", 0.1), param("period", 4.0, True), param("angle", 0.3), param("hold", 1.0))
    if name == "fold":
        return Fold(param("radius", 0.25, True), param("seconds", 4.0, True), param("clearance", 0.01),
                    param("hold", 1.0))
    if name == "hold":
        return Hold()
    fail("~motion = %r: must be one of wave, drag, fold, circle, hold" % (name,))


def main():
    rospy.init_node("gripper")
    motion = motion_from_params()
    frame = rospy.get_param("~frame", "gripper")
    parent = rospy.get_param("~parent", "world")
    start = rospy.get_param("~start", [0.0, 0.0, 0.0])
    if not isinstance(start, list) or len(start) != 3 or not all(is_number(v) for v in start):
        fail("~start = %r: must be a list of 3 finite numbers (x, y, z in m)" % (start,))
    rate = rospy.Rate(param("rate", 50.0, True))
    broadcaster = tf2_ros.TransformBroadcaster()
    begin = rospy.Time.now()
    last = None
    while not rospy.is_shutdown():
        now = rospy.Time.now()
        if now != last:  # tf2 refuses a second transform at the same stamp
            last = now
            offset, yaw = motion.at((now - begin).to_sec())
            t = TransformStamped()
            t.header.stamp = now
            t.header.frame_id = parent
            t.child_frame_id = frame
            t.transform.translation.x = start[0] + offset[0]
            t.transform.translation.y = start[1] + offset[1]
            t.transform.translation.z = start[2] + offset[2]
            t.transform.rotation.z = math.sin(0.5 * yaw)
            t.transform.rotation.w = math.cos(0.5 * yaw)
            broadcaster.sendTransform(t)
        try:
            rate.sleep()
        except rospy.ROSInterruptException:
            break


if __name__ == "__main__":
    main()
