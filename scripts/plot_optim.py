#!/usr/bin/python3
"""Optimisation curves of `diffphd optimize --out DIR` results: loss against evaluation.

usage: scripts/plot_optim.py DIR [DIR ...] --out docs/img
Reads every DIR/*.json written by `diffphd optimize --out DIR` and draws one chart per task,
optim_<task>.png (log loss against evaluation), plus optim_all.png with every task normalised by
its initial loss.
"""
import argparse
import glob
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def load(dirs):
    results = []
    for d in dirs:
        for path in sorted(glob.glob(os.path.join(d, "*.json"))):
            with open(path) as f:
                j = json.load(f)
            if "history" not in j or "task" not in j:
                continue
            results.append(j)
    return results


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="+")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    results = load(a.dirs)
    if not results:
        sys.exit("plot_optim.py: no optimize results (*.json with a history) in " + ", ".join(a.dirs))
    os.makedirs(a.out, exist_ok=True)
    fig_all, ax_all = plt.subplots(figsize=(6, 4))
    for j in results:
        ev = [h["evaluation"] for h in j["history"]]
        loss = [h["loss"] for h in j["history"]]
        best = []
        for v in loss:
            best.append(v if not best else min(best[-1], v))
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.semilogy(ev, loss, "o", ms=3, alpha=0.5, label="evaluated")
        ax.semilogy(ev, best, "-", label="best so far")
        ax.set_xlabel("evaluation (forward + backward)")
        ax.set_ylabel("loss")
        ax.set_title("%s: %.3g -> %.3g (%s)" % (j["task"], j["initial_loss"], j["final_loss"],
                                                j["stop_reason"]), fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
        fig.tight_layout()
        out = os.path.join(a.out, "optim_%s.png" % j["task"])
        fig.savefig(out, dpi=110)
        plt.close(fig)
        print("wrote", out)
        ax_all.semilogy(ev, [b / best[0] for b in best], "-", label=j["task"])
    ax_all.set_xlabel("evaluation")
    ax_all.set_ylabel("best loss / initial loss")
    ax_all.grid(True, which="both", alpha=0.3)
    ax_all.legend(fontsize=8)
    fig_all.tight_layout()
    out = os.path.join(a.out, "optim_all.png")
    fig_all.savefig(out, dpi=110)
    print("wrote", out)


if __name__ == "__main__":
    main(sys.argv[1:])
