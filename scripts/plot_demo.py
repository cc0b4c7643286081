#!/usr/bin/python3
"""Draws the demo chart from stats.csv: tip deflection and max displacement over time."""
import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main(stats_path: str, png_path: str) -> None:
    with open(stats_path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        sys.exit(f"{stats_path}: no rows")
    t = [float(r["time"]) for r in rows]
    tip = [float(r["tip_deflection_y"]) for r in rows]
    umax = [float(r["max_displacement"]) for r in rows]
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(t, tip, label="tip deflection (y)")
    ax.plot(t, umax, "--", label="max |displacement|")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("[m]")
    ax.set_title("three-segment cantilever (middle 10x stiffer) under gravity", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(png_path, dpi=120)
    print(f"plot_demo: wrote {png_path}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: plot_demo.py STATS_CSV OUT_PNG")
    main(sys.argv[1], sys.argv[2])
