#!/usr/bin/env python3
"""A random-shooting planner on the node's ~rollout action: it draws N candidate motions of the
grippers holding a towel over a table (both lowered by the same depth and carried along +y by the
same distance, along a smoothstep path, then held), has the node simulate each for S seconds from its
current state, and picks the one that lays the towel flattest: the smallest spread (standard
deviation) of the particles' heights at the horizon. Nothing moves the live cloth: the rollouts run on
the node's own copies of the simulation.

rosrun modal_mass_spring rollout_planner.py --candidates 64 --horizon 2 [--node /modal_mass_spring]
    [--seed 1] [--method coarse|full|...] [--time_step 0.001] [--max_lower 1.0] [--max_carry 1.0]
Its last line: rollouts: N candidates x S s simulated in W s wall (R times real time); best candidate K
(when every candidate diverged it says so and exits with 1)"""
import argparse
import math
import random
import sys
import time

import actionlib
import rospy
from modal_mass_spring.msg import HandleTrajectory, RolloutAction, RolloutCandidate, RolloutGoal
from modal_mass_spring.srv import GetState


def smoothstep(u):
    u = min(1.0, max(0.0, u))
    return u * u * (3.0 - 2.0 * u)


def candidate(frames, poses, lower, carry, horizon, waypoints):
    """Every gripper lowered by `lower` and carried by `carry` along +y over the first 3/4 of the
    horizon, through `waypoints` poses (each well within the node's limit on a move between two)."""
    motion = RolloutCandidate()
    move = 0.75 * horizon
    for frame, pose in zip(frames, poses):
        trajectory = HandleTrajectory(frame=frame)
        for k in range(1, waypoints + 1):
            t = move * k / waypoints
            s = smoothstep(t / move)
            p = type(pose)()
            p.position.x = pose.position.x
            p.position.y = pose.position.y + s * carry
            p.position.z = pose.position.z - s * lower
            p.orientation = pose.orientation
            trajectory.times.append(t)
            trajectory.poses.append(p)
        motion.handles.append(trajectory)
    return motion


def spread(points):
    heights = [p.z for p in points]
    mean = sum(heights) / len(heights)
    return math.sqrt(sum((z - mean) ** 2 for z in heights) / len(heights))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--candidates", type=int, default=64)
    parser.add_argument("--horizon", type=float, default=2.0, help="s")
    parser.add_argument("--node", default="/modal_mass_spring")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--method", default="", help="empty: the node's default for rollouts")
    parser.add_argument("--time_step", type=float, default=0.0,
                        help="s; 0: the goal's default (the live step; coarse: a whole multiple of it)")
    parser.add_argument("--max_lower", type=float, default=1.0, help="m: the deepest the grippers go down")
    parser.add_argument("--max_carry", type=float, default=1.0, help="m: the farthest they go along +y")
    args = parser.parse_args(rospy.myargv()[1:])
    if args.candidates < 1 or not args.horizon > 0.0:
        sys.exit("--candidates must be >= 1 and --horizon > 0")
    rospy.init_node("rollout_planner", anonymous=True)

    rospy.wait_for_service(args.node + "/get_state", timeout=60.0)
    state = rospy.ServiceProxy(args.node + "/get_state", GetState)().state
    if not state.handle_frames:
        sys.exit("the node at %s has no handles to plan with" % args.node)
    client = actionlib.SimpleActionClient(args.node + "/rollout", RolloutAction)
    if not client.wait_for_server(rospy.Duration(60.0)):
        sys.exit("no ~rollout action at %s" % args.node)

    rng = random.Random(args.seed)
    frames = list(dict.fromkeys(state.handle_frames))  # each frame once, its pose where it is now
    poses = [state.handle_frame_poses[state.handle_frames.index(f)] for f in frames]
    plans = [(rng.uniform(0.0, args.max_lower), rng.uniform(0.0, args.max_carry)) for _ in range(args.candidates)]
    waypoints = max(4, int(math.ceil(4.0 * max(args.max_lower, args.max_carry))))
    goal = RolloutGoal(method=args.method, time_step=args.time_step, horizon=args.horizon, sample_times=[args.horizon],
                       candidates=[candidate(frames, poses, lower, carry, args.horizon, waypoints)
                                   for lower, carry in plans])
    start = time.monotonic()
    client.send_goal(goal)
    client.wait_for_result()
    wall = time.monotonic() - start
    result = client.get_result()
    if result is None or not result.success:
        sys.exit("~rollout failed: %s" % (result.message if result else "no result"))
    best, best_spread = -1, float("inf")
    for outcome in result.outcomes:
        if outcome.diverged or not outcome.samples:
            print("candidate %d: diverged (%s)" % (outcome.candidate, outcome.message))
            continue
        s = spread(outcome.samples[-1].positions)
        lower, carry = plans[outcome.candidate]
        print("candidate %d: lowered %.3f m, carried %.3f m: height spread %.4f m" % (outcome.candidate, lower, carry, s))
        if s < best_spread:
            best, best_spread = outcome.candidate, s
    print(result.message)
    if best < 0:
        sys.exit("rollouts: every candidate diverged: no best candidate (a smaller --time_step or --method full may help)")
    print("rollouts: %d candidates x %g s simulated in %.2f s wall (%.1f times real time); best candidate %d"
          % (args.candidates, args.horizon, wall, args.candidates * args.horizon / wall, best))


if __name__ == "__main__":
    main()
