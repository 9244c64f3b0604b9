#!/usr/bin/env python3
"""Starts rviz with its arguments where it can run: rviz installed and a display to draw on. Elsewhere
(a headless robot, a container, a machine without rviz) it says why in one line on stderr and exits 0,
so the launch files that start it run the simulation there too; rviz:=false leaves it out."""
import os
import sys

import rospkg


def why_not(environ, find_package):
    """Empty when rviz can start, else the reason it cannot."""
    if not environ.get("DISPLAY") and not environ.get("WAYLAND_DISPLAY"):
        return "no display ($DISPLAY is not set)"
    try:
        find_package("rviz")
    except rospkg.ResourceNotFound:
        return "rviz is not installed (Debian: apt install rviz; ROS from packages.ros.org: ros-noetic-rviz)"
    return ""


def main():
    reason = why_not(os.environ, rospkg.RosPack().get_path)
    if reason:
        sys.stderr.write("rviz not started: %s; the simulation runs without it (rviz:=false hides this line)\n"
                         % reason)
        return 0
    # roslaunch's own arguments (__name:=, __log:=) go on to rviz with the rest.
    os.execvp("rosrun", ["rosrun", "rviz", "rviz"] + sys.argv[1:])


if __name__ == "__main__":
    sys.exit(main())
