#!/usr/bin/env python3
"""Per-step forward time and PD iterations against the fraction of vertices in contact, from the
stats.csv files of `diffphd run` on the napkin scenes (docs/benchmarks-contact.md).

Usage: scripts/plot_contact.py [--root bench/contact] [--out docs/img/contact_napkin.png]
Every ROOT/<run>/stats.csv with contact columns is one series; a run whose name ends in _50x50
is the 50 x 50 sheet, one containing "hetero" the heterogeneous napkin. Steps without active
contacts are left out.
"""
import argparse
import csv
import glob
import os
import sys


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default="bench/contact")
    ap.add_argument("--out", default="docs/img/contact_napkin.png")
    a = ap.parse_args()
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("plot_contact: matplotlib is not installed", file=sys.stderr)
        return 1
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    markers = {False: "o", True: "s"}
    n = 0
    for path in sorted(glob.glob(os.path.join(a.root, "*", "stats.csv"))):
        name = os.path.basename(os.path.dirname(path))
        if not name.startswith("napkin"):
            continue
        with open(path) as f:
            rows = [r for r in csv.DictReader(f)]
        if not rows or "contact_fraction" not in rows[0]:
            continue
        rows = [r for r in rows if int(r["contact_active"]) > 0]
        if not rows:
            continue
        big = name.endswith("_50x50")
        x = [100 * float(r["contact_fraction"]) for r in rows]
        ax[0].plot(x, [float(r["seconds"]) for r in rows], markers[big], markersize=4,
                   alpha=0.75, label=name)
        ax[1].plot(x, [int(r["iterations"]) for r in rows], markers[big], markersize=4,
                   alpha=0.75, label=name)
        n += 1
    ax[0].set_yscale("log")
    ax[0].set_ylabel("forward seconds / step")
    ax[1].set_ylabel("PD iterations / step")
    for s in ax:
        s.set_xlabel("vertices in contact (%)")
        s.grid(alpha=0.3, which="both")
    ax[1].legend(fontsize=7, ncol=2)
    fig.suptitle("napkin on a sphere: circles 25 x 25 (1352 vertices), squares 50 x 50 (5202)",
                 fontsize=10)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
    fig.savefig(a.out, dpi=110)
    print("plot_contact: wrote %s (%d runs)" % (a.out, n), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
