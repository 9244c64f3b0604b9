#!/usr/bin/env python3
"""A shipped handles scene on other grid sizes, through modal_compare's handles experiment against a
converged explicit `full`. The same cloth (its width, total mass and spring constants) on N x N
particles, its handles the same rows of the grid:

  turn: config/compare/large_motion_100.yaml, a clamp of the top two rows turned 60 degrees;
  drag: config/compare/cloth_drag_50.yaml, the top row lowered onto a table and dragged across it.

Each size steps the methods at the same margin to `full`'s explicit limit as the scene's own step
(the limit goes as one over N at a fixed width and mass: 0.8 ms on the 100 x 100 turn, 2.5 ms on the
50 x 50 drag), the reference at --reference-divisor times less. Every size is sampled at the same
simulated times (every 16 ms on the turn, 25 ms on the drag): reading the whole grid between two
steps evicts a small method's data from the cache, so sampling every few steps of a fine grid would
time a method slower there than on a coarse grid sampled less often. (16 ms does not divide the
turn's 1 s move: its end is sampled at 1.008 s.)

  python3 benchmark/size_sweep.py --scene turn --sizes 30,50,100,200 --methods full,coarse \\
      [--reference-divisor 8] [--set KEY=VALUE ...] [--binary PATH] [--output DIR]

Prints each size's handles table; the CSV files go to --output (default: a temporary folder)."""
import argparse
import os
import subprocess
import sys
import tempfile

_configs = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "config", "compare")
# The scene's config, its size, its explicit `full` step there, and the sample period (s): a whole
# number of the step on 30, 50, 100 and 200, and of `coarse`'s step there.
SCENES = {
    "turn": (os.path.join(_configs, "large_motion_100.yaml"), 100, 0.0008, 0.016),
    "drag": (os.path.join(_configs, "cloth_drag_50.yaml"), 50, 0.0025, 0.025),
}


def config_for(base, base_size, size):
    """The base config with the grid, spacing and particle mass of an N x N cloth of the same width
    and mass, and each handle the same number of whole rows (a handle of k rows: the first k N)."""
    lines = []
    with open(base) as f:
        for line in f:
            key = line.split(":")[0].strip()
            if key in ("rows", "cols"):
                line = "%s: %d\n" % (key, size)
            elif key == "spacing":
                width = float(line.split(":")[1].split("#")[0]) * (base_size - 1)
                line = "spacing: %r\n" % (width / (size - 1))
            elif key == "mass":
                total = float(line.split(":")[1].split("#")[0]) * base_size * base_size
                line = "mass: %r\n" % (total / (size * size))
            elif key == "- {particles":
                start, end = line.index("[") + 1, line.index("]")
                rows = len(line[start:end].split(",")) // base_size
                line = line[:start] + ", ".join(str(p) for p in range(rows * size)) + line[end:]
            lines.append(line)
    return "".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", choices=sorted(SCENES), default="turn")
    parser.add_argument("--sizes", default="50,100,200")
    parser.add_argument("--methods", default="full,coarse")
    parser.add_argument("--reference-divisor", type=int, default=8, help="the reference step is the step over this")
    parser.add_argument("--binary", default=os.path.join(os.environ.get("MODAL_WS", "/tmp/modal_mass_spring_ws"),
                                                         "devel", "lib", "modal_mass_spring", "modal_compare"))
    parser.add_argument("--output", default=None)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="passed on to modal_compare (e.g. memory_limit_gb=20 for 200 x 200)")
    args = parser.parse_args()
    try:
        sizes = [int(s) for s in args.sizes.split(",")]
    except ValueError:
        sizes = []
    if not sizes or min(sizes) < 3:
        sys.exit("--sizes '%s': must be comma-separated whole numbers >= 3" % args.sizes)
    if args.reference_divisor < 1:
        sys.exit("--reference-divisor %d: must be >= 1" % args.reference_divisor)
    if not os.access(args.binary, os.X_OK):
        sys.exit("--binary %s: not an executable modal_compare (build the package, or set MODAL_WS)" % args.binary)
    base, base_size, base_step, sample_period = SCENES[args.scene]
    output = args.output or tempfile.mkdtemp(prefix="size_sweep_")
    os.makedirs(output, exist_ok=True)
    for size in sizes:
        tag = "%s_%d" % (args.scene, size)
        config = os.path.join(output, tag + ".yaml")
        with open(config, "w") as f:
            f.write(config_for(base, base_size, size))
        time_step = base_step * base_size / size
        sample = round(sample_period / time_step)
        if sample < 1 or abs(sample * time_step - sample_period) > 1e-9:
            sys.exit("--sizes: %d x %d's step %r s does not divide the sample period %r s"
                     % (size, size, time_step, sample_period))
        command = [args.binary, "--config", config, "--experiment", "handles", "--methods", args.methods,
                   # --interval only has to be a multiple of --sample: the handles experiment samples its own
                   "--sample", str(sample), "--interval", str(100 * sample),
                   "--set", "integrator=explicit", "--set", "time_step=%r" % time_step,
                   "--reference-time-step", "%r" % (time_step / args.reference_divisor),
                   "--no-snapshots", "--quiet", "--output", output]
        for setting in args.set:
            command += ["--set", setting]
        print("$ " + " ".join(command), flush=True)
        result = subprocess.run(command)
        if result.returncode != 0:
            sys.exit("modal_compare failed on %d x %d (exit %d)" % (size, size, result.returncode))
    print("CSV files in " + output)


if __name__ == "__main__":
    main()
