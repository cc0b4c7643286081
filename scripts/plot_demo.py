#!/usr/bin/python3
"""Draws the chart of a `diffphd run` from its stats.csv: the largest displacement over time,
and the iterations each step needed (local-global or Newton, by the step's method) (with the steps that did not converge marked)."""
import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main(stats_path: str, png_path: str, title: str) -> None:
    with open(stats_path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        sys.exit(f"{stats_path}: no rows")
    t = [float(r["time"]) for r in rows]
    umax = [float(r["max_displacement"]) for r in rows]
    its = [int(r["iterations"]) for r in rows]
    bad = [(ti, it) for ti, it, r in zip(t, its, rows) if r["converged"] != "1"]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    ax1.plot(t, umax)
    ax1.set_ylabel("max |displacement| [m]")
    ax1.set_title(title, fontsize=10)
    ax1.grid(True, alpha=0.3)
    method = rows[0].get("method", "pd") if rows else "pd"
    ax2.plot(t, its, drawstyle="steps-mid", label=f"{method} iterations per step")
    if bad:
        ax2.plot(*zip(*bad), "rx", label="did not converge")
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("iterations")
    ax2.grid(True, alpha=0.3)
    ax2.legend()
    fig.tight_layout()
    fig.savefig(png_path, dpi=120)
    print(f"plot_demo: wrote {png_path}")


if __name__ == "__main__":
    if len(sys.argv) not in (3, 4):
        sys.exit("usage: plot_demo.py STATS_CSV OUT_PNG [TITLE]")
    main(sys.argv[1], sys.argv[2], sys.argv[3] if len(sys.argv) == 4 else "diffphd run")
