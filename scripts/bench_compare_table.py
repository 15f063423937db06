#!/usr/bin/env python3
"""Prints the comparison table of docs/research/benchmarks.md from scripts/bench-compare's rows.jsonl:
one block for the shipped sample and one for the held-aside test scenes (means over scenes)."""
import json
import sys
from collections import OrderedDict

LEVELS = ["low", "half", "high", "spp0064", "spp0128"]
METHODS = ["noisy", "classic", "oidn", "oidn, noisy aux", "tkpcn", "previous default", "radn", "radn, 2 passes", "guided"]


def main():
    rows = [json.loads(line) for line in open(sys.argv[1]) if line.strip()]
    groups = OrderedDict()
    for r in rows:
        g = "sample" if r["seq"] == "sample" else r.get("split", "test") + " scenes"
        groups.setdefault(g, OrderedDict()).setdefault((r["level"], r["method"]), []).append(r)
    for g, cells in groups.items():
        n = len({r["seq"] for rs in cells.values() for r in rs})
        print(f"**{g}** ({n} sequence{'s' if n > 1 else ''})\n")
        print("| level | method | PSNR (dB) | SSIM | relMSE | tMAE | speed (MP/s) |")
        print("|---|---|---:|---:|---:|---:|---:|")
        order = lambda k: (LEVELS.index(k[0]) if k[0] in LEVELS else 9,
                           METHODS.index(k[1]) if k[1] in METHODS else 9, k)
        for (level, method), rs in sorted(cells.items(), key=lambda kv: order(kv[0])):
            mean = lambda k: sum(r[k] for r in rs if r[k] is not None) / max(
                1, sum(1 for r in rs if r[k] is not None))
            secs = sum(r["seconds"] for r in rs)
            mp = sum(r["frames"] * r["pixels"] for r in rs) / 1e6
            speed = f"{mp / secs:.3f}" if secs > 0 else "-"
            print(f"| {level} | {method} | {mean('psnr'):.2f} | {mean('ssim'):.4f} | "
                  f"{mean('relmse'):.4f} | {mean('tmae'):.4f} | {speed} |")
        print()


if __name__ == "__main__":
    main()
