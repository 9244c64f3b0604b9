#!/usr/bin/env python3
"""Rostest sweep of bad node parameters: for each case the node is started on the paper's 2D config
with one thing wrong (on the parameter server, or on the command line as rosrun passes it), and must
exit with code 1 (not a signal, not a hang) and one FATAL line naming the parameter, before it builds
anything (no start-up line). One master (rostest's) serves every case."""
import re
import os
import subprocess
import sys
import unittest

import rospkg
import rospy
import rostest
import yaml
from roslib.packages import find_node

NAN = float("nan")

# (parameters set on the server, rosrun command-line arguments, the names the FATAL may give[, text
# the FATAL must hold: what is allowed])
CASES = [
    ({"rows": 0}, [], ["rows"]),
    ({"rows": -3}, [], ["rows"]),
    ({"rows": "abc"}, [], ["rows"]),
    ({"rows": 5.5}, [], ["rows"]),
    ({"cols": 0}, [], ["cols"]),
    ({"rows": 1, "cols": 1}, [], ["rows", "cols"]),
    ({"rows": 100000000}, [], ["rows"]),
    ({"spacing": 0.0}, [], ["spacing"]),
    ({"spacing": -0.1}, [], ["spacing"]),
    ({}, ["_spacing:=ten"], ["spacing"]),
    ({"dimension": 4}, [], ["dimension"]),
    ({"mass": 0.0}, [], ["mass"]),
    ({"mass": NAN}, [], ["mass"]),
    ({"structural_stiffness": -1.0}, [], ["structural_stiffness"]),
    ({"structural_stiffness": "3.0e6x"}, [], ["structural_stiffness"]),
    ({"shear_stiffness": 0.0}, [], ["shear_stiffness"]),
    ({"bending": "yes"}, [], ["bending"]),
    ({"bending": True, "bending_stiffness": 0.0}, [], ["bending_stiffness"]),
    ({"fixed": [25]}, [], ["fixed"]),
    ({"fixed": [0, 0]}, [], ["fixed"]),
    ({"fixed": list(range(25))}, [], ["fixed"]),
    ({"fixed": "none"}, [], ["fixed"]),
    ({"gravity": [0.0, 0.0]}, [], ["gravity"]),
    ({}, ["_gravity:=[0,0"], ["gravity"]),
    ({}, ["_gravity:=[0,x,0]"], ["gravity"]),
    ({"gravity": [0.0, 1.0, -9.81]}, [], ["gravity"]),
    ({"gravity": [0.0, 0.0, NAN]}, [], ["gravity"]),
    ({"rotation_deg": 45.0}, [], ["rotation_deg"]),
    ({}, ["_method:=bogus"], ["method"]),
    ({"method": 3}, [], ["method"]),
    ({"method": "adaptive", "error_tolerance": -1.0}, [], ["error_tolerance"]),
    ({"method": "adaptive", "error_tolerance": NAN}, [], ["error_tolerance"]),
    ({"method": "adaptive", "adaptive_dwell": -0.5}, [], ["adaptive_dwell"]),
    ({"method": "adaptive", "adaptive_method": "linear"}, [], ["adaptive_method"]),
    ({"method": "coarse", "coarse_cols": 9}, [], ["coarse_cols"], "[2, cols 5]"),
    ({"coarse_cols": -1}, [], ["coarse_cols"]),
    ({"num_modes": 0}, [], ["num_modes"]),
    ({"num_modes": 60}, [], ["num_modes"]),
    ({"alpha": -1.0}, [], ["alpha"]),
    ({"beta": -1.0}, [], ["beta"]),
    ({"alpha": 1e6}, [], ["alpha"]),  # the explicit integrator's damping bound, alpha * time_step <= 2
    ({"time_step": 0.0}, [], ["time_step"]),
    ({"time_step": -0.001}, [], ["time_step"]),
    ({"divergence_limit": -1.0}, [], ["divergence_limit"]),
    ({"linearization": "bogus"}, [], ["linearization"]),
    ({"integrator": "bogus"}, [], ["integrator"]),
    ({"initial_state": "bogus"}, [], ["initial_state"]),
    ({"newton_max_iterations": 0}, [], ["newton_max_iterations"]),
    ({"memory_limit_gb": 0.0}, [], ["memory_limit_gb"]),
    ({"basis": "derivatives"}, [], ["basis"]),
    ({"num_derivative_modes": 2}, [], ["num_derivative_modes"]),  # with basis: linear_modes
    ({"basis": "modal_derivatives", "num_derivative_modes": -1}, [], ["num_derivative_modes"]),
    ({"basis": "modal_derivatives", "num_derivative_modes": 11}, [], ["num_derivative_modes"]),
    ({"basis": "modal_derivatives", "num_modes": 38, "num_derivative_modes": 3}, [], ["num_derivative_modes"]),
    ({"basis": "modal_derivatives", "num_derivative_modes": 2, "dimension": 3}, [], ["basis"]),
    ({"num_derivative_modes": "two"}, [], ["num_derivative_modes"]),
    ({"num_skinning_weights": 4}, [], ["num_skinning_weights"]),  # with basis: linear_modes
    ({"basis": "skinning", "num_skinning_weights": 0}, [], ["num_skinning_weights"]),
    ({"basis": "skinning", "num_skinning_weights": -2}, [], ["num_skinning_weights"]),
    ({"basis": "skinning", "num_skinning_weights": 26}, [], ["num_skinning_weights"]),  # 25 particles
    ({"basis": "skinning", "num_skinning_weights": 2.5}, [], ["num_skinning_weights"]),
    ({"memory_limit_gb": -1.0}, [], ["memory_limit_gb"]),
    ({"method": "cubature", "cubature_tolerance": 0.0}, [], ["cubature_tolerance"]),
    ({"cubature_tolerance": 1.5}, [], ["cubature_tolerance"]),
    ({"cubature_max_springs": -1}, [], ["cubature_max_springs"]),
    ({"cubature_max_springs": 100000}, [], ["cubature_max_springs"]),
    ({"cubature_training_poses": 0}, [], ["cubature_training_poses"]),
    ({"cubature_training_poses": -10}, [], ["cubature_training_poses"]),
    ({"cubature_max_training_poses": 50}, [], ["cubature_max_training_poses"]),
    ({"cubature_max_training_poses": -1}, [], ["cubature_max_training_poses"]),
    ({"cubature_pose_size": -0.1}, [], ["cubature_pose_size"]),
    ({"cubature_pose_size": 0.0}, [], ["cubature_pose_size"]),
    ({"cubature_seed": -1}, [], ["cubature_seed"]),
    ({"cubature_seed": "one"}, [], ["cubature_seed"]),
    ({"rows": 3000, "cols": 3000, "dimension": 3, "num_modes": 30}, [], ["rows"]),  # names memory_limit_gb too
    # the cubature's training beyond the limit (counted because the node starts on cubature)
    ({"method": "cubature", "cubature_training_poses": 100000, "memory_limit_gb": 1.0}, [],
     ["cubature_training_poses", "memory_limit_gb"]),
    ({"real_time_factor": 0.0}, [], ["real_time_factor"]),
    ({"real_time_factor": 10000.0}, [], ["real_time_factor"]),
    ({"real_time_factor": 1000.0, "publish_rate": 1.0}, [], ["real_time_factor"]),
    ({"publish_rate": -5.0}, [], ["publish_rate"]),
    ({"publish_rate": 0}, [], ["publish_rate"]),
    ({}, ["_publish_rate:=fast"], ["publish_rate"]),
    ({"markers_rate": -1.0}, [], ["markers_rate"]),
    ({"publish_rate": 10.0, "markers_rate": 20.0}, [], ["markers_rate", "publish_rate"]),
    ({"fixed_frame": ""}, [], ["fixed_frame"]),
    ({"fixed_frame": "/world"}, [], ["fixed_frame"]),
    ({"grid_frame": "world"}, [], ["grid_frame"]),
    ({"tf_particles": [25]}, [], ["tf_particles"]),
    ({"tf_particles": [1, 1]}, [], ["tf_particles"]),
    ({"tf_particles": [0.5]}, [], ["tf_particles"]),
    ({}, ["_tf_particles:=[0,"], ["tf_particles"]),
    ({"offset": [0.0, 0.0]}, [], ["offset"]),
    ({"offset": [0.0, NAN, 0.0]}, [], ["offset"]),
    ({"color_by_strain": "yes"}, [], ["color_by_strain"]),
    ({"strain_scale": 0.0}, [], ["strain_scale"]),
    ({"particle_diameter": -1.0}, [], ["particle_diameter"]),
    ({"spring_width": 0.0}, [], ["spring_width"]),
    ({"status_log_period": -1.0}, [], ["status_log_period"]),
    ({"detail_max_particles": -1}, [], ["detail_max_particles"]),
    ({"surface_max_cells": 0}, [], ["surface_max_cells"]),
    ({"show_surface": "yes"}, [], ["show_surface"]),
    ({"show_particles": 2}, [], ["show_particles"]),
    ({"show_springs": "off"}, [], ["show_springs"]),
    ({"show_labels": "yes"}, [], ["show_labels"]),
    ({"show_shadow": 1}, [], ["show_shadow"]),
    ({"methods": ["linear", "bogus"]}, [], ["methods"]),
    ({"methods": ["full", "full"]}, [], ["methods"]),
    ({"methods": []}, [], ["methods"]),
    ({}, ["_methods:=[linear,"], ["methods"]),
    ({"method_spacing": 0.0}, [], ["method_spacing"]),
    ({"method_spacing": -1.0}, [], ["method_spacing"]),
    ({"methods": ["linear", "full"], "shadow_full": True}, [], ["shadow_full"]),
    ({"shadow_full": "yes"}, [], ["shadow_full"]),
    ({}, ["_diagnostic_period:=-1"], ["diagnostic_period"]),
    ({"diagnostic_period": 0.0}, [], ["diagnostic_period"]),
    ({"drag_stiffness": -1.0}, [], ["drag_stiffness"]),
    ({"drag_stiffness": 1e5}, [], ["drag_stiffness"]),  # the paper grid's step takes at most 1e4 N/m
    ({"drag_stiffness": "stiff"}, [], ["drag_stiffness"]),
    ({"poke_impulse": -0.01}, [], ["poke_impulse"]),
    ({"poke_impulse": NAN}, [], ["poke_impulse"]),
    ({"handles": [{"frame": "gripper", "particles": [25]}]}, [], ["handles"]),
    ({"handles": [{"frame": "gripper", "particles": [0, 1]}, {"frame": "finger", "particles": [1]}]}, [],
     ["handles"]),
    ({"fixed": [0, 4], "handles": [{"frame": "gripper", "particles": [4]}]}, [], ["handles"]),
    ({"handles": [{"frame": "", "particles": [0]}]}, [], ["handles"]),
    ({"handles": [{"frame": "/gripper", "particles": [0]}]}, [], ["handles"]),
    ({"handles": [{"frame": "gripper", "particles": []}]}, [], ["handles"]),
    ({"handles": [{"frame": "gripper"}]}, [], ["handles"]),
    ({"handles": [{"frame": "gripper", "particles": [0], "pose": 1}]}, [], ["handles"]),
    ({"handles": [0, 4]}, [], ["handles"]),
    ({"colliders": [{"type": "sphere", "center": [0, 0, 0], "radius": 0.1, "frame": ""}]}, [], ["colliders"]),
    ({"colliders": [{"type": "sphere", "center": [0, 0, 0], "radius": 0.1, "frame": "/finger"}]}, [],
     ["colliders"]),
    ({"colliders": [{"type": "sphere", "center": [0, 0, 0], "radius": 0.1, "frame": 3}]}, [], ["colliders"]),
    # self-collision: a 2D grid, a thickness not positive, above the spacing or not finite, a friction below 0,
    # a modal method
    ({"self_collision": True}, [], ["self_collision"]),
    ({"dimension": 3, "method": "full", "self_collision": True, "self_collision_thickness": 0.0}, [],
     ["self_collision_thickness"]),
    ({"dimension": 3, "method": "full", "self_collision": True, "self_collision_thickness": 0.2}, [],
     ["self_collision_thickness"]),
    ({"dimension": 3, "method": "full", "self_collision": True, "self_collision_thickness": NAN}, [],
     ["self_collision_thickness"]),
    ({"dimension": 3, "method": "full", "self_collision": True, "self_friction": -0.5}, [], ["self_friction"]),
    ({"dimension": 3, "method": "physical", "self_collision": True}, [], ["method"]),
    ({"self_collision": "yes"}, [], ["self_collision"]),
    ({"handles": "gripper"}, [], ["handles"]),
    ({"handles": [{"frame": 3, "particles": [0]}]}, [], ["handles"]),
    ({"handles": [{"frame": "world", "particles": [0]}]}, [], ["handles"]),
    ({}, ["_handles:=[{frame: gripper, particles: [0]}"], ["handles"]),
    ({}, ["_handles:=[{frame: gripper, particles: [0, x]}]"], ["handles"]),
    ({"handle_formulation": "frame"}, [], ["handle_formulation"]),
    ({"handle_formulation": "moving_frame"}, [], ["handle_formulation"]),  # no handles
    ({"handle_formulation": "moving_frame", "fixed": [0], "handles": [{"frame": "gripper", "particles": [24]}]},
     [], ["handle_formulation"]),  # a fixed particle
    ({"handle_formulation": "moving_frame", "fixed": [],
      "handles": [{"frame": "left", "particles": [0]}, {"frame": "right", "particles": [4]}]}, [],
     ["handle_formulation"]),  # two frames
    ({}, ["_rows:=3000000000"], ["rows"], "[-2147483648, 2147483647]"),
    ({"colliders": [{"type": 5}]}, [], ["colliders"], "must be a string: plane, box, sphere or capsule"),
    ({"colliders": [{"type": "sphere", "center": [0.2, 0, -0.6], "radius": 0.1, "friction": True}]}, [],
     ["colliders"], "must be a number (the Coulomb coefficient"),
    ({"colliders": [{"type": "sphere", "center": [0.2, 0, 1e300], "radius": 0.1}]}, [], ["colliders"],
     "[-1e+06, 1e+06]"),
    ({"contact_thickness": 10.0}, [], ["contact_thickness"], "at most 1 x spacing = 0.1 m"),
    # the paper's grid is 2D (the x-z plane): a surface that pushes along y is refused
    ({"colliders": [{"type": "plane", "point": [0, 0.05, 0], "normal": [0, 1, 0]}]}, [], ["colliders"],
     "its y must be 0 on a 2D grid"),
    ({"colliders": [{"type": "sphere", "center": [0.2, 0.05, -0.2], "radius": 0.1}]}, [], ["colliders"],
     "a sphere centred off the plane"),
    # the grid starts inside the box
    ({"colliders": [{"type": "box", "center": [0.2, 0, -0.2], "half_extents": [0.5, 0.5, 0.1]}]}, [], ["colliders"],
     "m inside it (initial_state initial"),
    # A grid whose equilibrium and basis would take minutes: the node parameter fails at once.
    ({"rows": 600, "cols": 600, "dimension": 3, "num_modes": 30, "linearization": "equilibrium",
      "tf_particles": [360000]}, [], ["tf_particles"]),
    ({"rows": 600, "cols": 600, "dimension": 3, "num_modes": 30, "linearization": "equilibrium",
      "publish_rate": -1.0}, [], ["publish_rate"]),
]


def named(fatal, names):
    """Whether the FATAL line's quoted parameter ('rows', or 'rows x cols' for a pair) is one of names."""
    quoted = re.search(r"invalid parameter '([^']*)'", fatal)
    return bool(quoted) and any(re.search(r"\b%s\b" % n, quoted.group(1)) for n in names)


class NodeBadInputs(unittest.TestCase):
    def test_every_bad_input_is_refused_by_name(self):
        package = rospkg.RosPack().get_path("modal_mass_spring")
        with open(os.path.join(package, "config", "paper_2d.yaml")) as config:
            base = yaml.safe_load(config)
        executable = find_node("modal_mass_spring", "modal_mass_spring_node")
        self.assertTrue(executable, "modal_mass_spring_node not found")
        env = dict(os.environ, ROSCONSOLE_FORMAT="[${severity}] ${message}")
        self.assertGreaterEqual(len(CASES), 40)
        failures = []
        for index, case in enumerate(CASES):
            params, args, names = case[:3]
            allowed = case[3] if len(case) > 3 else None
            name = "bad_%02d" % index
            rospy.set_param("/" + name, dict(base, **params))
            what = "case %d: %s %s" % (index, params if len(str(params)) < 120 else "(large)", " ".join(args))
            try:
                run = subprocess.run([executable[0], "__name:=" + name] + args, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True, errors="replace", timeout=60)
            except subprocess.TimeoutExpired:
                failures.append("%s: no exit within 60 s (it came up, or hangs)" % what)
                continue
            finally:
                rospy.delete_param("/" + name)
            output = run.stdout
            fatal = [line for line in output.splitlines() if "[FATAL]" in line]
            if run.returncode != 1:
                failures.append("%s: exit code %d (negative: a signal)\n%s" % (what, run.returncode, output))
            elif len(fatal) != 1:
                failures.append("%s: %d FATAL lines\n%s" % (what, len(fatal), output))
            elif not named(fatal[0], names):
                failures.append("%s: the FATAL names none of %s: %s" % (what, names, fatal[0]))
            elif allowed and allowed not in fatal[0]:
                failures.append("%s: the FATAL does not say %r: %s" % (what, allowed, fatal[0]))
            elif re.search(r"grid \(\dD, \d+ particles", output):
                failures.append("%s: built a simulation before refusing\n%s" % (what, output))
            else:
                print("%s -> %s" % (what, fatal[0]))
        self.assertEqual(failures, [], "\n\n".join(failures))


if __name__ == "__main__":
    rospy.init_node("node_bad_inputs", anonymous=True)
    rostest.rosrun("modal_mass_spring", "node_bad_inputs", NodeBadInputs, sys.argv)
