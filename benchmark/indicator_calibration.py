#!/usr/bin/env python3
"""The error indicator against the true distance to `full`, from modal_compare's error CSVs.

    indicator_calibration.py handles_*_error.csv accuracy_*_error.csv

For each method: Spearman's rank correlation of error_indicator (the largest since the state was set)
with rms_distance over every sample after step 0 of every file (pooled), the same over the scenarios'
means, the median ratio of the distance to the indicator (the scale that calibrates it), each
scenario's means; then the same rank correlation and median ratio for error_estimate, the calibrated
estimate that `adaptive` holds against its tolerance.
"""
import csv
import math
import statistics
import sys


def ranks(values):
    order = sorted(range(len(values)), key=lambda i: values[i])
    result = [0.0] * len(values)
    i = 0
    while i < len(values):
        j = i
        while j + 1 < len(values) and values[order[j + 1]] == values[order[i]]:
            j += 1
        for k in range(i, j + 1):
            result[order[k]] = (i + j) / 2.0
        i = j + 1
    return result


def spearman(a, b):
    ra, rb = ranks(a), ranks(b)
    ma, mb = statistics.fmean(ra), statistics.fmean(rb)
    num = sum((x - ma) * (y - mb) for x, y in zip(ra, rb))
    den = math.sqrt(sum((x - ma) ** 2 for x in ra) * sum((y - mb) ** 2 for y in rb))
    return num / den if den > 0 else float("nan")


def main(paths):
    samples = {}  # method -> scenario -> [(indicator, distance, estimate)]
    for path in paths:
        name = path.rsplit("/", 1)[-1].replace("_error.csv", "")
        for row in csv.DictReader(open(path)):
            if row["step"] == "0" or not row.get("error_indicator") or row["diverged"] == "1":
                continue
            scenario = name + "/" + row["variant"]
            estimate = float(row["error_estimate"]) if row.get("error_estimate") else math.nan
            pair = (float(row["error_indicator"]), float(row["rms_distance"]), estimate)
            samples.setdefault(row["method"], {}).setdefault(scenario, []).append(pair)
    for method, scenarios in samples.items():
        pairs = [p[:2] for s in scenarios.values() for p in s]
        means = [(statistics.fmean(p[0] for p in s), statistics.fmean(p[1] for p in s)) for s in scenarios.values()]
        ratios = [d / i for i, d in pairs if i > 0]
        print(f"{method}: {len(pairs)} samples in {len(scenarios)} scenarios; rank correlation pooled "
              f"{spearman([i for i, _ in pairs], [d for _, d in pairs]):.3f}, over the scenarios' means "
              f"{spearman([i for i, _ in means], [d for _, d in means]):.3f}; distance / indicator median "
              f"{statistics.median(ratios):.3g}")
        for scenario, (i, d) in zip(scenarios, means):
            print(f"  {scenario:40s} indicator {i:.2e} m  RMS distance {d:.2e} m")
        estimates = [(p[2], p[1]) for s in scenarios.values() for p in s if not math.isnan(p[2])]
        if estimates:
            print(f"  estimate: rank correlation pooled {spearman([e for e, _ in estimates], [d for _, d in estimates]):.3f}; "
                  f"distance / estimate median {statistics.median(d / e for e, d in estimates if e > 0):.3g}")


if __name__ == "__main__":
    main(sys.argv[1:])
