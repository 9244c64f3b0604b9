#!/usr/bin/env python3
"""The wall time from the node's start to its first published markers, cold and cached.

Starts its own ROS master on a free port, loads a config into the node's namespace, then starts the
node --runs times: each time it measures from the moment the process is spawned to the first
~markers message a subscriber here receives (the node's whole start-up: process, ROS connections,
the Simulation's build or cache load, the first tick), and stops it. The first run uses an empty
cache directory unless --keep-cache (a cold start that fills it); the others load from it. With
--cpu-seconds, the last run also gives the node's share of one core and, from ~status over the same
window, its stepping per tick and per step.

  benchmark/measure_start.py --config config/cloth_large.yaml --runs 4 [--cpu-seconds 20]
Needs the workspace's setup.bash sourced (rosrun finds the node).
"""
import argparse
import os
import re
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time


def free_port():
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", required=True, help="YAML file of node parameters")
    parser.add_argument("--runs", type=int, default=4, help="node starts, the first cold (default 4)")
    parser.add_argument("--cache-dir", help="cache folder (default: a new temporary one)")
    parser.add_argument("--keep-cache", action="store_true", help="do not empty the cache before the first run")
    parser.add_argument("--timeout", type=float, default=600.0, help="s to wait for one start's markers")
    parser.add_argument("--cpu-seconds", type=float, default=0.0,
                        help="after the last start's first markers, measure the node's share of one core over this "
                             "many seconds of wall time (default 0: not measured)")
    args = parser.parse_args()
    if args.runs < 1:
        parser.error("--runs must be at least 1")

    cache_dir = args.cache_dir or tempfile.mkdtemp(prefix="modal_cache_")
    if not args.keep_cache:
        shutil.rmtree(cache_dir, ignore_errors=True)
    port = free_port()
    os.environ["ROS_MASTER_URI"] = "http://localhost:%d" % port
    master = subprocess.Popen(["roscore", "-p", str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        import rospy
        import rosparam
        from modal_mass_spring.msg import Status
        from visualization_msgs.msg import MarkerArray

        for _ in range(100):
            try:
                import rosgraph
                if rosgraph.Master("/measure").is_online():
                    break
            except Exception:
                pass
            time.sleep(0.1)
        name = "/measured_node"
        for params, ns in rosparam.load_file(args.config, default_namespace=name):
            rosparam.upload_params(ns, params)
        rospy.set_param(name + "/cache_dir", cache_dir)
        rospy.init_node("measure_start", anonymous=True, disable_signals=True)
        received = threading.Event()
        rospy.Subscriber(name + "/markers", MarkerArray, lambda _msg: received.set(), queue_size=1)
        statuses = []  # ~status while the core share is measured
        measuring = threading.Event()
        rospy.Subscriber(name + "/status", Status, lambda msg: measuring.is_set() and statuses.append(msg),
                         queue_size=100)

        times = []
        for run in range(args.runs):
            received.clear()
            start = time.monotonic()
            node = subprocess.Popen(["rosrun", "modal_mass_spring", "modal_mass_spring_node", "__name:=measured_node"],
                                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            log = []
            reader = threading.Thread(target=lambda: log.extend(iter(node.stdout.readline, "")), daemon=True)
            reader.start()
            got = received.wait(args.timeout)
            elapsed = time.monotonic() - start
            share = None
            if got and run == args.runs - 1 and args.cpu_seconds > 0:
                # rosrun execs the node: its pid is the node's. utime + stime in clock ticks.
                def cpu():
                    with open("/proc/%d/stat" % node.pid) as stat:
                        fields = stat.read().rsplit(")", 1)[1].split()
                    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
                before, wall = cpu(), time.monotonic()
                measuring.set()
                time.sleep(args.cpu_seconds)
                measuring.clear()
                share = (cpu() - before) / (time.monotonic() - wall)
            node.send_signal(signal.SIGINT)
            try:
                node.wait(30)
            except subprocess.TimeoutExpired:
                node.kill()
                node.wait()
            reader.join(5)
            cache_line = next((l.strip() for l in log if "basis loaded" in l or "basis computed" in l), "(no cache line)")
            cache_line = re.sub(r"\x1b\[[0-9;]*m|\[ INFO\] \[[0-9.]+\]: ", "", cache_line)
            if not got:
                print("run %d: no markers within %g s; the node's output:\n%s" % (run + 1, args.timeout, "".join(log)))
                return 1
            times.append(elapsed)
            print("run %d: %.3f s to the first markers; %s" % (run + 1, elapsed, cache_line))
            if share is not None:
                print("run %d: the node used %.1f%% of one core over %g s of running" % (run + 1, 100 * share,
                                                                                        args.cpu_seconds))
                if statuses:
                    # The stepping per tick and per step as ~status reports them, medians over the window.
                    print("  ~status over %d ticks: median %.3f ms of stepping per tick (%s steps), %.2f us per step; "
                          "basis_from_cache %s, cubature_from_cache %s"
                          % (len(statuses), 1e3 * statistics.median(m.tick_step_seconds for m in statuses),
                             "/".join(str(n) for n in sorted({m.tick_steps for m in statuses})),
                             1e6 * statistics.median(m.step_seconds for m in statuses),
                             statuses[-1].basis_from_cache, statuses[-1].cubature_from_cache))
                # Its last status line (status_log_period) and any warning: did it run, at what cost?
                clean = [re.sub(r"\x1b\[[0-9;]*m", "", l).strip() for l in log]
                for line in [l for l in clean if "WARN" in l or "ERROR" in l][:3] + clean[-1:]:
                    print("  " + line)
        if len(times) > 1:
            print("cached starts (runs 2 to %d): median %.3f s, min %.3f s, max %.3f s"
                  % (len(times), statistics.median(times[1:]), min(times[1:]), max(times[1:])))
        return 0
    finally:
        master.send_signal(signal.SIGINT)
        master.wait()
        if not args.cache_dir:
            shutil.rmtree(cache_dir, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
