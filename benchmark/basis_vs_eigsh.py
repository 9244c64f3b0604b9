#!/usr/bin/env python3
"""The modal basis against scipy's eigsh (ARPACK shift-invert) on the identical K and M, in one run.

basis_timing writes K (free dofs) and the diagonal of M of a grid as Matrix Market files; then, --runs
times, alternately (the order swapped every run, so a change in the machine's load hits both), it
times computeModalBasis on those files in a new basis_timing process (its own timer, around the call
only) and scipy.sparse.linalg.eigsh here (around the call only, its SuperLU factorisation included).
Both: the r lowest eigenpairs of K u = lambda^2 M u, shift sigma = -1e-4 max(K_ii / M_ii), Lanczos
basis of ncv = max(2 r + 1, r + 20) vectors, convergence when a Ritz value's residual estimate is
below tol = 1e-12 times the Ritz value (ARPACK's and Spectra's criterion alike). Prints the medians
of wall and CPU time, their ratio, and the largest relative difference between the two eigenvalue lists.

  /usr/bin/python3 benchmark/basis_vs_eigsh.py [--size 100] [--modes 30] [--runs 7]
Needs python3-scipy and the workspace's basis_timing (catkin_make tests builds it).
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np
import scipy.io
import scipy.sparse
import scipy.sparse.linalg

TOLERANCE = 1e-12  # as modal_basis.cpp passes to Spectra


def default_binary():
    workspace = os.environ.get("MODAL_WS", "/tmp/modal_mass_spring_ws")
    return os.path.join(workspace, "devel", "lib", "modal_mass_spring", "basis_timing")


def ours(binary, folder, modes):
    out = subprocess.run([binary, "--read", folder, "--modes", str(modes)], check=True,
                         capture_output=True, text=True).stdout.split()
    fields = dict(zip(out[0::2], map(float, out[1::2])))
    values = np.loadtxt(os.path.join(folder, "ours.txt"))
    return fields["wall"], fields["cpu"], values


def eigsh(k, m, modes):
    sigma = -1e-4 * (k.diagonal() / m.diagonal()).max()
    ncv = max(2 * modes + 1, modes + 20)
    wall, cpu = time.perf_counter(), time.process_time()
    values = scipy.sparse.linalg.eigsh(k, k=modes, M=m, sigma=sigma, which="LM", ncv=ncv, tol=TOLERANCE,
                                       return_eigenvectors=True)[0]
    return time.perf_counter() - wall, time.process_time() - cpu, np.sort(values)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=100, help="grid of size x size particles (default 100)")
    parser.add_argument("--dimension", type=int, default=2, choices=(2, 3), help="2D or 3D grid (default 2)")
    parser.add_argument("--modes", type=int, default=30, help="r, the modes wanted (default 30)")
    parser.add_argument("--runs", type=int, default=7, help="timed runs of each (default 7)")
    parser.add_argument("--binary", default=default_binary(), help="basis_timing (default: in $MODAL_WS)")
    args = parser.parse_args()
    if not os.path.exists(args.binary):
        sys.exit("basis_timing not found at %s: build it (catkin_make tests) or pass --binary" % args.binary)

    with tempfile.TemporaryDirectory() as folder:
        subprocess.run([args.binary, "--write", folder, "--size", str(args.size), "--dimension", str(args.dimension)],
                       check=True, capture_output=True)
        k = scipy.io.mmread(os.path.join(folder, "K.mtx")).tocsc()
        m = scipy.sparse.diags(np.ravel(scipy.io.mmread(os.path.join(folder, "M.mtx")))).tocsc()
        print("ours: %s (built %s)" % (args.binary, time.strftime("%Y-%m-%d %H:%M", time.localtime(os.path.getmtime(args.binary)))))
        print("%dD grid %d x %d: %d free dofs, r = %d, tol = %g, %d runs each, alternating"
              % (args.dimension, args.size, args.size, k.shape[0], args.modes, TOLERANCE, args.runs))
        times = {"ours": [], "eigsh": []}
        difference = 0.0
        for run in range(args.runs):
            order = ("ours", "eigsh") if run % 2 == 0 else ("eigsh", "ours")
            values = {}
            for name in order:
                if name == "ours":
                    wall, cpu, values[name] = ours(args.binary, folder, args.modes)
                else:
                    wall, cpu, values[name] = eigsh(k, m, args.modes)
                times[name].append((wall, cpu))
            # Relative, except near zero (a flat 3D sheet's zero modes): modal_basis.cpp calls an
            # eigenvalue below 1e-8 max(K_ii / M_ii) zero.
            zero = 1e-8 * (k.diagonal() / m.diagonal()).max()
            scale = np.maximum(np.abs(values["eigsh"]), zero)
            difference = max(difference, float(np.max(np.abs(values["ours"] - values["eigsh"]) / scale)))

    def median(name, column):
        return statistics.median(t[column] for t in times[name])

    for column, label in ((0, "wall"), (1, "CPU")):
        a, b = median("ours", column), median("eigsh", column)
        print("%-4s median: ours %.3f s, eigsh %.3f s, ratio %.3f" % (label, a, b, a / b))
    print("largest relative eigenvalue difference: %.2e" % difference)


if __name__ == "__main__":
    main()
