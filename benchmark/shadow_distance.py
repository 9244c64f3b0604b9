#!/usr/bin/env python3
"""A method's live distance to the shadow `full` (the `rms_distance` of the node's ~status) over a
stretch of simulated time, on a launch file's gripper motion, with and without simulated time.

Starts `roslaunch -p 11399 modal_mass_spring LAUNCH ARGS... shadow_full:=true rviz:=false` (its own master),
reads /modal_mass_spring/status until --seconds of simulated time have passed after --skip seconds,
then stops the launch. Prints the median, 95th percentile and largest rms_distance, the mean achieved
real-time factor, and the wall time taken. Run it on a quiet machine: a node that falls behind is what
it measures.

  /usr/bin/python3 benchmark/shadow_distance.py --seconds 60 -- held_cloth.launch basis:=skinning \\
      method:=physical use_sim_time:=true
Needs the workspace sourced (source $MODAL_WS/devel/setup.bash).
"""
import argparse
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import rosgraph
import rospy
from modal_mass_spring.msg import Status


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds measured")
    parser.add_argument("--skip", type=float, default=2.0, help="simulated seconds left out at the start")
    parser.add_argument("--timeout", type=float, default=1800.0, help="wall seconds before giving up")
    parser.add_argument("--csv", help="also write each status's simulated time and rms_distance to this file")
    parser.add_argument("launch", nargs="+", help="the launch file, then its arguments")
    args = parser.parse_args()
    if args.seconds <= 0.0 or args.skip < 0.0:
        parser.error("--seconds must be positive and --skip not negative")

    port = "11399"
    env = dict(os.environ, ROS_MASTER_URI="http://localhost:" + port)
    os.environ["ROS_MASTER_URI"] = env["ROS_MASTER_URI"]
    launch = subprocess.Popen(["roslaunch", "-p", port, "modal_mass_spring"] + args.launch +
                              ["shadow_full:=true", "rviz:=false"], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, start_new_session=True)
    master = rosgraph.Master("/shadow_distance")
    for _ in range(120):
        if master.is_online() or launch.poll() is not None:
            break
        time.sleep(0.5)
    if launch.poll() is not None:
        sys.exit("roslaunch ended at once (exit code %d): run it by hand to see why" % launch.returncode)
    samples, factors, times = [], [], []
    done = threading.Event()
    lock = threading.Lock()

    def on_status(msg):
        if msg.reference != "full" or msg.sim_time < args.skip:
            return
        with lock:
            samples.append(msg.rms_distance)
            times.append(msg.sim_time)
            factors.append(msg.real_time_factor)
        if msg.sim_time >= args.skip + args.seconds:
            done.set()

    start = time.time()
    try:
        rospy.init_node("shadow_distance", anonymous=True, disable_signals=True)
        rospy.Subscriber("/modal_mass_spring/status", Status, on_status, queue_size=100)
        finished = done.wait(args.timeout)
    finally:
        os.killpg(launch.pid, signal.SIGINT)
        try:
            launch.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(launch.pid, signal.SIGKILL)
    wall = time.time() - start
    with lock:
        distances = np.array(samples)
        rtf = np.array(factors)
    if distances.size == 0:
        sys.exit("no status with a reference came from the node: is shadow_full on, did it start?")
    print("%s: %d statuses over %s%.0f simulated s in %.0f wall s" %
          (" ".join(args.launch), distances.size, "" if finished else "(timed out) ", args.seconds, wall))
    print("rms_distance to the shadow full: median %.4f m, 95th percentile %.4f m, largest %.4f m" %
          (np.median(distances), np.percentile(distances, 95), distances.max()))
    print("achieved real-time factor: mean %.3f" % rtf.mean())
    if args.csv:
        with open(args.csv, "w") as out:
            out.write("sim_time,rms_distance\n")
            with lock:
                for t, d in zip(times, samples):
                    out.write("%.4f,%.6g\n" % (t, d))


if __name__ == "__main__":
    main()
