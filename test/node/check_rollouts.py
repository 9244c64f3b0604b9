#!/usr/bin/env python3
"""Rostest checker of ~get_state, ~set_state and ~rollout (test/node/rollouts.test): paused, the node
steps 300 steps from a saved state; restored, it steps the same positions again; a rollout from that
state with the frame held where it is gives them too, on the node's own worker simulations, with
`full` and with the default method, `coarse`; bad goals are refused by name."""
import math
import threading
import time
import unittest

import actionlib
import rospy
import rostest
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import Pose
from modal_mass_spring.msg import (HandleTrajectory, RolloutAction, RolloutActionFeedback, RolloutCandidate,
                                   RolloutGoal)
from modal_mass_spring.srv import GetState, SetMethod, SetState, Step
from std_srvs.srv import SetBool

NODE = "/modal_mass_spring"
STEPS = 300


def largest_distance(a, b):
    return max(math.sqrt((p.x - q.x) ** 2 + (p.y - q.y) ** 2 + (p.z - q.z) ** 2) for p, q in zip(a, b))


class Rollouts(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_rollouts")
        rospy.wait_for_message(NODE + "/status", rospy.AnyMsg, timeout=60.0)
        cls.get_state = rospy.ServiceProxy(NODE + "/get_state", GetState)
        cls.set_state = rospy.ServiceProxy(NODE + "/set_state", SetState)
        cls.step = rospy.ServiceProxy(NODE + "/step", Step)
        cls.set_method = rospy.ServiceProxy(NODE + "/set_method", SetMethod)
        cls.pause = rospy.ServiceProxy(NODE + "/pause", SetBool)
        cls.lock = threading.Lock()
        cls.published_feedback = []

        def on_feedback(msg):
            with cls.lock:
                cls.published_feedback.append(msg)

        cls.feedback_sub = rospy.Subscriber(NODE + "/rollout/feedback", RolloutActionFeedback, on_feedback,
                                            queue_size=100)
        cls.client = actionlib.SimpleActionClient(NODE + "/rollout", RolloutAction)
        assert cls.client.wait_for_server(rospy.Duration(30.0))
        # The gripper frame found and the cloth swinging from it, then held for the checks.
        rospy.sleep(1.5)
        cls.pause(True)

    def rollout(self, goal):
        self.client.send_goal(goal)
        goal_id = self.client.gh.comm_state_machine.action_goal.goal_id.id
        self.assertTrue(self.client.wait_for_result(rospy.Duration(60.0)))
        # The last candidate's feedback and the result travel on topics of their own: the feedback may
        # come after the result, which the client then drops; it is read as published.
        deadline = time.time() + 5.0
        while True:
            with self.lock:
                feedback = [m.feedback for m in self.published_feedback if m.status.goal_id.id == goal_id]
            if (self.client.get_state() != GoalStatus.SUCCEEDED or len(feedback) >= len(goal.candidates)
                    or time.time() > deadline):
                return self.client.get_state(), self.client.get_result(), feedback
            time.sleep(0.05)

    def test_state_restored_and_rolled_out_replays_the_steps(self):
        saved = self.get_state().state
        self.assertEqual(saved.method, "full")
        self.assertEqual(saved.handle_frames, ["gripper"])
        self.assertTrue(self.step(STEPS).step_count > 0)
        stepped = self.get_state().state
        self.assertGreater(largest_distance(saved.positions, stepped.positions), 1e-4, "the cloth must move")

        reply = self.set_state(saved)
        self.assertTrue(reply.success, reply.message)
        self.step(STEPS)
        self.assertLess(largest_distance(self.get_state().state.positions, stepped.positions), 1e-9)

        horizon = STEPS * saved.time_step
        goal = RolloutGoal(use_state=True, state=saved, method="full", horizon=horizon, sample_times=[horizon],
                           candidates=[RolloutCandidate()] * 3)
        status, result, feedback = self.rollout(goal)
        self.assertEqual(status, GoalStatus.SUCCEEDED, result.message)
        self.assertEqual([o.candidate for o in result.outcomes], [0, 1, 2])
        self.assertEqual(sorted(f.candidate for f in feedback), [0, 1, 2])
        for outcome in result.outcomes:
            self.assertFalse(outcome.diverged, outcome.message)
            sample = outcome.samples[-1]
            self.assertLess(largest_distance(sample.positions, stepped.positions), 1e-9)
            self.assertEqual(len(sample.handle_wrenches), 1)
            self.assertEqual(len(sample.contact_forces), 1)
        # The live run was not touched.
        self.assertLess(largest_distance(self.get_state().state.positions, stepped.positions), 1e-9)

    def test_default_method_coarse_replays_the_live_coarse_steps(self):
        original = self.get_state().state
        try:
            reply = self.set_method("coarse")
            self.assertTrue(reply.success, reply.message)
            saved = self.get_state().state
            self.assertEqual(saved.method, "coarse")
            self.step(STEPS)
            stepped = self.get_state().state
            self.assertGreater(largest_distance(saved.positions, stepped.positions), 1e-4, "the cloth must move")
            horizon = STEPS * saved.time_step
            goal = RolloutGoal(use_state=True, state=saved, horizon=horizon, sample_times=[horizon],
                               candidates=[RolloutCandidate()])
            status, result, _ = self.rollout(goal)
            self.assertEqual(status, GoalStatus.SUCCEEDED, result.message)
            self.assertIn("with coarse at time_step %g s" % saved.time_step, result.message)
            self.assertLess(largest_distance(result.outcomes[0].samples[-1].positions, stepped.positions), 1e-9)
        finally:
            self.assertTrue(self.set_state(original).success)

    def test_default_coarse_from_full_takes_its_own_step(self):
        # The live method is full: the default coarse spans two live steps (4 x 4 on 2 x 2, the square
        # root of 4 particles a coarse one), and ends near full's steps.
        saved = self.get_state().state
        self.assertEqual(saved.method, "full")
        horizon = STEPS * saved.time_step
        goal = RolloutGoal(use_state=True, state=saved, method="full", horizon=horizon, sample_times=[horizon],
                           candidates=[RolloutCandidate()])
        status, result, _ = self.rollout(goal)
        self.assertEqual(status, GoalStatus.SUCCEEDED, result.message)
        full = result.outcomes[0].samples[-1].positions
        goal.method = ""
        status, result, _ = self.rollout(goal)
        self.assertEqual(status, GoalStatus.SUCCEEDED, result.message)
        self.assertIn("with coarse at time_step %g s" % (2 * saved.time_step), result.message)
        self.assertGreater(largest_distance(result.outcomes[0].samples[-1].positions, saved.positions), 1e-4)
        self.assertLess(largest_distance(result.outcomes[0].samples[-1].positions, full), 0.05)

    def test_bad_goals_refused_by_name(self):
        state = self.get_state().state
        pose = state.handle_frame_poses[0]
        lowered = Pose(position=pose.position, orientation=pose.orientation)
        moved = RolloutCandidate(handles=[HandleTrajectory(frame="gripper", times=[0.5], poses=[lowered])])
        unknown = RolloutCandidate(handles=[HandleTrajectory(frame="elbow", times=[0.5], poses=[lowered])])
        nan_pose = Pose(position=pose.position, orientation=pose.orientation)
        nan_pose.position.z = float("nan")
        nan = RolloutCandidate(handles=[HandleTrajectory(frame="gripper", times=[0.5], poses=[nan_pose])])
        cases = [
            (RolloutGoal(horizon=1.0, candidates=[]), "candidates", "rollout_max_candidates = 5"),
            (RolloutGoal(horizon=1.0, candidates=[moved] * 6), "candidates", "rollout_max_candidates = 5"),
            (RolloutGoal(horizon=0.0, candidates=[moved]), "horizon", "rollout_max_horizon = 2 s"),
            (RolloutGoal(horizon=3.0, candidates=[moved]), "horizon", "rollout_max_horizon = 2 s"),
            (RolloutGoal(horizon=1.0, candidates=[unknown]), "candidates[0].handles[0].frame", "'gripper'"),
            (RolloutGoal(horizon=1.0, candidates=[nan]), "candidates[0].handles[0].poses[0]", "finite"),
            (RolloutGoal(horizon=1.0, method="fastest", candidates=[moved]), "method", "physical"),
        ]
        for goal, name, allowed in cases:
            status, result, feedback = self.rollout(goal)
            self.assertEqual(status, GoalStatus.ABORTED, result.message)
            self.assertIn(name, result.message)
            self.assertIn(allowed, result.message)
            self.assertEqual(result.outcomes, [])
            self.assertEqual(feedback, [])


if __name__ == "__main__":
    rostest.rosrun("modal_mass_spring", "rollouts", Rollouts)
