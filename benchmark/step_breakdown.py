#!/usr/bin/env python3
"""Where a step's instructions go, from a callgrind profile of benchmark/step_breakdown.

Usage: step_breakdown.py CALLGRIND_OUT STEPS TIME_STEP [CALLGRIND_OUT STEPS TIME_STEP ...]

Reads `callgrind_annotate --inclusive=yes` of each profile (collected inside Simulation::step only)
and prints one markdown row per profile: instructions per step and per simulated second (STEPS steps of
TIME_STEP s) in total, and per step in each part, the parts
by the functions' inclusive costs:
  forces          the method's force model's force() and energy() (not the wrapper that adds the
                  handles' and the frame's loads: those are in other)
  tangent         its tangentStiffness()
  solve           the implicit integrator's direction() without the tangent in it, and the explicit
                  one's solve()
  contact         the contact correction (correctContacts) without the reconstructions in it
  reconstruction  positions and velocities of every particle from the reduced coordinates
                  (ModalMethod::displacement, ::velocity), wherever the step calls them
  handles         the handles' and the moving frame's terms (setHandleMotion, setFrameForces)
  other           the rest of the step (the integrators' vector updates, checks, commits)
"""
import re
import subprocess
import sys

PARTS = {
    "forces": [r"(Full|LinearModal|PhysicalModal|Cubature)ForceModel::(force|energy)\("],
    "tangent": [r"(Full|LinearModal|PhysicalModal|Cubature)ForceModel::tangentStiffness\("],
    "direction": [r"ImplicitNewmark::direction\("],
    "explicit_solve": [r"ExplicitNewmark::solve\("],
    "contact": [r"Method::correctContacts\("],
    "reconstruction": [r"ModalMethod::displacement\(", r"ModalMethod::velocity\("],
    "handles": [r"Method::setHandleMotion\(", r"MethodModel::setFrameForces\("],
    "total": [r"modal_mass_spring::Simulation::step\(int\)"],
}


def profile(path):
    """Inclusive cost per function, and per function the inclusive cost of each of its callees."""
    text = subprocess.run(["callgrind_annotate", "--inclusive=yes", "--tree=calling", "--threshold=100", path],
                          check=True, capture_output=True, text=True).stdout
    costs, callees, current = {}, {}, None
    for line in text.splitlines():
        m = re.match(r"\s*([\d,]+)\s+(?:\([^)]*\)\s+)?([*>])\s+(.*)$", line)
        if not m or ":" not in m.group(3):
            continue
        cost = int(m.group(1).replace(",", ""))
        function = re.sub(r" \(\d+x\)", "", m.group(3).split(":", 1)[1]).split(" [")[0].strip()
        if m.group(2) == "*":
            current = function
            costs[function] = costs.get(function, 0) + cost
        elif current is not None:
            callees.setdefault(current, {})
            callees[current][function] = callees[current].get(function, 0) + cost
    return costs, callees


def part(costs, patterns):
    return sum(c for f, c in costs.items() if any(re.search(p, f) for p in patterns))


def main():
    args = sys.argv[1:]
    if not args or len(args) % 3:
        sys.exit(__doc__)
    print("| profile | instructions per step | per simulated second | forces | tangent | factorisation and solve | "
          "contact | reconstruction | handles | other |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for path, steps, time_step in zip(args[::3], args[1::3], args[2::3]):
        costs, callees = profile(path)
        p = {k: part(costs, v) for k, v in PARTS.items()}
        # The reconstructions the contact correction calls are counted once, as reconstruction.
        contact_reconstruction = sum(part(calls, PARTS["reconstruction"]) for f, calls in callees.items()
                                     if any(re.search(q, f) for q in PARTS["contact"]))
        solve = p["direction"] - p["tangent"] + p["explicit_solve"]
        parts = [p["forces"], p["tangent"], solve, p["contact"] - contact_reconstruction, p["reconstruction"],
                 p["handles"]]
        other = p["total"] - sum(parts)
        n = int(steps)
        cells = [f"{x / n / 1e6:.3g} M ({100 * x / p['total']:.0f}%)" for x in parts + [other]]
        per_second = p["total"] / n / float(time_step)
        print(f"| {path} | {p['total'] / n / 1e6:.3g} M | {per_second / 1e9:.3g} G | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
