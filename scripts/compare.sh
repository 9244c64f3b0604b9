#!/usr/bin/env bash
# Regenerates every CSV (docs/data/) and figure (docs/*.png) of the method comparison: builds the
# package, runs modal_compare on the paper's configs (and the stability of nonmonotone_2d.yaml) and
# draws the figures. The summary tables go to
# stdout and docs/data/summary.txt. Usage: scripts/compare.sh [modal_compare options for every run]
# COMPARE_BUILD=0 skips the build and uses the modal_compare already in the workspace.
# COMPARE_ONLY=stability reruns only the stability runs (deterministic: no timing, so the machine
# need not be quiet), replaces only stability_*.csv and writes their tables to
# docs/data/summary_stability.txt, which then supersedes the stability tables of summary.txt.
# COMPARE_ONLY=handles reruns only the moving-handle scenarios (docs/data/handles/, docs/handles_*.png).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"

build_log="$(mktemp)"
if [ "${COMPARE_BUILD:-1}" != 0 ] && ! bash "$REPO_DIR/scripts/build.sh" >"$build_log" 2>&1; then
  tail -n 40 "$build_log"
  echo "compare.sh: the build failed (full log: $build_log)" >&2
  exit 1
fi
rm -f "$build_log"

tool="$WS_DIR/devel/lib/modal_mass_spring/modal_compare"
data="$REPO_DIR/docs/data"
configs="$REPO_DIR/config/compare"
mkdir -p "$data"
only="${COMPARE_ONLY:-}"
if [ -n "$only" ] && [ "$only" != stability ] && [ "$only" != derivatives ] && [ "$only" != error_cost ] &&
  [ "$only" != handles ]; then
  echo "compare.sh: COMPARE_ONLY must be empty, 'stability', 'derivatives', 'error_cost' or 'handles', not '$only'" >&2
  exit 2
fi
# Modal derivatives against linear modes (docs/results.md, "Modal derivatives"): physical with R linear
# modes plus D derivative directions against linear and physical with R + D linear modes, each against
# full, on the paper's 3D sheet at its equilibrium and on a 50 x 50 cloth; and the largest explicit
# step of each. Writes docs/data/derivatives/ and docs/derivatives_*.png.
derivatives() {
  local out="$data/derivatives" config setup r d steps name
  mkdir -p "$out"
  rm -f "$out"/*.csv
  # config, linear modes R, derivative directions D, steps (5 s each)
  for setup in "paper_3d 10 20 5000" "cloth_50 10 10 10000" "cloth_50 5 15 10000"; do
    read -r config r d steps <<<"$setup"
    name="${config}_r${r}_d${d}"
    local common=(--config "$configs/$config.yaml" --set linearization=equilibrium --steps "$steps" --interval "$steps"
      --sample 20 --no-snapshots --output "$out")
    "$tool" "${common[@]}" --tag "derivatives_${name}_linear_modes" --experiment accuracy \
      --set num_modes=$((r + d)) --methods linear,physical "$@"
    "$tool" "${common[@]}" --tag "derivatives_${name}_modal_derivatives" --experiment accuracy \
      --set num_modes="$r" --set basis=modal_derivatives --set num_derivative_modes="$d" --methods physical "$@"
    "$tool" "${common[@]}" --tag "derivatives_${name}_linear_modes" --experiment stability \
      --set num_modes=$((r + d)) --methods linear,physical --stability-steps 2000 --tolerance 0.02 "$@"
    "$tool" "${common[@]}" --tag "derivatives_${name}_modal_derivatives" --experiment stability \
      --set num_modes="$r" --set basis=modal_derivatives --set num_derivative_modes="$d" --methods physical \
      --stability-steps 2000 --tolerance 0.02 "$@"
  done
}
if [ "$only" = derivatives ]; then
  mkdir -p "$data/derivatives"
  {
    echo "# modal_compare, modal derivatives, $(date -u +%Y-%m-%dT%H:%MZ), commit $(git -C "$REPO_DIR" describe --always --dirty)"
    echo "# load average $(cut -d' ' -f1-3 /proc/loadavg) at the start"
    derivatives "$@"
    echo "# load average $(cut -d' ' -f1-3 /proc/loadavg) at the end"
  } | tee "$data/derivatives/summary.txt"
  /usr/bin/python3 "$REPO_DIR/scripts/plot_comparison.py" --data "$data/derivatives" --out "$REPO_DIR/docs"
  exit 0
fi
# Moving handles (docs/results.md, "Moving handles"): the held cloth's scenarios (config/compare/
# held_cloth.yaml: the top edge translated and turned, two corner grips moved apart and together), 1 s
# of motion and 2 s held, every method under both integrators and both handle formulations (auto: the
# moving frame for the one-handle scenarios, constraint modes for the two grips) at 5 ms against the converged reference
# (full, explicit, 0.1 ms, checked against 0.05 ms), sampled every 50 ms, and the shapes where the move
# ends (explicit) drawn in docs/handles_held_cloth_shapes.png; then `linear` and `physical`
# (explicit, constraint modes) with 30, 100 and 300 modes: what more modes buy. About 8 minutes.
if [ "$only" = handles ]; then
  out="$data/handles"
  mkdir -p "$out"
  rm -f "$out"/*.csv
  {
    echo "# modal_compare, moving handles, $(date -u +%Y-%m-%dT%H:%MZ), commit $(git -C "$REPO_DIR" describe --always --dirty)"
    echo "# load average $(cut -d' ' -f1-3 /proc/loadavg) at the start (timings are only as quiet as the machine)"
    "$tool" --config "$configs/held_cloth.yaml" --experiment handles --vary integrator=explicit,implicit \
      --vary handle_formulation=constraint_modes,auto --sample 10 --reference-time-step 0.0001 --output "$out" "$@"
    "$tool" --config "$configs/held_cloth.yaml" --tag held_cloth_modes --experiment handles --methods linear,physical --set handle_formulation=constraint_modes \
      --set integrator=explicit --vary num_modes=30,100,300 --sample 10 --reference-time-step 0.0001 --no-snapshots \
      --output "$out" "$@"
    echo "# load average $(cut -d' ' -f1-3 /proc/loadavg) at the end"
  } | tee "$out/summary.txt"
  /usr/bin/python3 "$REPO_DIR/scripts/plot_comparison.py" --data "$out" --out "$REPO_DIR/docs"
  exit 0
fi
# Error against cost (docs/error_cost.png, which leads docs/results.md): every method x linearization x
# integrator at 1, 10 and 50 ms on the paper's 2D and 3D setups against the converged reference, as
# the combinations below but with `cubature` too, each time step's methods timed in one run.
if [ "$only" = error_cost ]; then
  out="$data/error_cost"
  mkdir -p "$out"
  rm -f "$out"/*.csv
  {
    echo "# modal_compare, error against cost, $(date -u +%Y-%m-%dT%H:%MZ), commit $(git -C "$REPO_DIR" describe --always --dirty)"
    echo "# load average $(cut -d' ' -f1-3 /proc/loadavg) at the start"
    for config in paper_2d paper_3d; do
      for dt_ms in 1 10 50; do
        steps=$((5000 / dt_ms)); sample=$(( (50 + dt_ms - 1) / dt_ms ))
        "$tool" --config "$configs/$config.yaml" --tag "error_cost_${config}_dt${dt_ms}ms" --experiment accuracy \
          --vary linearization=rest,equilibrium --vary integrator=explicit,implicit \
          --set time_step="$(awk "BEGIN{print $dt_ms / 1000}")" --steps "$steps" --interval "$steps" --sample "$sample" \
          --reference-time-step 0.0001 --no-snapshots --output "$out" "$@"
      done
    done
    echo "# load average $(cut -d' ' -f1-3 /proc/loadavg) at the end"
  } | tee "$out/summary.txt"
  /usr/bin/python3 "$REPO_DIR/scripts/plot_comparison.py" --data "$out" --out "$REPO_DIR/docs"
  exit 0
fi
if [ "$only" = stability ]; then
  rm -f "$data"/stability_*.csv
  summary="$data/summary_stability.txt"
else
  rm -f "$data"/*.csv "$data/summary_stability.txt"
  summary="$data/summary.txt"
fi
timed() { [ "$only" != stability ]; }

{
  echo "# modal_compare, $(date -u +%Y-%m-%dT%H:%MZ), commit $(git -C "$REPO_DIR" describe --always --dirty)"
  echo "# CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//'), $(nproc) cores," \
    "load average $(cut -d' ' -f1-3 /proc/loadavg) at the start (timings are only as quiet as the machine)"
  [ "$only" = stability ] && echo "# COMPARE_ONLY=stability: supersedes the stability tables of summary.txt"
  # The paper's experiments: cost over grid sizes, accuracy against full, largest stable step.
  experiments=all
  timed || experiments=stability
  "$tool" --config "$configs/paper_2d.yaml" --experiment $experiments --sizes 5,10,20,40,80 --output "$data" "$@"
  "$tool" --config "$configs/paper_3d.yaml" --experiment $experiments --sizes 5,10,20,40,80 --output "$data" "$@"
  # Beyond the paper: every method x linearization x integrator on the paper's 2D and 3D
  # setups (the 3D sheet keeps its 45 degree start under both linearizations), from the unloaded
  # start, 5 s, against a converged reference (full, explicit, 0.1 ms, checked against 0.05 ms), at
  # three time steps; the error sampled every 50 ms, with the wall time per step.
  for config in paper_2d paper_3d; do
    for dt_ms in $(timed && echo 1 10 50); do
      steps=$((5000 / dt_ms)); sample=$(( (50 + dt_ms - 1) / dt_ms ))
      "$tool" --config "$configs/$config.yaml" --tag "combinations_${config}_dt${dt_ms}ms" --experiment accuracy \
        --vary linearization=rest,equilibrium --vary integrator=explicit,implicit \
        --set time_step="$(awk "BEGIN{print $dt_ms / 1000}")" --steps "$steps" --interval "$steps" --sample "$sample" \
        --reference-time-step 0.0001 --no-snapshots --output "$data" "$@"
    done
    # Stability of each method under both integrators, each implicit method also run at ten times the
    # largest stable step of the same method under the explicit scheme. 2D: both linearizations,
    # 2000 steps a trial. 3D: the equilibrium basis only (the rest basis of the flat sheet is 30 zero
    # modes, and implicit physical on it takes about 40 ms a step at large steps; the accuracy runs
    # above cover it), 500 steps a trial and steps up to 0.6 s: implicit full takes 24 ms a step at
    # 0.25 s and 130 ms at 2 s (Newton iterations and step halving), so longer trials take too long.
    if [ "$config" = paper_3d ]; then
      extra=(--vary linearization=equilibrium --stability-steps 500 --max-time-step 0.6)
    else
      extra=(--vary linearization=rest,equilibrium --stability-steps 2000)
    fi
    "$tool" --config "$configs/$config.yaml" --tag "${config}_integrators" --experiment stability "${extra[@]}" \
      --vary integrator=explicit,implicit --tolerance 0.05 --check-factor 10 --output "$data" "$@"
  done
  # Stability that is not monotone in the time step: each method
  # under the explicit scheme, and implicit full and physical, 5000 steps a trial; the search
  # reports the largest step below which every step tried is stable and the stable windows above it.
  "$tool" --config "$configs/nonmonotone_2d.yaml" --experiment stability --stability-steps 5000 --output "$data" "$@"
  "$tool" --config "$configs/nonmonotone_2d.yaml" --tag nonmonotone_2d_implicit --experiment stability \
    --methods full,physical --vary integrator=implicit --stability-steps 5000 --output "$data" "$@"
  echo "# load average $(cut -d' ' -f1-3 /proc/loadavg) at the end"
} | tee "$summary"

/usr/bin/python3 "$REPO_DIR/scripts/plot_comparison.py" --data "$data" --out "$REPO_DIR/docs"
# The modal-derivatives runs, with their own summary and figures.
if [ -z "$only" ]; then
  COMPARE_ONLY=derivatives COMPARE_BUILD=0 bash "${BASH_SOURCE[0]}" "$@"
  COMPARE_ONLY=handles COMPARE_BUILD=0 bash "${BASH_SOURCE[0]}" "$@"
fi
