#!/usr/bin/env python3
"""Draws the CSV files of modal_compare as PNG figures.

Usage: plot_comparison.py --data DIR --out DIR

Reads, from DIR, every file the tool writes and draws:
  cost_<tag>.csv                      -> cost.png (one panel per file; per-step cost and basis build)
  accuracy_<tag>_snapshots.csv        -> snapshots_<tag>.png (each modal method over `full`)
  accuracy_<tag>_error.csv            -> error_<tag>.png (largest and RMS distance to `full`)
  stability_<tag>.csv                 -> stability_<tag>.png (largest step below which every step tried
      is stable, per method, with the stable windows found above it)
  accuracy_combinations_<config>_dt<N>ms_error.csv (runs with --reference-time-step, one per time
      step) -> combinations.png (error against the converged reference and wall time per simulated
      second, against the time step, for every method x linearization x integrator)
  accuracy_error_cost_<config>_dt<N>ms_error.csv (the same runs with every method) -> error_cost.png
      (mean RMS distance to the converged reference against the median wall time of one step, log-log,
      one panel per config: which method to pick for an error and a budget)
  accuracy_derivatives_<config>_linear_modes_error.csv with
  accuracy_derivatives_<config>_modal_derivatives_error.csv -> derivatives_<config>.png (RMS distance
      to `full` over time and the swing, the sheet's mean y, of `linear` and `physical` with R + D
      linear modes and `physical` with R modes plus D derivative directions; the swing period of each
      from the mean y's zero crossings)
  handles_<tag>_error.csv (modal_compare --experiment handles) -> handles_<tag>.png (RMS distance to
      the reference over time, one panel per handle scenario, every method), with
      handles_<tag>_summary.csv for its table, and handles_<tag>_snapshots.csv -> handles_<tag>_shapes.png
      (the cloth where the move ends: the reference, `linear` and `physical`, one panel per scenario)
and writes the numbers behind them as Markdown tables to DIR/tables.md, for docs/results.md to quote.
The columns it needs are listed in COLUMNS: a file without them stops the script with a message.
"""
import argparse
import csv
import math
import pathlib
import re
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

COLUMNS = {
    "cost": ["variant", "method", "dimension", "rows", "cols", "particles", "free_dofs", "num_modes",
             "build_seconds", "step_seconds", "diverged"],
    "error": ["variant", "method", "step", "time", "max_distance", "rms_distance", "diverged"],
    "snapshots": ["variant", "method", "step", "time", "particle", "row", "col", "fixed", "x", "y", "z"],
    "summary": ["variant", "method", "mean_rms", "max_rms", "final_rms", "step_seconds_median", "diverged"],
    "stability": ["variant", "method", "stable_dt", "unstable_dt", "steps", "tolerance", "modal_bound",
                  "full_bound"],
}
METHOD_COLORS = {"full": "0.35", "linear": "tab:red", "physical": "tab:blue", "cubature": "tab:green", "reference": "0.35",
                 "reference_half_step": "black"}
REFERENCES = ("reference", "reference_half_step")
VARIANT_STYLES = ["-", "--", ":", "-."]


class ColumnError(Exception):
    pass


def read_csv(path, kind):
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        missing = [c for c in COLUMNS[kind] if c not in (reader.fieldnames or [])]
        if missing:
            raise ColumnError(f"{path}: missing column(s) {', '.join(missing)} (a {kind} file needs "
                              f"{', '.join(COLUMNS[kind])})")
        rows = list(reader)
    if not rows:
        raise ColumnError(f"{path}: no rows")
    return rows


def number(text):
    """A CSV number; modal_compare leaves a field empty when it is not finite (the `diverged` flag or
    the column says why), so an empty field reads as NaN."""
    return float(text) if text not in ("", "nan", "-nan") else math.nan


def unbounded(row):
    """A stability row with no divergence up to --max-time-step: unstable_dt is empty (or "inf" in
    files written before non-finite numbers became empty fields)."""
    return row["unstable_dt"] in ("", "inf")


def windows(row):
    """The stable windows above the boundary, [(from, to)] in s, from "from:to;from:to"."""
    text = row.get("stable_windows", "")
    return [tuple(float(v) for v in w.split(":")) for w in text.split(";") if w]


def tag_of(path, prefix, suffix):
    return path.name[len(prefix):-len(suffix)]


def ordered(values):
    """Unique values in first-seen order."""
    return list(dict.fromkeys(values))


def plot_cost(paths, out):
    fig, axes = plt.subplots(1, len(paths), figsize=(6 * len(paths), 4.5), squeeze=False)
    for ax, path in zip(axes[0], paths):
        rows = read_csv(path, "cost")
        variants = ordered(r["variant"] for r in rows)
        for vi, variant in enumerate(variants):
            style = VARIANT_STYLES[vi % len(VARIANT_STYLES)]
            vrows = [r for r in rows if r["variant"] == variant]
            suffix = "" if len(variants) == 1 else f" ({variant})"
            for method in ordered(r["method"] for r in vrows):
                mrows = sorted((r for r in vrows if r["method"] == method), key=lambda r: int(r["particles"]))
                ax.plot([int(r["particles"]) for r in mrows], [number(r["step_seconds"]) for r in mrows], style,
                        marker="o", color=METHOD_COLORS.get(method), label=f"{method}: one step{suffix}")
            brows = sorted({int(r["particles"]): r for r in vrows}.values(), key=lambda r: int(r["particles"]))
            ax.plot([int(r["particles"]) for r in brows], [number(r["build_seconds"]) for r in brows], style,
                    marker="s", color="black", label=f"modal basis build (once){suffix}")
        first = rows[0]
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("particles (square grid, top row fixed)")
        ax.set_ylabel("seconds (median of timed runs)")
        ax.set_title(f"{first['dimension']}D, {first['num_modes']} modes ({tag_of(path, 'cost_', '.csv')})")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    target = out / "cost.png"
    fig.savefig(target, dpi=110)
    plt.close(fig)
    return [target]


def springs(rows, cols):
    """Structural and shear springs of a rows x cols grid, as particle index pairs."""
    pairs = []
    for r in range(rows):
        for c in range(cols):
            p = r * cols + c
            if c + 1 < cols:
                pairs.append((p, p + 1))
            if r + 1 < rows:
                pairs.append((p, p + cols))
            if r + 1 < rows and c + 1 < cols:
                pairs.append((p, p + cols + 1))
                pairs.append((p + 1, p + cols))
    return pairs


def plot_snapshots(path, out):
    rows = read_csv(path, "snapshots")
    tag = tag_of(path, "accuracy_", "_snapshots.csv")
    nrows = max(int(r["row"]) for r in rows) + 1
    ncols = max(int(r["col"]) for r in rows) + 1
    links = springs(nrows, ncols)
    three_d = any(abs(number(r["y"])) > 1e-12 for r in rows)
    frames = {}
    for r in rows:
        frames.setdefault((r["variant"], r["method"], int(r["step"])), {})[int(r["particle"])] = (
            number(r["x"]), number(r["y"]), number(r["z"]))
    steps = sorted({k[2] for k in frames})
    base = "reference" if any(k[1] == "reference" for k in frames) else "full"
    panels = [(v, m) for v, m in ordered((k[0], k[1]) for k in frames) if m != base]
    times = {int(r["step"]): number(r["time"]) for r in rows}
    # Every panel on the scale of the reference, so the figures compare shapes and sizes; a method
    # that drifts far away leaves the panel and says so in its title.
    reference = [p for k, f in frames.items() if k[1] == base for p in f.values()]
    lo = [min(p[d] for p in reference) for d in range(3)]
    hi = [max(p[d] for p in reference) for d in range(3)]
    span = max(h - l for l, h in zip(lo, hi))
    lo = [l - 0.1 * span for l in lo]
    hi = [h + 0.1 * span for h in hi]
    xs, ys, zs = (lo[0], hi[0]), (lo[1], hi[1]), (lo[2], hi[2])

    def inside(p):
        return all(lo[d] <= p[d] <= hi[d] for d in range(3))

    def outside(frame):
        return any(not (lo[d] <= p[d] <= hi[d]) for p in frame.values() for d in range(3))

    width = 2.6 if three_d else 2.6 * (hi[0] - lo[0]) / (hi[2] - lo[2]) + 0.4
    fig = plt.figure(figsize=(width * len(steps), (3.2 if three_d else 2.8) * len(panels) + 0.6))
    if any(v != "base" for v, _ in panels):
        fig.set_size_inches(max(fig.get_size_inches()[0], 2.3 * len(steps)), fig.get_size_inches()[1] + 0.3 * len(panels))
    for i, (variant, method) in enumerate(panels):
        for j, step in enumerate(steps):
            index = i * len(steps) + j + 1
            ax = fig.add_subplot(len(panels), len(steps), index, projection="3d" if three_d else None)
            for name, color, width in ((base, METHOD_COLORS["full"], 0.8), (method, METHOD_COLORS.get(method), 1.0)):
                frame = frames.get((variant, name, step))
                if frame is None:  # diverged before this step
                    continue
                for a, b in links:
                    pa, pb = frame[a], frame[b]
                    if three_d:
                        if not (inside(pa) and inside(pb)):  # 3D axes do not clip
                            continue
                        ax.plot([pa[0], pb[0]], [pa[1], pb[1]], [pa[2], pb[2]], color=color, lw=width * 0.6)
                    else:
                        ax.plot([pa[0], pb[0]], [pa[2], pb[2]], color=color, lw=width * 0.6)
                pts = list(frame.values())
                if three_d:
                    pts = [p for p in pts if inside(p)]
                    ax.scatter([p[0] for p in pts], [p[1] for p in pts], [p[2] for p in pts], s=4, color=color)
                else:
                    ax.scatter([p[0] for p in pts], [p[2] for p in pts], s=8, color=color, zorder=3)
                    ax.set_xlim(*xs)
                    ax.set_ylim(*zs)
            if three_d:
                ax.set_xlim(*xs)
                ax.set_ylim(*ys)
                ax.set_zlim(*zs)
                ax.set_box_aspect((hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]))
                ax.view_init(elev=15, azim=-60)
                ax.tick_params(labelsize=5)
            else:
                ax.set_xlim(*xs)
                ax.set_ylim(*zs)
                ax.set_aspect("equal")
                ax.tick_params(labelsize=6)
            label = method if variant == "base" else f"{method}\n{variant}"
            if frames.get((variant, method, step)) is None:
                label += ": diverged"
            elif outside(frames[(variant, method, step)]):
                label += " (leaves the frame)"
            ax.set_title(f"{label}\nstep {step} ({times[step]:g} s)", fontsize=7 if variant == "base" else 6)
    fig.suptitle(f"{tag}: each method (colour) over {base} (grey)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.45 / fig.get_size_inches()[1]))
    target = out / f"snapshots_{tag}.png"
    fig.savefig(target, dpi=110 if len(panels) <= 2 else 70)
    plt.close(fig)
    return [target]


def plot_error(path, out):
    rows = read_csv(path, "error")
    tag = tag_of(path, "accuracy_", "_error.csv")
    base = "reference" if any(r["method"] == "reference" for r in rows) else "full"
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    variants = ordered(r["variant"] for r in rows)
    for column, ax, title in (("max_distance", axes[0], f"largest particle distance to {base}"),
                              ("rms_distance", axes[1], f"RMS particle distance to {base}")):
        for vi, variant in enumerate(variants):
            for method in ordered(r["method"] for r in rows if r["variant"] == variant):
                if method == base or (method == "reference_half_step" and vi > 0):
                    continue
                series = [(number(r["time"]), number(r[column])) for r in rows
                          if r["variant"] == variant and r["method"] == method and r["diverged"] == "0"]
                series = [(t, e) for t, e in series if e > 0]
                label = method if len(variants) == 1 else f"{method} ({variant})"
                if method == "reference_half_step":
                    label = "reference at half its step (convergence check)"
                ax.plot([t for t, _ in series], [e for _, e in series], VARIANT_STYLES[vi % len(VARIANT_STYLES)],
                        color=METHOD_COLORS.get(method), label=label, lw=1)
        ax.set_yscale("log")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("m")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        if len(variants) == 1:
            ax.legend(fontsize=8)
    fig.suptitle(f"{tag}: error against {base}", fontsize=10)
    if len(variants) == 1:
        fig.tight_layout()
    else:  # many curves: the legend goes below, off the data
        fig.set_size_inches(11, 4 + 0.2 * len(variants) * 2)
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=8)
        fig.tight_layout(rect=(0, 0.1 * len(variants) * 2 / (4 + 0.2 * len(variants) * 2) + 0.1, 1, 1))
    target = out / f"error_{tag}.png"
    fig.savefig(target, dpi=110)
    plt.close(fig)
    return [target]


def scenario_of(variant):
    """A handles variant is the scenario's name, then the varied settings, if any."""
    name, _, rest = variant.partition(" ")
    return name, rest


def short_setting(setting):
    """A legend's name for varied settings: the values alone, "integrator=explicit
    handle_formulation=auto" as "explicit, auto"."""
    return ", ".join(part.split("=", 1)[-1].replace("_", " ") for part in setting.split())


def plot_handles(path, out):
    """RMS distance to the reference over time, one panel per scenario, every method (the line style
    tells the varied settings apart); a diverged run's curve stops where it diverged, marked x."""
    rows = read_csv(path, "error")
    tag = tag_of(path, "handles_", "_error.csv")
    base = "reference" if any(r["method"] == "reference" for r in rows) else "full"
    scenarios = ordered(scenario_of(r["variant"])[0] for r in rows)
    settings = ordered(scenario_of(r["variant"])[1] for r in rows)
    columns = min(3, len(scenarios))
    lines = (len(scenarios) + columns - 1) // columns
    fig, axes = plt.subplots(lines, columns, figsize=(4.2 * columns, 3.3 * lines + 0.8), squeeze=False, sharey=True)
    for k, scenario in enumerate(scenarios):
        ax = axes[k // columns][k % columns]
        for si, setting in enumerate(settings):
            variant = scenario + (" " + setting if setting else "")
            for method in ordered(r["method"] for r in rows if r["variant"] == variant):
                # The reference and its check are the same for every setting: drawn once.
                if method == base or (method == "reference_half_step" and si > 0):
                    continue
                series = [r for r in rows if r["variant"] == variant and r["method"] == method and int(r["step"]) > 0]
                good = [(number(r["time"]), number(r["rms_distance"])) for r in series if r["diverged"] == "0"]
                good = [(t, e) for t, e in good if e > 0]
                label = method + (f" ({short_setting(setting)})" if setting else "")
                if method == "reference_half_step":
                    label = "reference at half its step (convergence check)"
                ax.plot([t for t, _ in good], [e for _, e in good], VARIANT_STYLES[si % len(VARIANT_STYLES)],
                        color=METHOD_COLORS.get(method), label=label if k == 0 else None, lw=1)
                if good and any(r["diverged"] == "1" for r in series):
                    ax.plot([good[-1][0]], [good[-1][1]], "x", color=METHOD_COLORS.get(method), ms=7)
        ax.set_yscale("log")
        ax.set_title(scenario, fontsize=10)
        ax.set_xlabel("time (s)")
        ax.grid(True, which="both", alpha=0.3)
        if k % columns == 0:
            ax.set_ylabel(f"RMS distance to {base} (m)")
    for k in range(len(scenarios), lines * columns):
        axes[k // columns][k % columns].axis("off")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(4, max(1, len(labels))), fontsize=8)
    fig.suptitle(f"{tag}: moving handles, every method against {base} (x: diverged)", fontsize=10)
    legend_rows = (len(labels) + 3) // 4
    fig.tight_layout(rect=(0, (0.25 + 0.2 * legend_rows) / (3.3 * lines + 0.8), 1, 1))
    target = out / f"handles_{tag}.png"
    fig.savefig(target, dpi=110)
    plt.close(fig)
    return [target]


def plot_handle_shapes(path, out):
    """The cloth where the move ends, one 3D panel per scenario (of the first varied setting): the
    reference, `linear` and `physical` as wireframes over the grid's rows and columns."""
    rows = read_csv(path, "snapshots")
    tag = tag_of(path, "handles_", "_snapshots.csv")
    base = "reference" if any(r["method"] == "reference" for r in rows) else "full"
    first = ordered(scenario_of(r["variant"])[1] for r in rows)[0]
    scenarios = [s for s in ordered(scenario_of(r["variant"])[0] for r in rows)]
    shown = [(base, "black"), ("linear", METHOD_COLORS["linear"]), ("physical", METHOD_COLORS["physical"])]
    columns = min(3, len(scenarios))
    lines = (len(scenarios) + columns - 1) // columns
    fig = plt.figure(figsize=(4.4 * columns, 4.2 * lines + 1.2))
    for k, scenario in enumerate(scenarios):
        ax = fig.add_subplot(lines, columns, k + 1, projection="3d")
        variant = scenario + (" " + first if first else "")
        lows, highs = [math.inf] * 3, [-math.inf] * 3
        for method, color in shown:
            points = [r for r in rows if r["variant"] == variant and r["method"] == method]
            if not points:
                continue
            n_rows = max(int(r["row"]) for r in points) + 1
            n_cols = max(int(r["col"]) for r in points) + 1
            grid = [[None] * n_cols for _ in range(n_rows)]
            for r in points:
                grid[int(r["row"])][int(r["col"])] = tuple(number(r[c]) for c in ("x", "y", "z"))
            for axis in range(3):
                values = [p[axis] for line in grid for p in line]
                lows[axis], highs[axis] = min(lows[axis], min(values)), max(highs[axis], max(values))
            label = method if k == 0 else None
            for line in grid:  # along each row, then along each column
                ax.plot([p[0] for p in line], [p[1] for p in line], [p[2] for p in line], color=color, lw=0.6,
                        label=label)
                label = None
            for c in range(n_cols):
                column = [grid[r][c] for r in range(n_rows)]
                ax.plot([p[0] for p in column], [p[1] for p in column], [p[2] for p in column], color=color, lw=0.6)
        # Equal scales on the three axes, so a turn looks like a turn.
        half = max(h - l for l, h in zip(lows, highs)) / 2
        for axis, setter in enumerate((ax.set_xlim, ax.set_ylim, ax.set_zlim)):
            centre = (lows[axis] + highs[axis]) / 2
            setter(centre - half, centre + half)
        ax.set_box_aspect((1, 1, 1))
        ax.set_title(f"{scenario}, t = {number(points[0]['time']):.2g} s" if points else scenario, fontsize=10)
        ax.set_xlabel("x (m)", fontsize=8)
        ax.set_ylabel("y (m)", fontsize=8)
        ax.set_zlabel("z (m)", fontsize=8)
        ax.tick_params(labelsize=7)
    fig.legend(loc="lower center", ncol=3, fontsize=9)
    fig.suptitle(f"{tag}: the cloth where the handles stop moving" + (f" ({first})" if first else ""), fontsize=10)
    # tight_layout misplaces 3D axes: the margins by hand, room for the titles between the lines.
    fig.subplots_adjust(left=0.0, right=0.96, bottom=0.6 / fig.get_figheight(), top=1 - 0.8 / fig.get_figheight(),
                        wspace=0.1, hspace=0.12)
    target = out / f"handles_{tag}_shapes.png"
    fig.savefig(target, dpi=110)
    plt.close(fig)
    return [target]


def handle_tables(data):
    parts = []
    for path in sorted(data.glob("handles_*_summary.csv")):
        rows = read_csv(path, "summary")
        base = "reference" if any(r["method"] == "reference" for r in rows) else "full"
        # A method that could not be built on a scenario says why (files before not_built have no column).
        body = [[r["variant"], r["method"], "did not build: " + r["not_built"], "", "", ""] if r.get("not_built") else
                [r["variant"], r["method"], fmt(1e3 * number(r["mean_rms"])), fmt(1e3 * number(r["max_rms"])),
                 "diverged" if r["diverged"] == "1" else fmt(1e3 * number(r["final_rms"])),
                 fmt(1e6 * number(r["step_seconds_median"]))]
                for r in rows if r["method"] != base]
        parts.append(f"## {path.name}: distance of the free particles to the reference (mm)\n\nMean and largest "
                     "RMS over every sample after step 0, the RMS at the end; median wall time per step.\n\n" + markdown(
                         ["scenario", "method", "mean RMS", "largest RMS", "RMS at the end", "step (us)"], body))
    return parts


def plot_stability(path, out):
    rows = read_csv(path, "stability")
    tag = tag_of(path, "stability_", ".csv")
    labels = [r["method"] if r["variant"] == "base" else r["method"] + "\n" + r["variant"].replace(" ", "\n")
              for r in rows]
    values = [number(r["stable_dt"]) for r in rows]
    per_bar = 1.45 if all(r["variant"] == "base" for r in rows) else 1.9
    fig, ax = plt.subplots(figsize=(max(5.5, per_bar * len(rows)), 4.2 + 0.25 * max(l.count("\n") for l in labels)))
    bars = ax.bar(range(len(rows)), values, color=[METHOD_COLORS.get(r["method"], "0.5") for r in rows])
    window_label = "stable windows above the boundary"
    for i, (bar, value, r) in enumerate(zip(bars, values, rows)):
        if unbounded(r):
            bar.set_hatch("//")
        text = f">= {value:.3g} s\n(no divergence found)" if unbounded(r) else f"{value * 1e3:.3g} ms"
        for k, (low, high) in enumerate(windows(r)):
            ax.plot([i + 0.3, i + 0.3], [low, high * 1.02], color="black", lw=3, solid_capstyle="butt",
                    label=window_label)
            window_label = None
        if windows(r):
            text += f"\n+{len(windows(r))} stable window(s)"
        if number(r.get("check_dt", "0") or "0") > 0:
            text += f"\n{'stable' if r.get('check_stable') == '1' else 'DIVERGES'} at\n{number(r['check_dt']):.3g} s (10x)"
        ax.annotate(text, (bar.get_x() + bar.get_width() / 2, value), ha="center", va="bottom", fontsize=7)
    modal = ordered(number(r["modal_bound"]) for r in rows)
    full = ordered(number(r["full_bound"]) for r in rows)
    for i, value in enumerate(v for v in modal if math.isfinite(v)):
        ax.axhline(value, color="tab:red", ls="--", lw=0.8, label="2/omega, highest mode of the basis" if i == 0 else None)
    for i, value in enumerate(v for v in full if not math.isnan(v)):
        ax.axhline(value, color="0.3", ls=":", lw=0.8, label="2/omega, highest of K(x0) (all dofs)" if i == 0 else None)
    ax.set_xticks(range(len(rows)))
    ax.set_xticklabels(labels, fontsize=7)
    ax.set_yscale("log")
    positive = [v for v in values + modal + full + [w for r in rows for pair in windows(r) for w in pair]
                if v > 0 and math.isfinite(v)]
    ax.set_ylim(min(positive) / 3, max(positive) * 30)
    ax.set_ylabel("largest stable time step (s)")
    first = rows[0]
    ax.set_title(f"{tag}: every step tried below it ran {first['steps']} steps\n(scan, then bisection to "
                 f"a relative {first['tolerance']})", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.tight_layout()
    target = out / f"stability_{tag}.png"
    fig.savefig(target, dpi=110)
    plt.close(fig)
    return [target]


def combination_files(data):
    """{config: {time step (s): path}} of the accuracy runs against a converged reference."""
    found = {}
    for path in sorted(data.glob("accuracy_combinations_*_dt*ms_error.csv")):
        tag = tag_of(path, "accuracy_combinations_", "_error.csv")
        config, _, dt = tag.rpartition("_dt")
        found.setdefault(config, {})[float(dt[:-2]) / 1e3] = path
    return found


def summarize(rows):
    """Per (variant, method): mean and largest RMS distance, median wall time per step, diverged."""
    out = {}
    for r in rows:
        key = (r["variant"], r["method"])
        s = out.setdefault(key, {"rms": [], "diverged": False, "times": []})
        if int(r["step"]) == 0:
            continue
        if r["diverged"] == "1":
            s["diverged"] = True
            continue
        s["rms"].append(number(r["rms_distance"]))
        t = number(r.get("step_seconds", "0") or "0")
        if t > 0:
            s["times"].append(t)
    for s in out.values():
        s["mean_rms"] = math.nan if s["diverged"] or not s["rms"] else sum(s["rms"]) / len(s["rms"])
        s["max_rms"] = math.nan if s["diverged"] or not s["rms"] else max(s["rms"])
        times = sorted(s["times"])
        s["step_seconds"] = times[len(times) // 2] if times else math.nan
    return out


def short_variant(variant):
    parts = dict(p.split("=", 1) for p in variant.split() if "=" in p)
    return f"{parts.get('linearization', '?')}, {parts.get('integrator', '?')}"


def plot_combinations(found, out):
    configs = sorted(found)
    fig, axes = plt.subplots(2, len(configs), figsize=(6.5 * len(configs), 9), squeeze=False)
    styles = {"rest": "--", "equilibrium": "-"}
    markers = {"explicit": "o", "implicit": "s"}
    for c, config in enumerate(configs):
        by_dt = {dt: summarize(read_csv(path, "error")) for dt, path in sorted(found[config].items())}
        dts = sorted(by_dt)
        keys = ordered(k for dt in dts for k in by_dt[dt] if k[1] not in REFERENCES)
        check = [by_dt[dt].get((k[0], "reference_half_step")) for dt in dts for k in keys]
        for key in keys:
            variant, method = key
            parts = dict(p.split("=", 1) for p in variant.split() if "=" in p)
            style = styles.get(parts.get("linearization"), ":")
            marker = markers.get(parts.get("integrator"), "^")
            errors = [by_dt[dt][key]["mean_rms"] if key in by_dt[dt] else math.nan for dt in dts]
            costs = [by_dt[dt][key]["step_seconds"] / dt if key in by_dt[dt] and not by_dt[dt][key]["diverged"]
                     else math.nan for dt in dts]
            label = f"{method}, {short_variant(variant)}"
            kw = dict(color=METHOD_COLORS.get(method), ls=style, marker=marker, ms=5, lw=1,
                      mfc="none" if parts.get("integrator") == "implicit" else None)
            axes[0][c].plot(dts, errors, label=label, **kw)
            axes[1][c].plot(dts, costs, label=label, **kw)
            for dt, e in zip(dts, errors):
                if math.isnan(e):
                    axes[0][c].annotate("x", (dt, 1.0), xycoords=("data", "axes fraction"), ha="center", va="top",
                                        color=METHOD_COLORS.get(method), fontsize=9)
        floor = [max((by_dt[dt][k]["max_rms"] for k in by_dt[dt] if k[1] == "reference_half_step"), default=math.nan)
                 for dt in dts]
        axes[0][c].plot(dts, floor, color="black", lw=0.8, ls=":", label="reference vs. reference at half its step")
        axes[0][c].set_title(f"{config}: mean RMS distance to the converged reference over 5 s\n"
                             "(x at the top: diverged at that step)", fontsize=9)
        axes[1][c].set_title(f"{config}: wall time per simulated second (median step time / dt)", fontsize=9)
        for ax in axes[:, c]:
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("time step (s)")
            ax.grid(True, which="both", alpha=0.3)
        axes[0][c].set_ylabel("m")
        axes[1][c].set_ylabel("s of wall time per s simulated")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8)
    fig.suptitle("Every method x linearization x integrator: colour = method, line = linearization (solid "
                 "equilibrium, dashed rest), marker = integrator (filled explicit, open implicit)", fontsize=9)
    fig.tight_layout(rect=(0, 0.13, 1, 0.97))
    target = out / "combinations.png"
    fig.savefig(target, dpi=100)
    plt.close(fig)
    return [target]


def error_cost_files(data):
    """{config: {time step (s): path}} of the error-against-cost runs."""
    found = {}
    for path in sorted(data.glob("accuracy_error_cost_*_dt*ms_error.csv")):
        config, _, dt = tag_of(path, "accuracy_error_cost_", "_error.csv").rpartition("_dt")
        found.setdefault(config, {})[float(dt[:-2]) / 1e3] = path
    return found


def plot_error_cost(found, out):
    """One point per method x linearization x integrator x time step: cost per step against error."""
    configs = sorted(found)
    fig, axes = plt.subplots(1, len(configs), figsize=(6.5 * len(configs), 6.2), squeeze=False)
    markers = {"explicit": "o", "implicit": "s"}
    # One marker size per time step, the same in every panel and in the legend.
    dt_sizes = {dt: 16 + 30 * k for k, dt in enumerate(sorted({dt for config in configs for dt in found[config]}))}
    diverged = []
    for c, config in enumerate(configs):
        ax = axes[0][c]
        by_dt = {dt: summarize(read_csv(path, "error")) for dt, path in sorted(found[config].items())}
        dts = sorted(by_dt)
        keys = ordered(k for dt in dts for k in by_dt[dt] if k[1] not in REFERENCES)
        for variant, method in keys:
            parts = dict(p.split("=", 1) for p in variant.split() if "=" in p)
            integrator, linearization = parts.get("integrator"), parts.get("linearization")
            points = []
            for dt in dts:
                s = by_dt[dt].get((variant, method))
                if s is None:
                    continue
                if s["diverged"]:
                    diverged.append(f"{config} {method}, {linearization}, {integrator}, {dt * 1e3:g} ms")
                    continue
                points.append((s["step_seconds"], s["mean_rms"], dt))
            if not points:
                continue
            color = METHOD_COLORS.get(method)
            ax.plot([p[0] for p in points], [p[1] for p in points], color=color, lw=0.6,
                    ls="-" if linearization == "equilibrium" else "--", alpha=0.6)
            for cost, error, dt in points:
                ax.scatter([cost], [error], s=dt_sizes[dt], marker=markers.get(integrator, "^"),
                           facecolors=color if linearization == "equilibrium" else "none", edgecolors=color, lw=1.1)
        floor = max((s["max_rms"] for dt in dts for k, s in by_dt[dt].items() if k[1] == "reference_half_step"),
                    default=math.nan)
        if not math.isnan(floor) and floor > 0:
            ax.axhline(floor, color="black", lw=0.8, ls=":")
            ax.annotate("reference vs. itself at half its step", (0.01, floor), xycoords=("axes fraction", "data"),
                        va="bottom", fontsize=7)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("median wall time of one step (s)")
        ax.set_ylabel("mean RMS distance to the converged reference over 5 s (m)")
        ax.set_title(f"{config}: error against cost per step", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    from matplotlib.lines import Line2D
    handles = [Line2D([], [], color=METHOD_COLORS[m], lw=3, label=m) for m in ("full", "linear", "physical", "cubature")]
    handles += [Line2D([], [], color="0.3", marker="o", ls="none", label="explicit"),
                Line2D([], [], color="0.3", marker="s", ls="none", label="implicit"),
                Line2D([], [], color="0.3", marker="o", mfc="0.3", ls="-", label="equilibrium (filled, solid)"),
                Line2D([], [], color="0.3", marker="o", mfc="none", ls="--", label="rest (open, dashed)")]
    handles += [Line2D([], [], color="0.3", marker="o", mfc="none", ls="none", ms=math.sqrt(size),
                       label=f"time step {dt * 1e3:g} ms") for dt, size in dt_sizes.items()]
    fig.legend(handles=handles, loc="lower center", ncol=6, fontsize=8)
    note = "Down and left is better; a time step's cost per simulated second is the step's cost / dt."
    if diverged:
        note += " Diverged (not drawn): " + "; ".join(diverged) + "."
    fig.text(0.5, 0.995, note, ha="center", va="top", fontsize=7, wrap=True)
    fig.tight_layout(rect=(0, 0.11, 1, 0.95))
    target = out / "error_cost.png"
    fig.savefig(target, dpi=100)
    plt.close(fig)
    return [target]


def combination_tables(found):
    parts = []
    for config in sorted(found):
        body = []
        for dt, path in sorted(found[config].items()):
            summary = summarize(read_csv(path, "error"))
            check = max((s["max_rms"] for k, s in summary.items() if k[1] == "reference_half_step"), default=math.nan)
            for (variant, method), s in summary.items():
                if method in REFERENCES:
                    continue
                body.append([f"{dt * 1e3:g}", method, short_variant(variant),
                             "diverged" if s["diverged"] else fmt(s["mean_rms"]),
                             "diverged" if s["diverged"] else fmt(s["max_rms"]),
                             fmt(1e6 * s["step_seconds"]),
                             "-" if s["diverged"] else fmt(s["step_seconds"] / dt), fmt(check)])
        parts.append(f"## {config}: every combination against the converged reference\n\nMean and largest RMS "
                     "particle distance over 5 s (sampled every 50 ms), the median wall time of one step while it ran, "
                     "wall time per simulated second, and the reference's own check (largest RMS distance to "
                     "the reference at half its step).\n\n" + markdown(
                         ["dt (ms)", "method", "linearization, integrator", "mean RMS (m)", "largest RMS (m)",
                          "step (us)", "wall s / simulated s", "reference check (m)"], body))
    return parts


def fmt(value, digits=3):
    if math.isnan(value):
        return "-"
    if math.isinf(value):
        return "none found"
    return f"{value:.{digits}g}"


def markdown(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def derivative_files(data):
    """{config: (linear_modes error file, modal_derivatives error file)} for the pairs present."""
    found = {}
    for path in sorted(data.glob("accuracy_derivatives_*_modal_derivatives_error.csv")):
        config = tag_of(path, "accuracy_derivatives_", "_modal_derivatives_error.csv")
        twin = path.with_name(f"accuracy_derivatives_{config}_linear_modes_error.csv")
        if twin.exists():
            found[config] = (twin, path)
    return found


def swing_period(series):
    """Mean period (s) of a swing from the zero crossings of (t, y - its mean); NaN below 3 crossings."""
    if not series:
        return math.nan
    mean = sum(y for _, y in series) / len(series)
    crossings = []
    for (t0, y0), (t1, y1) in zip(series, series[1:]):
        if (y0 - mean) * (y1 - mean) < 0:
            crossings.append(t0 + (t1 - t0) * (y0 - mean) / ((y0 - mean) - (y1 - mean)))
    if len(crossings) < 3:
        return math.nan
    return 2 * (crossings[-1] - crossings[0]) / (len(crossings) - 1)


def derivative_labels(config):
    """Labels of the four runs; with R and D from a name ending in _r<R>_d<D>, their basis sizes."""
    match = re.search(r"_r(\d+)_d(\d+)$", config)
    if not match:
        return ["full", "linear", "physical, linear modes", "physical, modal derivatives"]
    r, d = int(match.group(1)), int(match.group(2))
    return ["full", f"linear, {r + d} modes", f"physical, {r + d} linear modes",
            f"physical, {r} modes + {d} derivative directions"]


def derivative_runs(config, pair):
    """[(label, method rows)] of full, linear, physical with linear modes, physical with derivatives."""
    linear_rows, derivative_rows = (read_csv(p, "error") for p in pair)
    labels = derivative_labels(config)
    runs = [(labels[0], [r for r in linear_rows if r["method"] == "full"]),
            (labels[1], [r for r in linear_rows if r["method"] == "linear"]),
            (labels[2], [r for r in linear_rows if r["method"] == "physical"]),
            (labels[3], [r for r in derivative_rows if r["method"] == "physical"])]
    return [(label, rows) for label, rows in runs if rows]


def derivative_summary(rows):
    valid = [r for r in rows if r["diverged"] == "0" and int(r["step"]) > 0]
    mean_rms = sum(number(r["rms_distance"]) for r in valid) / max(1, len(valid))
    swing = [(number(r["time"]), number(r["center_y"])) for r in rows if r["diverged"] == "0"]
    diverged = any(r["diverged"] == "1" for r in rows)
    return mean_rms, swing_period(swing), diverged


DERIVATIVE_COLORS = ["0.35", "tab:red", "tab:blue", "tab:green"]  # in the order of derivative_labels


def plot_derivatives(found, out):
    written = []
    for config, pair in found.items():
        runs = derivative_runs(config, pair)
        colors = dict(zip(derivative_labels(config), DERIVATIVE_COLORS))
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        for label, rows in runs:
            ok = [r for r in rows if r["diverged"] == "0"]
            t = [number(r["time"]) for r in ok]
            if label != "full":
                axes[0].plot(t, [number(r["rms_distance"]) for r in ok], color=colors[label], label=label, lw=1)
            axes[1].plot(t, [number(r["center_y"]) for r in ok], color=colors[label], label=label, lw=1)
        axes[0].set_title("RMS particle distance to full", fontsize=10)
        axes[0].set_ylabel("m")
        axes[1].set_title("the swing: mean y of the particles", fontsize=10)
        axes[1].set_ylabel("m")
        for ax in axes:
            ax.set_xlabel("time (s)")
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=8)
        fig.suptitle(f"{config}: modal derivatives against linear modes", fontsize=10)
        fig.tight_layout()
        target = out / f"derivatives_{config}.png"
        fig.savefig(target, dpi=110)
        plt.close(fig)
        written.append(target)
    return written


def derivative_tables(found):
    parts = []
    for config, pair in found.items():
        runs = derivative_runs(config, pair)
        full_period = derivative_summary(runs[0][1])[1]
        body = []
        for label, rows in runs:
            mean_rms, period, diverged = derivative_summary(rows)
            body.append([label, "-" if label == "full" else fmt(mean_rms) + (" (diverged)" if diverged else ""),
                         fmt(period), fmt(period / full_period)])
        parts.append(f"## {pair[0].name}, {pair[1].name}: modal derivatives\n\nMean RMS distance to full over "
                     "every sample after step 0; the swing period from the zero crossings of the particles' mean y, "
                     "and its ratio to full's.\n\n"
                     + markdown(["method", "mean RMS distance (m)", "swing period (s)", "period / full's"], body))
    return parts


def write_tables(data, target):
    """The figures' numbers as Markdown: per-step cost, error every snapshot interval, stable steps."""
    parts = ["# Numbers behind the figures\n\nWritten by scripts/plot_comparison.py from the CSV files in this folder.\n"]
    for path in sorted(data.glob("cost_*.csv")):
        rows = read_csv(path, "cost")
        methods = ordered(r["method"] for r in rows)
        body = []
        for variant in ordered(r["variant"] for r in rows):
            for size in ordered(r["rows"] for r in rows if r["variant"] == variant):
                cell = {r["method"]: r for r in rows if r["variant"] == variant and r["rows"] == size}
                first = next(iter(cell.values()))
                body.append([variant, f"{size}x{first['cols']}", first["particles"], first["free_dofs"],
                             fmt(1e3 * number(first["build_seconds"]))]
                            + [fmt(1e6 * number(cell[m]["step_seconds"])) + (" (diverged)" if cell[m]["diverged"] == "1" else "")
                               if m in cell else "-" for m in methods])
        parts.append(f"## {path.name}: median cost\n\n" + markdown(
            ["variant", "grid", "particles", "free dofs", "basis build (ms)"] + [f"{m} step (us)" for m in methods], body))
    for path in sorted(data.glob("accuracy_*_error.csv")):
        rows = [r for r in read_csv(path, "error") if r["method"] != "full"]
        snapshot_steps = sorted({int(r["step"]) for r in read_csv(path.with_name(path.name.replace("_error", "_snapshots")), "snapshots")}) \
            if path.with_name(path.name.replace("_error", "_snapshots")).exists() else []
        body = []
        for variant in ordered(r["variant"] for r in rows):
            for method in ordered(r["method"] for r in rows if r["variant"] == variant):
                series = [r for r in rows if r["variant"] == variant and r["method"] == method]
                valid = [r for r in series if r["diverged"] == "0" and int(r["step"]) > 0]
                mean_rms = sum(number(r["rms_distance"]) for r in valid) / max(1, len(valid))
                mean_max = sum(number(r["max_distance"]) for r in valid) / max(1, len(valid))
                at = {int(r["step"]): r for r in series}
                body.append([variant, method, fmt(mean_max), fmt(mean_rms)]
                            + [fmt(number(at[s]["rms_distance"])) if s in at else "-" for s in snapshot_steps if s > 0])
        parts.append(f"## {path.name}: distance to full (m)\n\nMeans over every sample after step 0; then the RMS "
                     "distance at each snapshot step.\n\n" + markdown(
                         ["variant", "method", "mean largest", "mean RMS"] + [f"RMS @ {s}" for s in snapshot_steps if s > 0], body))
    for path in sorted(data.glob("stability_*.csv")):
        rows = read_csv(path, "stability")
        body = [[r["variant"], r["method"], fmt(1e3 * number(r["stable_dt"]), 5),
                 "none found" if unbounded(r) else fmt(1e3 * number(r["unstable_dt"]), 5),
                 fmt(1e3 * number(r["modal_bound"]), 5), fmt(1e3 * number(r["full_bound"]), 5),
                 ", ".join(f"{1e3 * a:.4g}" if a == b else f"{1e3 * a:.4g}-{1e3 * b:.4g}" for a, b in windows(r)) or "none"]
                for r in rows]
        if any(number(r.get("check_dt", "0") or "0") > 0 for r in rows):
            for b, r in zip(body, rows):
                b.append(f"{'stable' if r['check_stable'] == '1' else 'DIVERGED'} at {fmt(1e3 * number(r['check_dt']), 4)}"
                         if number(r.get("check_dt", "0") or "0") > 0 else "-")
        header = ["variant", "method", "stable", "diverges", "2/omega highest mode", "2/omega K(x0)",
                  "stable windows above"]
        if len(body[0]) > len(header):
            header.append("10 x the explicit method's stable step (ms)")
        parts.append(f"## {path.name}: largest stable time step (ms), {rows[0]['steps']} steps, relative tolerance "
                     f"{rows[0]['tolerance']}\n\n" + markdown(header, body))
    parts += combination_tables(combination_files(data))
    parts += derivative_tables(derivative_files(data))
    parts += handle_tables(data)
    target.write_text("\n".join(parts))
    return [target]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="folder with the CSV files of modal_compare")
    parser.add_argument("--out", required=True, help="folder for the PNG files")
    args = parser.parse_args(argv)
    data, out = pathlib.Path(args.data), pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    try:
        cost = sorted(data.glob("cost_*.csv"))
        if cost:
            written += plot_cost(cost, out)
        for path in sorted(data.glob("accuracy_*_snapshots.csv")):
            written += plot_snapshots(path, out)
        # Of the runs against the converged reference, only the smallest time step gets an error figure;
        # combinations.png draws them all.
        skip = {p for steps in combination_files(data).values() for dt, p in steps.items() if dt != min(steps)}
        # The modal-derivative runs are drawn in pairs (derivatives_<config>.png), not one by one.
        skip |= {p for pair in derivative_files(data).values() for p in pair}
        # The error-against-cost runs are drawn together (error_cost.png).
        skip |= {p for steps in error_cost_files(data).values() for p in steps.values()}
        for path in sorted(data.glob("accuracy_*_error.csv")):
            if path not in skip:
                written += plot_error(path, out)
        for path in sorted(data.glob("stability_*.csv")):
            if not path.name.startswith("stability_derivatives_"):  # tabulated only, in tables.md
                written += plot_stability(path, out)
        combinations = combination_files(data)
        if combinations:
            written += plot_combinations(combinations, out)
        error_cost = error_cost_files(data)
        if error_cost:
            written += plot_error_cost(error_cost, out)
        derivatives = derivative_files(data)
        if derivatives:
            written += plot_derivatives(derivatives, out)
        for path in sorted(data.glob("handles_*_error.csv")):
            written += plot_handles(path, out)
        for path in sorted(data.glob("handles_*_snapshots.csv")):
            written += plot_handle_shapes(path, out)
        if written:
            written += write_tables(data, data / "tables.md")
    except ColumnError as error:
        print(f"plot_comparison: error: {error}", file=sys.stderr)
        return 1
    if not written:
        print(f"plot_comparison: error: no CSV files of modal_compare in {data}", file=sys.stderr)
        return 1
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
