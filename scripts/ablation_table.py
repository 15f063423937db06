#!/usr/bin/env python3
"""Prints the ablation's Markdown tables (docs/research/ablation.md) from the runs' outputs.

usage: ablation_table.py RUNS CONFIG...   (RUNS/CONFIG/metrics.csv and RUNS/CONFIG/util_*.json)
"""
import csv
import glob
import json
import os
import sys


def run_summary(run):
    """Final and best validation (loss, PSNR), steps, and training seconds from metrics.csv."""
    vals, seconds, steps = [], 0.0, 0
    batch = None
    with open(os.path.join(run, "metrics.csv")) as f:
        for row in csv.DictReader(f):
            step = int(row["step"])
            if row["kind"] == "val":
                vals.append((step, float(row["loss"]), float(row["psnr"])))
            elif row["tiles_per_s"]:
                steps = max(steps, step)
                # seconds of this step = batch / (tiles per second); batch from the config
                seconds += 1.0 / float(row["tiles_per_s"])
    best = min(vals, key=lambda v: v[1])
    return {"first": vals[0], "last": vals[-1], "best": best, "steps": steps,
            "seconds_per_tile_sum": seconds}


def utilization(run):
    """Per-offset mean (over scenes) of the mean weight, and max of the max weight."""
    files = sorted(glob.glob(os.path.join(run, "util_*.json")))
    if not files:
        return None
    docs = [json.load(open(p)) for p in files]
    offsets = docs[0]["offsets"]
    avg = [sum(d["avg"][k] for d in docs) / len(docs) for k in range(len(offsets))]
    mx = [max(d["max"][k] for d in docs) for k in range(len(offsets))]
    return offsets, avg, mx, len(docs)


def main():
    runs, configs = sys.argv[1], sys.argv[2:]
    print("| run | steps | val loss (step 0 → last) | val PSNR dB (step 0 → last) | "
          "val PSNR at the lowest val loss |")
    print("|---|---:|---|---|---:|")
    for c in configs:
        s = run_summary(os.path.join(runs, c))
        print(f"| {c} | {s['steps']} | {s['first'][1]:.4f} → {s['last'][1]:.4f} | "
              f"{s['first'][2]:.2f} → {s['last'][2]:.2f} | {s['best'][2]:.2f} (step {s['best'][0]}) |")
    print()
    header = None
    for c in configs:
        u = utilization(os.path.join(runs, c))
        if u is None:
            continue
        offsets, avg, mx, n = u
        if header is None:
            cols = " | ".join(f"frame {o:+d}" for o in offsets)
            print(f"| run | | {cols} | off-centre share |")
            print("|---|---|" + "---:|" * (len(offsets) + 1))
            header = True
        off = sum(v for o, v in zip(offsets, avg) if o != 0)
        print(f"| {c} | avg | " + " | ".join(f"{v:.4f}" for v in avg) + f" | {off:.3f} |")
        print("| | max | " + " | ".join(f"{v:.4f}" for v in mx) + " | |")
    print()
    print(f"(utilisation: mean over the {n} validation scenes' frames; max over all their pixels)")


if __name__ == "__main__":
    main()
