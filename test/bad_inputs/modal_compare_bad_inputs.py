#!/usr/bin/env python3
"""modal_compare on bad inputs: every one must end with exit code 2 and a message naming it, before
any work and without writing a file (see bad_input_runner.py for what is checked).

Usage: modal_compare_bad_inputs.py --tool PATH/modal_compare --configs DIR [--xunit FILE]
DIR is config/compare of the package (paper_2d.yaml: 5 x 5 in 2D, 40 free dofs, time_step 0.001).
"""
import argparse
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from bad_input_runner import Case, run_cases  # noqa: E402

OUT = "{work}/out"


def cases(configs):
    paper = str(pathlib.Path(configs).resolve() / "paper_2d.yaml")

    def tool(name, named, *args, **kw):
        """A case on paper_2d.yaml with the output in {work}/out."""
        return Case(name, ["--quiet", "--config", paper, "--output", OUT] + list(args), named, **kw)

    def setting(key, value, named=None, *more):
        """A case overriding one core parameter with --set."""
        name = "".join(c if c.isalnum() or c in "_.-" else "_" for c in f"set_{key}_{value}")
        return tool(name, named or key, "--set", f"{key}={value}", *more)

    def config(name, text, named, *args):
        """A case on a config file of its own."""
        return Case(name, ["--quiet", "--config", "{work}/bad.yaml", "--output", OUT] + list(args), named,
                    files={"bad.yaml": text})

    # A 4 x 4 sheet in 3D held by its top row, one scenario; the cases add a line to its handle or
    # scenario map, or replace a part.
    held = ("rows: 4\ncols: 4\ndimension: 3\nfixed: []\nlinearization: equilibrium\nnum_modes: 4\n"
            "handle_scenarios:\n  - name: lift\n    handles:\n      - particles: [0, 1, 2, 3]\n"
            "        translation: [0, 0, 0.1]\n")

    cloth = (pathlib.Path(configs) / "held_cloth.yaml").read_text()
    cloth = cloth[:cloth.index("handle_scenarios:")]

    table = [
        # ------------------------------------------------ the command line
        Case("no_config", ["--quiet", "--output", OUT, "--experiment", "accuracy"], "--config"),
        Case("config_missing_value", ["--output", OUT, "--config"], "--config"),
        Case("config_not_found", ["--config", "{work}/nonexistent.yaml", "--output", OUT], "nonexistent.yaml"),
        Case("config_is_a_folder", ["--config", "{work}", "--output", OUT], "config"),
        tool("unknown_option", "--frobnicate", "--frobnicate"),
        tool("single_dash_option", "-x", "-x"),
        tool("positional_argument", "stray", "stray"),
        tool("option_twice", "--steps", "--steps", "5", "--steps", "6"),
        tool("cache_dir_empty", "--cache-dir", "--cache-dir", ""),
        tool("cache_dir_with_no_cache", "--cache-dir", "--no-cache", "--cache-dir", "{work}/cache"),
        tool("no_cache_twice", "--no-cache", "--no-cache", "--no-cache"),
        tool("experiment_unknown", "speed", "--experiment", "speed"),
        tool("experiment_empty", "--experiment", "--experiment", ""),
        tool("experiment_empty_item", "--experiment", "--experiment", "accuracy,,cost"),
        tool("experiment_twice_in_list", "--experiment", "--experiment", "accuracy,accuracy"),
        tool("methods_unknown", "quadratic", "--methods", "linear,quadratic"),
        tool("methods_empty", "--methods", "--methods", ""),
        tool("methods_twice_in_list", "--methods", "--methods", "linear,linear"),
        tool("steps_zero", "--steps", "--steps", "0"),
        tool("steps_negative", "--steps", "--steps", "-5"),
        tool("steps_not_a_number", "--steps", "--steps", "many"),
        tool("steps_not_an_integer", "--steps", "--steps", "1e3"),
        tool("steps_beyond_int", "--steps", "--steps", "99999999999"),
        tool("interval_zero", "--interval", "--interval", "0"),
        tool("sample_zero", "--sample", "--sample", "0"),
        tool("sample_not_dividing_interval", "--sample", "--sample", "300"),
        tool("sample_above_steps", "--sample", "--steps", "500", "--interval", "1000", "--sample", "1000"),
        tool("coarse_step_multiple_negative", "--coarse-step-multiple", "--coarse-step-multiple", "-1"),
        tool("coarse_step_multiple_not_dividing_sample", "--coarse-step-multiple", "--coarse-step-multiple", "3"),
        tool("reference_time_step_tiny", "--reference-time-step", "--experiment", "accuracy",
             "--reference-time-step", "1e-300"),
        tool("reference_time_step_not_dividing", "--reference-time-step", "--experiment", "accuracy",
             "--reference-time-step", "0.0003"),
        tool("reference_time_step_above_time_step", "--reference-time-step", "--experiment", "accuracy",
             "--reference-time-step", "0.002"),
        tool("reference_time_step_negative", "--reference-time-step", "--reference-time-step", "-1"),
        tool("reference_time_step_nan", "--reference-time-step", "--reference-time-step", "nan"),
        tool("max_time_step_tiny", "--max-time-step", "--max-time-step", "1e-10"),
        tool("max_time_step_zero", "--max-time-step", "--max-time-step", "0"),
        tool("max_time_step_inf", "--max-time-step", "--max-time-step", "inf"),
        tool("max_time_step_below_time_step", "--max-time-step", "--experiment", "stability",
             "--max-time-step", "0.0005"),
        tool("tolerance_below_an_ulp", "--tolerance", "--experiment", "stability", "--tolerance", "1e-16"),
        tool("tolerance_zero", "--tolerance", "--tolerance", "0"),
        tool("tolerance_one", "--tolerance", "--tolerance", "1"),
        tool("tolerance_nan", "--tolerance", "--tolerance", "nan"),
        tool("stability_steps_zero", "--stability-steps", "--stability-steps", "0"),
        tool("scan_ratio_one", "--scan-ratio", "--scan-ratio", "1"),
        tool("scan_ratio_large", "--scan-ratio", "--scan-ratio", "3"),
        tool("window_factor_below_one", "--window-factor", "--window-factor", "0.5"),
        tool("check_factor_not_a_number", "--check-factor", "--check-factor", "zero"),
        tool("check_factor_negative", "--check-factor", "--check-factor", "-1"),
        tool("check_factor_without_integrators", "--check-factor", "--experiment", "stability", "--check-factor", "10"),
        tool("check_factor_without_stability", "--check-factor", "--experiment", "accuracy", "--check-factor", "10",
             "--vary", "integrator=explicit,implicit"),
        tool("sizes_too_small", "--sizes", "--experiment", "cost", "--sizes", "1,5"),
        tool("sizes_empty_item", "--sizes", "--experiment", "cost", "--sizes", "5,,10"),
        tool("sizes_not_numbers", "--sizes", "--experiment", "cost", "--sizes", "five"),
        tool("sizes_fewer_dofs_than_modes", "--sizes 3", "--set", "num_modes=30", "--experiment", "cost",
             "--sizes", "5,3"),
        tool("sizes_huge", "--sizes 100000", "--experiment", "cost", "--sizes", "5,100000"),
        tool("repeats_zero", "--repeats", "--repeats", "0"),
        tool("min_repeat_seconds_zero", "--min-repeat-seconds", "--min-repeat-seconds", "0"),
        tool("min_repeat_seconds_huge", "--min-repeat-seconds", "--min-repeat-seconds", "1e9"),
        tool("tag_with_slash", "--tag", "--tag", "a/b"),
        tool("tag_empty", "--tag", "--tag", ""),
        tool("tag_dot_dot", "--tag", "--tag", ".."),
        Case("output_under_a_file", ["--quiet", "--config", paper, "--output", "{work}/file/out"], "--output",
             files={"file": "a regular file, not a folder\n"}),
        Case("output_in_proc", ["--quiet", "--config", paper, "--output", "/proc/modal_compare_out"], "--output"),
        tool("set_without_equals", "--set", "--set", "rows"),
        tool("set_without_key", "--set", "--set", "=5"),
        tool("set_without_value", "--set", "--set", "rows="),
        tool("set_bad_key", "--set", "--set", "bad-key=3"),
        tool("set_twice", "rows", "--set", "rows=5", "--set", "rows=6"),
        tool("set_unknown_key", "stifness", "--set", "stifness=3"),
        tool("set_node_key", "publish_rate", "--set", "publish_rate=30"),
        tool("set_invalid_yaml", "rows", "--set", "rows=[1, 2"),
        tool("vary_unknown_value", "sideways", "--vary", "integrator=explicit,sideways"),
        tool("vary_method", "--vary", "--vary", "method=full,linear"),
        tool("vary_empty_value", "--vary", "--vary", "integrator=explicit,,implicit"),
        tool("vary_value_twice", "--vary", "--vary", "integrator=explicit,explicit"),
        tool("vary_key_twice", "--vary", "--vary", "integrator=explicit", "--vary", "integrator=implicit"),
        tool("vary_unknown_key", "unknown_key", "--vary", "unknown_key=1,2"),
        tool("vary_without_equals", "--vary", "--vary", "integrator"),
        tool("vary_out_of_range", "num_modes", "--vary", "num_modes=4,41"),
        # ------------------------------------------------ every core parameter out of range
        setting("rows", "0"),
        setting("cols", "-3"),
        tool("set_one_particle", "rows", "--set", "rows=1", "--set", "cols=1"),
        setting("spacing", "0"),
        setting("spacing", "-1"),
        setting("spacing", ".nan"),
        setting("dimension", "4"),
        setting("mass", "0"),
        setting("mass", ".inf"),
        setting("structural_stiffness", "-1"),
        setting("shear_stiffness", "0"),
        tool("set_bending_stiffness_zero", "bending_stiffness", "--set", "bending=true", "--set",
             "bending_stiffness=0"),
        setting("fixed", "[25]"),
        setting("fixed", "[-1]"),
        setting("fixed", "[0, 0]"),
        setting("fixed", "[" + ", ".join(str(i) for i in range(25)) + "]"),
        setting("gravity", "[0, 0]"),
        setting("gravity", "[0, 0, .nan]"),
        setting("gravity", "[0, 1, -9.81]"),
        setting("rotation_deg", ".inf"),
        setting("rotation_deg", "30"),
        setting("method", "quadratic"),
        setting("num_modes", "0"),
        setting("num_modes", "41"),
        setting("alpha", "-1"),
        setting("beta", "-0.1"),
        setting("time_step", "0"),
        setting("time_step", "-1"),
        setting("time_step", ".inf"),
        setting("divergence_limit", "-1"),
        setting("linearization", "sideways"),
        setting("integrator", "sideways"),
        setting("initial_state", "sideways"),
        setting("newton_max_iterations", "0"),
        setting("memory_limit_gb", "0"),
        setting("memory_limit_gb", "-1"),
        setting("basis", "derivatives"),
        setting("handle_formulation", "frame"),
        setting("handle_formulation", "moving_frame"),  # no handles
        setting("num_derivative_modes", "2"),  # with basis: linear_modes
        setting("num_skinning_weights", "4"),  # with basis: linear_modes
        tool("num_skinning_weights_zero", "num_skinning_weights", "--set", "basis=skinning"),
        tool("num_skinning_weights_beyond_particles", "num_skinning_weights", "--set", "basis=skinning",
             "--set", "num_skinning_weights=26"),
        tool("num_skinning_weights_not_an_integer", "num_skinning_weights", "--set", "basis=skinning",
             "--set", "num_skinning_weights=2.5"),
        tool("num_derivative_modes_negative", "num_derivative_modes", "--set", "basis=modal_derivatives",
             "--set", "num_derivative_modes=-1"),
        tool("num_derivative_modes_beyond_pairs", "num_derivative_modes", "--set", "basis=modal_derivatives",
             "--set", "num_derivative_modes=11"),
        tool("num_derivative_modes_beyond_free_dofs", "num_derivative_modes", "--set", "basis=modal_derivatives",
             "--set", "num_modes=38", "--set", "num_derivative_modes=3"),
        tool("modal_derivatives_of_a_3d_sheet_at_rest", "basis", "--set", "basis=modal_derivatives",
             "--set", "num_derivative_modes=2", "--set", "dimension=3"),
        setting("cubature_tolerance", "0"),
        setting("cubature_tolerance", "1"),
        setting("cubature_max_springs", "-1"),
        setting("cubature_max_springs", "100000"),
        setting("cubature_training_poses", "0"),
        setting("cubature_training_poses", "-10"),
        setting("cubature_max_training_poses", "50"),
        setting("cubature_max_training_poses", "1.5"),
        setting("cubature_pose_size", "-0.1"),
        setting("cubature_pose_size", ".nan"),
        setting("cubature_seed", "-1"),
        setting("cubature_seed", "1.5"),
        # ------------------------------------------------ wrong types
        setting("mass", "heavy"),
        setting("rows", "5.5"),
        setting("rows", "2147483648", "[-2147483648, 2147483647]"),
        setting("bending", "3"),
        setting("fixed", "0"),
        setting("gravity", "{z: -9.81}"),
        setting("method", "[full]"),
        setting("num_modes", "[4]"),
        setting("num_derivative_modes", "two"),
        setting("time_step", "true"),
        setting("integrator", "{a: 1}"),
        # ------------------------------------------------ grids too large to build
        tool("grid_overflowing_int", "rows", "--set", "rows=65538", "--set", "cols=65536", "--experiment",
             "accuracy", "--steps", "200"),
        tool("grid_two_rows_overflowing_int", "cols", "--set", "rows=2", "--set", "cols=536870912",
             "--experiment", "accuracy", "--steps", "200"),
        tool("grid_beyond_memory", "memory_limit_gb", "--set", "rows=3000", "--set", "cols=3000",
             "--experiment", "accuracy", "--steps", "200"),
        tool("grid_too_many_modes_for_memory", "memory_limit_gb", "--set", "rows=300", "--set", "cols=300",
             "--set", "num_modes=20000", "--set", "memory_limit_gb=1"),
        # ------------------------------------------------ config files
        config("config_duplicate_key", "rows: 5\ncols: 5\nrows: 6\n", "rows"),
        config("config_duplicate_node_key", "rows: 5\npublish_rate: 30\npublish_rate: 60\n", "publish_rate"),
        config("config_not_yaml", "rows: [1, 2\n", "bad.yaml"),
        config("config_a_list", "- 1\n- 2\n", "map"),
        config("config_a_scalar", "hello\n", "map"),
        config("config_wrong_type", "mass: heavy\n", "mass"),
        config("config_out_of_range", "num_modes: 0\n", "num_modes"),
        config("config_fixed_out_of_range", "rows: 3\ncols: 3\nfixed: [9]\n", "fixed"),
        config("config_gravity_short", "gravity: [0, -9.81]\n", "gravity"),
        # ------------------------------------------------ handle scenarios (the handles experiment)
        tool("handles_without_scenarios", "handle_scenarios", "--experiment", "handles"),
        config("handles_scenarios_a_map", "handle_scenarios: {name: a}\n", "handle_scenarios", "--experiment", "handles"),
        config("handles_unknown_key", held + "    speed: 2\n", "handle_scenarios[0].speed", "--experiment", "handles"),
        config("handles_particle_outside", held.replace("[0, 1, 2, 3]", "[0, 1, 2, 16]"), "handles[0]",
               "--experiment", "handles"),
        config("handles_particle_fixed", held.replace("fixed: []", "fixed: [3]"), "also be fixed",
               "--experiment", "handles"),
        config("handles_axis_zero", held + "        rotation_axis: [0, 0, 0]\n", "rotation_axis",
               "--experiment", "handles"),
        config("handles_angle_too_large", held + "        rotation_deg: 361\n", "rotation_deg",
               "--experiment", "handles"),
        # every setup of every scenario and variant is built before the first run: refused in seconds
        # (two small corner grips, which no constraint modes hold, run: their modal methods are reported
        # as "did not build", tested in test_handle_scenarios)
        config("handles_move_shorter_than_its_steps", held + "    move_time: 1e-12\n", "move_time",
               "--experiment", "handles"),
        setting("cubature_pose_size", "1e-300"),
        tool("vary_cubature_pose_size_overflowing", "cubature_pose_size=1e200", "--experiment", "accuracy",
             "--vary", "cubature_pose_size=0.4,1e200"),
        tool("tag_too_long", "--tag", "--tag", "t" * 250),
        tool("results_beyond_memory", "--steps", "--experiment", "accuracy", "--steps", "100000000",
             "--sample", "1", "--interval", "1000"),
        # each setup fits alone, its methods' simulations together do not: the limit is named, not --steps
        tool("simulations_beyond_memory", "memory_limit_gb", "--set", "rows=300", "--set", "cols=300",
             "--set", "memory_limit_gb=1", "--methods", "linear,physical", "--experiment", "accuracy",
             "--steps", "10"),
        # the cubature's training beyond the limit, refused when a method trains it (physical alone runs)
        tool("cubature_training_beyond_memory", "memory_limit_gb", "--set", "cubature_training_poses=100000",
             "--set", "memory_limit_gb=1", "--methods", "physical,cubature", "--experiment", "accuracy",
             "--steps", "10"),
        # also refused when another experiment runs: the config is read whole
        config("handles_bad_in_accuracy_run", held.replace("name: lift", "name: 'lift,now'"),
               "handle_scenarios[0].name", "--experiment", "accuracy"),
        # ------------------------------------------------ colliders (contact)
        config("colliders_a_map", "colliders: {type: plane}\n", "colliders"),
        config("colliders_unknown_type", "colliders:\n  - {type: cylinder}\n", "colliders[0].type"),
        config("colliders_unknown_key", "colliders:\n  - {type: plane, point: [0, 0, 0], normal: [0, 0, 1], colour: red}\n",
               "colliders[0].colour"),
        config("colliders_zero_normal", "colliders:\n  - {type: plane, point: [0, 0, 0], normal: [0, 0, 0]}\n",
               "colliders[0].normal"),
        config("colliders_negative_radius", "colliders:\n  - {type: sphere, center: [0, 0, 0], radius: -1}\n",
               "colliders[0].radius"),
        config("colliders_nan_center", "colliders:\n  - {type: box, center: [.nan, 0, 0], half_extents: [1, 1, 1]}\n",
               "colliders[0].center"),
        config("colliders_frame", "colliders:\n  - {type: sphere, center: [0, 0, 0], radius: 0.1, frame: finger}\n",
               "colliders[0].frame"),
        config("contact_thickness_negative", "contact_thickness: -0.01\n", "contact_thickness"),
        config("contact_thickness_ten", "contact_thickness: 10\n", "at most 1 x spacing = 0.1 m"),
        config("contact_thickness_huge", "contact_thickness: 1e300\n", "'contact_thickness' = 1e+300"),
        config("colliders_type_a_number", "colliders: [{type: 5}]\n", "'colliders[0].type' = 5: must be a string"),
        config("colliders_duplicate_key",
               "colliders:\n  - type: sphere\n    center: [0.2, 0, -0.6]\n    radius: 0.1\n    radius: 0.5\n",
               "'colliders[0].radius' = (given twice)"),
        config("colliders_coordinate_huge", "colliders:\n  - {type: plane, point: [0, 0, -1e300], normal: [0, 0, 1]}\n",
               "'colliders[0].point'"),
        config("colliders_radius_huge", "colliders:\n  - {type: sphere, center: [0.2, 0, -0.6], radius: 1e300}\n",
               "'colliders[0].radius'"),
        config("colliders_friction_a_map",
               "colliders:\n  - {type: sphere, center: [0.2, 0, -0.6], radius: 0.1, friction: {mu: 1}}\n",
               "must be a number (the Coulomb coefficient"),
        # paper_2d.yaml is a 2D grid in the x-z plane: a surface that pushes along y is refused
        config("colliders_2d_plane_normal_y", "colliders:\n  - {type: plane, point: [0, 0.05, 0], normal: [0, 1, 0]}\n",
               "'colliders[0].normal'"),
        config("colliders_2d_sphere_off_plane", "colliders:\n  - {type: sphere, center: [0.2, 0.05, -0.2], radius: 0.1}\n",
               "'colliders[0].center'"),
        config("colliders_2d_box_thin_along_y",
               "colliders:\n  - {type: box, center: [0.2, 0, -0.2], half_extents: [0.5, 0.01, 0.5]}\n",
               "'colliders[0].half_extents'"),
        # the cloth hangs at its equilibrium, which ignores colliders, through the table
        Case("cloth_table_starting_inside_the_table",
             ["--quiet", "--config", str(pathlib.Path(configs).resolve() / "cloth_table.yaml"), "--output", OUT,
              "--set", "initial_state=equilibrium", "--experiment", "accuracy", "--steps", "10", "--interval", "10",
              "--sample", "10"],
             "'colliders[0]' = a box"),
        # a gripper carrying the sheet 100 m in 10 s (the default divergence_limit is 100 x its 0.3 m
        # side): not a divergence, and `full` stays the reference
        Case("handles_carried_100_m",
             ["--quiet", "--config", "{work}/bad.yaml", "--output", OUT, "--experiment", "handles", "--methods",
              "physical"],
             "| carry    | physical |",
             files={"bad.yaml": held.replace("name: lift", "name: carry").replace("[0, 0, 0.1]", "[100, 0, 0]")
                    + "    move_time: 10\n"},
             code=0, writes=True, absent="diverged"),
        # a step so large that every method diverges at once: reported with its step, in seconds
        tool("cost_diverging_at_the_first_step", "(diverged at step 1)", "--set", "time_step=0.5", "--experiment",
             "cost", "--sizes", "5", "--repeats", "1", "--methods", "physical", code=0, writes=True),
        # ------------------------------------------------ self-collision
        config("self_collision_2d", "self_collision: true\n", "self_collision"),
        config("self_collision_thickness_zero", "dimension: 3\nself_collision: true\nself_collision_thickness: 0\n",
               "self_collision_thickness"),
        config("self_collision_thickness_above_spacing",
               "dimension: 3\nself_collision: true\nself_collision_thickness: 0.2\n", "self_collision_thickness"),
        config("self_collision_thickness_nan", "dimension: 3\nself_collision: true\nself_collision_thickness: .nan\n",
               "self_collision_thickness"),
        config("self_friction_negative", "dimension: 3\nself_collision: true\nself_friction: -1\n", "self_friction"),
    ]
    return table


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tool", required=True, help="the modal_compare executable")
    parser.add_argument("--configs", required=True, help="config/compare of the package")
    parser.add_argument("--xunit", help="JUnit XML file to write")
    parser.add_argument("--timeout", type=float, default=30.0, help="seconds per case")
    args = parser.parse_args(argv)
    table = cases(args.configs)
    failed = run_cases(args.tool, table, "bad_inputs.modal_compare", args.xunit, args.timeout)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
