#!/usr/bin/env python3
"""Measures how long a service call to a running node takes (not a test: a number for docs/benchmarks.md and
reviews). Calls ~pause with data=false (changes nothing on a running node) N times at random moments
and prints the median, 99th percentile and largest round trip.
Usage: measure_service_latency.py [node name, default /modal_mass_spring] [calls, default 200]"""
import random
import sys
import time

import rospy
from std_srvs.srv import SetBool


def main():
    node = sys.argv[1] if len(sys.argv) > 1 else "/modal_mass_spring"
    calls = int(sys.argv[2]) if len(sys.argv) > 2 else 200
    rospy.init_node("measure_service_latency", anonymous=True)
    rospy.wait_for_service(node + "/pause", timeout=120)
    pause = rospy.ServiceProxy(node + "/pause", SetBool, persistent=True)
    times = []
    for _ in range(calls):
        time.sleep(random.uniform(0.0, 0.05))
        start = time.monotonic()
        pause(False)
        times.append(time.monotonic() - start)
    times.sort()
    p = lambda q: times[min(len(times) - 1, int(q * len(times)))]
    print("%d calls to %s/pause: median %.1f ms, p99 %.1f ms, max %.1f ms"
          % (calls, node, 1e3 * p(0.5), 1e3 * p(0.99), 1e3 * times[-1]))


if __name__ == "__main__":
    main()
