#!/usr/bin/env python3
"""Compares two `laser_digest --dump` files (issue 15): per set and estimator/smoothing, how many points
differ, the largest change of each field, and rows found in one build only. Usage:
compare_digest_dumps.py BEFORE AFTER"""
import collections
import sys


def load(path):
    points = {}
    with open(path) as f:
        for line in f:
            v = line.split()
            points[tuple(v[:5])] = [float(x) for x in v[5:10]] + [int(v[10])]
    return points


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    before, after = load(sys.argv[1]), load(sys.argv[2])
    fields = ["column", "peak", "width", "quality", "uncertainty"]
    stats = collections.defaultdict(lambda: {"n": 0, "differ": 0, "flags": 0, "only": 0,
                                             "max": [0.0] * len(fields)})
    for key in before.keys() | after.keys():
        s = stats[key[:3]]
        if key not in before or key not in after:
            s["only"] += 1
            continue
        s["n"] += 1
        a, b = before[key], after[key]
        if a != b:
            s["differ"] += 1
        if a[5] != b[5]:
            s["flags"] += 1
        for k in range(len(fields)):
            s["max"][k] = max(s["max"][k], abs(a[k] - b[k]))
    for key in sorted(stats):
        s = stats[key]
        print(" ".join(key), f"points {s['n']} differ {s['differ']} flags {s['flags']} in one only {s['only']}",
              " ".join(f"max|d{f}| {m:.3g}" for f, m in zip(fields, s["max"])))


if __name__ == "__main__":
    main()
