#!/usr/bin/env python3
"""How far a rollout method is from `full` on the planner's candidates: sends rollout_planner.py's
candidates (the same seed) to the node's ~rollout once with `full` and once with each --methods entry,
and prints per method the wall time, the RMS particle distance to `full` at each sample time (mean and
largest over the candidates), the deepest particle below the table top, and whether the planner would
pick the same candidate. Run beside launch/rollout_demo.launch:

  python3 benchmark/rollout_accuracy.py --candidates 16 --horizon 2 --methods coarse,full@0.0005 [--table_z Z]"""
import argparse
import importlib.util
import math
import os
import random
import time

import actionlib
import rospy
from modal_mass_spring.msg import RolloutAction, RolloutGoal
from modal_mass_spring.srv import GetState

_here = os.path.dirname(os.path.abspath(__file__))
_spec = importlib.util.spec_from_file_location("rollout_planner", os.path.join(_here, "..", "scripts", "rollout_planner.py"))
planner = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(planner)


def rms(a, b):
    return math.sqrt(sum((p.x - q.x) ** 2 + (p.y - q.y) ** 2 + (p.z - q.z) ** 2 for p, q in zip(a, b)) / len(a))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--candidates", type=int, default=16)
    parser.add_argument("--horizon", type=float, default=2.0)
    parser.add_argument("--samples", type=int, default=4, help="sample times, evenly over the horizon")
    parser.add_argument("--methods", default="coarse")
    parser.add_argument("--time_step", type=float, default=0.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--table_z", type=float, default=None, help="the table top (m); none: not checked")
    parser.add_argument("--node", default="/modal_mass_spring")
    args = parser.parse_args(rospy.myargv()[1:])
    rospy.init_node("rollout_accuracy", anonymous=True)
    rospy.wait_for_service(args.node + "/get_state", timeout=60.0)
    state = rospy.ServiceProxy(args.node + "/get_state", GetState)().state
    client = actionlib.SimpleActionClient(args.node + "/rollout", RolloutAction)
    client.wait_for_server(rospy.Duration(60.0))

    rng = random.Random(args.seed)
    frames = list(dict.fromkeys(state.handle_frames))
    poses = [state.handle_frame_poses[state.handle_frames.index(f)] for f in frames]
    plans = [(rng.uniform(0.0, 1.0), rng.uniform(0.0, 1.0)) for _ in range(args.candidates)]
    candidates = [planner.candidate(frames, poses, lower, carry, args.horizon, 4) for lower, carry in plans]
    times = [args.horizon * (k + 1) / args.samples for k in range(args.samples)]

    def run(method, time_step=args.time_step):
        goal = RolloutGoal(use_state=True, state=state, method=method, time_step=time_step, horizon=args.horizon, sample_times=times,
                           candidates=candidates)
        start = time.monotonic()
        client.send_goal(goal)
        client.wait_for_result()
        result = client.get_result()
        if result is None or not result.success:
            raise SystemExit("%s: %s" % (method, result.message if result else "no result"))
        return time.monotonic() - start, sorted(result.outcomes, key=lambda o: o.candidate), result.message

    def best(outcomes):
        return min((planner.spread(o.samples[-1].positions), o.candidate) for o in outcomes if not o.diverged)[1]

    wall_full, full, _ = run("full")
    print("full: %.2f s wall, best candidate %d" % (wall_full, best(full)))
    for entry in args.methods.split(","):
        method, _, step = entry.partition("@")
        wall, outcomes, message = run(method, float(step) if step else args.time_step)
        per_time = [[rms(o.samples[k].positions, f.samples[k].positions) for o, f in zip(outcomes, full)]
                    for k in range(len(times))]
        deepest = None
        if args.table_z is not None:
            deepest = max(args.table_z - p.z for o in outcomes for s in o.samples for p in s.positions)
        print(message)
        print("%s: %.2f s wall (%.1f times full's), best candidate %d" % (method, wall, wall_full / wall, best(outcomes)))
        for t, distances in zip(times, per_time):
            print("  t = %.2f s: RMS to full mean %.4f m, largest %.4f m" % (t, sum(distances) / len(distances), max(distances)))
        print("  mean over the samples and candidates: %.4f m" % (sum(map(sum, per_time)) / (len(times) * len(candidates))))
        if deepest is not None:
            print("  deepest particle below the table top: %.4f m" % deepest)


if __name__ == "__main__":
    main()
