#!/usr/bin/env bash
# The large-motion measurements (docs/results.md, "Large motions"): the held-cloth scenarios of
# config/compare/large_motion*.yaml and the released sheets, every method against a converged `full`,
# on the modal basis, with modal derivatives and (when the core has it) on the skinning subspace; and
# the step times on the 100 x 100 held cloth. Writes docs/data/large_motion/ and docs/*large_motion*.png.
# Uses the modal_compare already built in $MODAL_WS. Usage: benchmark/large_motion.sh [part ...], parts
# held, grips, release, swing, large (default: all), and span (not by default: benchmark/skinning_span_error,
# built by `catkin_make skinning_span_error`, on the shakes and the grips); extra modal_compare options
# in LARGE_MOTION_ARGS.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/../scripts/env.sh"

tool="$WS_DIR/devel/lib/modal_mass_spring/modal_compare"
out="$REPO_DIR/docs/data/large_motion"
configs="$REPO_DIR/config/compare"
mkdir -p "$out"
parts=("$@")
[ ${#parts[@]} -eq 0 ] && parts=(held grips release swing large)
read -r -a extra <<<"${LARGE_MOTION_ARGS:---quiet}"
# The skinning subspace when the core has it (a core without it refuses basis: skinning).
skinning=0
grep -q '"skinning"' "$REPO_DIR/src/core/simulation/options.cpp" && skinning=1

# Every method on the modal basis, physical and cubature with modal derivatives (10 linear modes + 20
# derivative directions, as many coordinates as the 30 modes) and on the skinning subspace.
bases() {  # config experiment tag [options...]
  local config=$1 experiment=$2 tag=$3
  shift 3
  "$tool" --config "$configs/$config.yaml" --experiment "$experiment" --tag "${tag}_modes" --output "$out" \
    --methods full,linear,physical,cubature "$@" "${extra[@]}"
  "$tool" --config "$configs/$config.yaml" --experiment "$experiment" --tag "${tag}_derivatives" --output "$out" \
    --set basis=modal_derivatives --set num_modes=10 --set num_derivative_modes=20 --methods physical,cubature \
    --no-snapshots "$@" "${extra[@]}"
  # (The tool's memory check counts a cubature training per run, about 18 GB with 24 weights, more
  # than the default memory_limit_gb; the runs take far less.)
  if [ "$skinning" = 1 ]; then
    "$tool" --config "$configs/$config.yaml" --experiment "$experiment" --tag "${tag}_skinning" --output "$out" \
      --set basis=skinning --vary num_skinning_weights=12,24,48 --methods physical --set memory_limit_gb=40 \
      --no-snapshots "$@" "${extra[@]}"
    "$tool" --config "$configs/$config.yaml" --experiment "$experiment" --tag "${tag}_skinning_cubature" --output "$out" \
      --set basis=skinning --set num_skinning_weights=24 --methods physical,cubature --set memory_limit_gb=40 \
      --no-snapshots "$@" "${extra[@]}"
  fi
}

for part in "${parts[@]}"; do
  {
    echo "# modal_compare, large motions ($part), $(date -u +%Y-%m-%dT%H:%MZ), commit $(git -C "$REPO_DIR" describe --always --dirty)"
    echo "# CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//'), $(nproc) cores," \
      "load average $(cut -d' ' -f1-3 /proc/loadavg) at the start"
    case $part in
      # The clamp lifted and turned, tilted, shaken; 5 ms steps against full, explicit, at 0.1 ms
      # (checked against 0.05 ms), sampled every 50 ms.
      # Today's methods also in the clamp's moving frame (handle_formulation auto), their best on turns.
      held)
        bases large_motion handles large_motion --sample 10 --reference-time-step 0.0001
        "$tool" --config "$configs/large_motion.yaml" --experiment handles --tag large_motion_frame --output "$out" \
          --set handle_formulation=auto --methods linear,physical,cubature --sample 10 --reference-time-step 0.0001 \
          --no-snapshots "${extra[@]}"
        ;;
      # Two small corner grips brought together, nothing else fixed.
      grips) bases large_motion_grips handles large_motion_grips --sample 10 --reference-time-step 0.0001 ;;
      # Released from 60 degrees off vertical, top row fixed: 3 s.
      release) bases large_motion_release accuracy large_motion_release --steps 600 --interval 200 --sample 10 \
        --reference-time-step 0.0001 ;;
      # The swinging sheets of the modal-derivatives results, against a converged reference instead of
      # full at the same step: the paper's 3D sheet at its equilibrium (5 s) and the 50 x 50 cloth (2.5 s).
      swing)
        bases paper_3d accuracy swing_paper_3d --set linearization=equilibrium --steps 5000 --interval 1000 --sample 20 \
          --reference-time-step 0.0001 --no-snapshots
        bases cloth_50 accuracy swing_cloth_50 --steps 5000 --interval 1000 --sample 20 \
          --reference-time-step 0.00025 --no-snapshots
        ;;
      # Step times on the 100 x 100 held cloth turned 60 degrees, both integrators in one run, each
      # method against `full` of the same integrator at the same 1 ms step (a converged reference,
      # 9000 more steps of the 100 x 100 grid a variant, did not fit the shared machine's time).
      large)
        "$tool" --config "$configs/large_motion_100.yaml" --experiment handles --tag large_motion_100 --output "$out" \
          --methods linear,physical,cubature --vary integrator=explicit,implicit --sample 10 --no-snapshots "${extra[@]}"
        if [ "$skinning" = 1 ]; then
          "$tool" --config "$configs/large_motion_100.yaml" --experiment handles --tag large_motion_100_skinning \
            --output "$out" --set basis=skinning --set num_skinning_weights=24 --set memory_limit_gb=40 --methods physical,cubature \
            --vary integrator=explicit,implicit --sample 10 --no-snapshots "${extra[@]}"
        fi
        ;;
      # Span or dynamics: the skinning span's best pose of the converged reference beside `physical`
      # for 24 to 192 weights, the reference nudged 1 nm out of its plane at 0.4 s, `physical` restarted
      # from the best pose at 1.2 s, the distance off the start plane (y) and the spring energies; then
      # the reference nudged 1 mm and continued from `physical`'s state at 1.2 s; then the same on a
      # sheet hung 2 degrees out of the vertical (no mirror symmetry about its plane), restarted and
      # handed over at 0.6 s.
      span)
        span_tool="$WS_DIR/devel/lib/modal_mass_spring/skinning_span_error"
        for scenario in large_motion:shake_x large_motion:shake_y large_motion_grips:corners_together; do
          config=${scenario%%:*} name=${scenario#*:}
          for run in sizes nudge tilt tilt_nudge; do
            case $run in
              sizes) opts=(--weights 24,48,96,192 --perturb 0,1e-9,0 --restart-time 1.2 --energy 1) ;;
              nudge) opts=(--weights 24 --perturb 0.001,0.001,0 --handover-time 1.2) ;;
              tilt) opts=(--weights 24,48,192 --perturb 0,1e-6,0 --set rotation_deg=2 --energy 1) ;;
              tilt_nudge) opts=(--weights 24 --perturb 0.001,0.001,0 --set rotation_deg=2 --restart-time 0.6 \
                --handover-time 0.6) ;;
            esac
            echo "# skinning_span_error $name $run: ${opts[*]}"
            "$span_tool" --config "$configs/$config.yaml" --scenario "$name" --set memory_limit_gb=1000 --every 4 \
              --perturb-time 0.4 --off-plane 1 "${opts[@]}" 2>&1 | tee "$out/span_error_${name}_$run.txt"
          done
        done
        ;;
      *) echo "large_motion.sh: unknown part '$part': held, grips, release, swing, large or span" >&2; exit 2 ;;
    esac
    echo "# load average $(cut -d' ' -f1-3 /proc/loadavg) at the end"
  } | tee "$out/summary_$part.txt"
done
# (span writes text only: no figure to redraw.)
[ "${parts[*]}" = span ] || /usr/bin/python3 "$REPO_DIR/scripts/plot_comparison.py" --data "$out" --out "$REPO_DIR/docs"
