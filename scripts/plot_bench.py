#!/usr/bin/python3
"""Draws the charts of a `diffphd bench` run from its results.csv.

Usage: plot_bench.py DIR/results.csv [--out DIR]      (PNGs go next to the CSV unless --out)

Charts, each drawn only when the CSV has rows for it (the files written are printed):

  speed_vs_accuracy_<scene>_<contrast>x.png
      One per (scene, contrast) in which some method was run at more than one tolerance.
      Left: median time per step [ms] against the error to the Newton reference on the true
      Neo-Hookean energy (max_rel_error), both log, one line per method, one marker per
      tolerance (labelled with it). Right (when present): the same against the error to a
      tight run of the same PD model (max_rel_error_same_model, i.e. solver error only).
      Hollow markers: runs in which not every step converged (or whose status is not "ok").

  stability_vs_contrast.png
      One column per scene run at more than one contrast, x = stiffness contrast (log).
      Top: fraction of steps that converged, per method, at its smallest tolerance (or at
      the rows a truthy 'default' column marks, where the CSV has one); a dotted vertical
      line marks the first contrast from which each method fails ("fails from Cx").
      Bottom: max_rel_error (log) of the same runs.

  feature_cost.png
      Rows with a non-empty 'feature' column: horizontal bars of the median time per step,
      with the mean PD iterations as text, one panel per scene.

Feature rows are left out of the first two charts. Missing columns read as empty, and
empty / nan / non-positive values are skipped on log axes, so failed runs never crash it.
"""
import argparse
import csv
import math
import os
import re
import sys
from collections import OrderedDict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402

DPI = 120
KNOWN_METHODS = ["diffphd", "pd", "newton"]
KNOWN_COLORS = {"diffphd": "tab:blue", "pd": "tab:orange", "newton": "tab:green"}
EXTRA_COLORS = ["tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan",
                "tab:gray"]
MARKERS = {"diffphd": "o", "pd": "s", "newton": "^"}
EXTRA_MARKERS = ["D", "v", "P", "X", "<", ">", "h"]


# ---------------------------------------------------------------- reading

def text(row, col):
    """The stripped string in column col ('' when the column or the value is missing)."""
    v = row.get(col)
    return v.strip() if isinstance(v, str) else ""


def num(row, col):
    """The value of column col as a float; nan when missing, empty or unparsable."""
    s = text(row, col)
    if not s:
        return math.nan
    try:
        return float(s)
    except ValueError:
        return math.nan


def finite(x):
    return isinstance(x, float) and math.isfinite(x)


def positive(x):
    """Usable on a log axis."""
    return finite(x) and x > 0


def truthy(s):
    return s.strip().lower() in ("1", "true", "yes", "y", "default")


def status_ok(row):
    s = text(row, "status").lower()
    return s in ("", "ok")


def all_converged(row):
    """True when every step converged and the run's status is ok."""
    if not status_ok(row):
        return False
    c, n = num(row, "converged_steps"), num(row, "steps")
    if finite(c) and finite(n):
        return c >= n
    return True  # nothing says otherwise


def converged_fraction(row):
    """converged_steps / steps; 0 for a failed run that reports no counts; nan if unknown."""
    c, n = num(row, "converged_steps"), num(row, "steps")
    frac = c / n if finite(c) and finite(n) and n > 0 else math.nan
    if not status_ok(row) and not finite(frac):
        return 0.0
    return frac


def read_rows(path):
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        rows = [r for r in reader if any(text(r, k) for k in (reader.fieldnames or []))]
    # "reference-*" rows are the converged reference runs themselves (diffphd bench writes them
    # so their cost and convergence are on record); they are not methods to chart.
    return [r for r in rows if not text(r, "method").startswith("reference-")]


# ---------------------------------------------------------------- formatting

def pretty_num(x):
    """1000000.0 -> '1e6', 100.0 -> '100', 1e-06 -> '1e-6', 2.5 -> '2.5'."""
    if not finite(x):
        return "nan"
    s = f"{x:g}"
    return re.sub(r"e([+-])0*(\d)", lambda m: "e" + ("-" if m.group(1) == "-" else "") + m.group(2), s)


def pretty_exp(x):
    """A tolerance or contrast for labels: below 1e-2 or from 1e4 on in exponent form ('1e-4',
    '2.5e-5', '1e6', '1.23e4'), else as pretty_num ('0.5', '100', '1000')."""
    if not positive(x) or 1e-2 <= x < 1e4:
        return pretty_num(x)
    mant, exp = f"{x:.2e}".split("e")
    mant = mant.rstrip("0").rstrip(".")
    return f"{mant}e{int(exp)}"


def file_contrast(c):
    """The contrast as it appears in a file name: integers in full, others like pretty_num."""
    if finite(c) and c == round(c) and abs(c) < 1e15:
        return str(int(round(c)))
    return pretty_num(c)


def safe_name(s):
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", s).strip("_") or "scene"


class Styles:
    """Stable colour and marker per method across all charts."""

    def __init__(self, methods):
        self.color, self.marker = {}, {}
        i = 0
        for m in methods:
            if m in KNOWN_COLORS:
                self.color[m], self.marker[m] = KNOWN_COLORS[m], MARKERS[m]
            else:
                self.color[m] = EXTRA_COLORS[i % len(EXTRA_COLORS)]
                self.marker[m] = EXTRA_MARKERS[i % len(EXTRA_MARKERS)]
                i += 1


def method_order(rows):
    present = OrderedDict((text(r, "method"), None) for r in rows)
    known = [m for m in KNOWN_METHODS if m in present]
    return known + [m for m in present if m not in KNOWN_METHODS]


def group_by(rows, *cols):
    """OrderedDict keyed by the tuple of those columns (strings), in order of first appearance."""
    out = OrderedDict()
    for r in rows:
        out.setdefault(tuple(text(r, c) for c in cols), []).append(r)
    return out


def save(fig, path, written):
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    written.append(path)


# ---------------------------------------------------------------- chart 1

def plot_speed_vs_accuracy(rows, styles, out_dir, written):
    by_pair = OrderedDict()
    for r in rows:
        scene, c = text(r, "scene"), num(r, "contrast")
        # group on the file-name form of the contrast (nan would never compare equal)
        by_pair.setdefault((scene, file_contrast(c) if finite(c) else "unknown"), (c, []))[1].append(r)

    for (scene, cname), (contrast, prow) in by_pair.items():
        by_method = group_by(prow, "method")
        multi_tol = any(len({text(r, "tolerance") for r in mr}) > 1 for mr in by_method.values())
        if not multi_tol:
            continue
        has_same = any(positive(num(r, "max_rel_error_same_model")) and
                       positive(num(r, "median_ms_per_step")) for r in prow)
        # Contact scenes have no Newton reference (the Newton baseline has no contact model):
        # no finite max_rel_error anywhere, so only the same-model panel is drawn.
        has_newton = any(positive(num(r, "max_rel_error")) for r in prow)
        panels = []
        if has_newton or not has_same:
            panels.append(("max_rel_error",
                           "max rel. error vs Newton reference (true Neo-Hookean) [-]",
                           "error to true model"))
        if has_same:
            panels.append(("max_rel_error_same_model",
                           "max rel. error vs tight run of same PD model [-]",
                           "solver error only"))
        fig, axes = plt.subplots(1, len(panels), figsize=(6.2 * len(panels), 4.8), squeeze=False)
        drawn = 0
        for ax, (col, xlabel, sub) in zip(axes[0], panels):
            shown, empty = [], []
            for m in method_order(prow):
                mrows = sorted(by_method.get((m,), []), key=lambda r: (
                    not finite(num(r, "tolerance")), num(r, "tolerance")))
                pts = [(num(r, col), num(r, "median_ms_per_step"), num(r, "tolerance"),
                        all_converged(r)) for r in mrows]
                pts = [p for p in pts if positive(p[0]) and positive(p[1])]
                if not pts:
                    if not (col == "max_rel_error_same_model" and m == "newton"):
                        empty.append(m)
                    continue
                shown.append(m)
                color, marker = styles.color[m], styles.marker[m]
                ax.plot([p[0] for p in pts], [p[1] for p in pts], "-", color=color, alpha=0.6,
                        zorder=1)
                for x, y, tol, ok in pts:
                    ax.plot([x], [y], marker=marker, linestyle="none", markersize=7,
                            markeredgecolor=color, markerfacecolor=color if ok else "none",
                            markeredgewidth=1.5, zorder=2)
                    if finite(tol):
                        ax.annotate(pretty_exp(tol), (x, y), textcoords="offset points",
                                    xytext=(5, 4), fontsize=7, color=color)
                drawn += len(pts)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.margins(0.08, 0.1)  # room for the tolerance labels
            ax.set_xlabel(xlabel)
            ax.set_ylabel("median time per step [ms]")
            ax.set_title(f"{scene}, contrast {pretty_exp(contrast)}x: {sub}", fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
            handles = [Line2D([], [], color=styles.color[m], marker=styles.marker[m], label=m)
                       for m in shown]
            handles += [Line2D([], [], color=styles.color[m], marker=styles.marker[m],
                               linestyle="none", markerfacecolor="none", alpha=0.5,
                               label=f"{m}: no finite error") for m in empty]
            handles.append(Line2D([], [], color="k", marker="o", markerfacecolor="none",
                                  linestyle="none", label="not all steps converged"))
            ax.legend(handles=handles, fontsize=8, title="labels: tolerance",
                      title_fontsize=7)
        if drawn == 0:
            plt.close(fig)
            continue
        name = f"speed_vs_accuracy_{safe_name(scene)}_{cname}x.png"
        save(fig, os.path.join(out_dir, name), written)


# ---------------------------------------------------------------- chart 2

def pick_default(rows):
    """The run that stands for a method at a contrast: the rows a truthy 'default' column marks,
    else the smallest tolerance (rows without a tolerance come last)."""
    marked = [r for r in rows if truthy(text(r, "default"))]
    cand = marked or rows
    return min(cand, key=lambda r: (not finite(num(r, "tolerance")), num(r, "tolerance")))


def plot_stability(rows, styles, out_dir, written):
    scenes = []
    for (scene,), srows in group_by(rows, "scene").items():
        contrasts = {num(r, "contrast") for r in srows if positive(num(r, "contrast"))}
        if len(contrasts) > 1:
            scenes.append((scene, srows))
    if not scenes:
        return
    n = len(scenes)
    fig, axes = plt.subplots(2, n, figsize=(6.0 * n, 7.0), squeeze=False, sharex="col")
    for j, (scene, srows) in enumerate(scenes):
        top, bot = axes[0][j], axes[1][j]
        all_c = []
        methods = method_order(srows)
        fail_labels = []
        for m in methods:
            mrows = [r for r in srows if text(r, "method") == m and positive(num(r, "contrast"))]
            by_c = OrderedDict()
            for r in mrows:
                by_c.setdefault(num(r, "contrast"), []).append(r)
            picked = sorted(((c, pick_default(rs)) for c, rs in by_c.items()), key=lambda t: t[0])
            if not picked:
                continue
            all_c += [c for c, _ in picked]
            color, marker = styles.color[m], styles.marker[m]
            fr = [(c, converged_fraction(r), status_ok(r)) for c, r in picked]
            fr_pts = [(c, f, ok) for c, f, ok in fr if finite(f)]
            if fr_pts:
                top.plot([p[0] for p in fr_pts], [p[1] for p in fr_pts], "-", marker=marker,
                         color=color, label=m)
                bad = [(c, f) for c, f, ok in fr_pts if not ok]
                if bad:
                    top.plot(*zip(*bad), "x", color="k", markersize=9, zorder=3)
            err = [(c, num(r, "max_rel_error")) for c, r in picked]
            err = [(c, e) for c, e in err if positive(e)]
            if err:
                bot.plot([p[0] for p in err], [p[1] for p in err], "-", marker=marker,
                         color=color, label=m)
            first_fail = next((c for c, f, ok in fr if not ok or (finite(f) and f < 1)), None)
            if first_fail is not None:
                for ax in (top, bot):
                    ax.axvline(first_fail, color=color, linestyle=":", linewidth=1.5)
                fail_labels.append((first_fail, m, color))
        lo = min([1.0] + all_c) / 1.6
        hi = max([1e6] + all_c) * 1.6
        for i, (c, m, color) in enumerate(fail_labels):
            # labels in the right half of the axis go to the left of their line
            right_half = math.log(c / lo) > 0.5 * math.log(hi / lo)
            top.text(c, 0.05 + 0.1 * i, f" {m} fails from {pretty_exp(c)}x ",
                     color=color, fontsize=8, ha="right" if right_half else "left",
                     va="bottom", transform=top.get_xaxis_transform(),
                     bbox=dict(facecolor="white", edgecolor="none", alpha=0.7, pad=1))
        for ax in (top, bot):
            ax.set_xscale("log")
            ax.set_xlim(lo, hi)
            ax.grid(True, which="both", alpha=0.3)
        top.set_ylim(-0.05, 1.08)
        top.set_ylabel("converged steps / steps [-]")
        top.set_title(f"{scene}: stability vs stiffness contrast\n"
                      "(smallest tolerance per method; x = failed status)", fontsize=10)
        bot.set_yscale("log")
        bot.set_ylabel("max rel. error vs Newton reference [-]")
        bot.set_xlabel("stiffness contrast max E / min E [-]")
        bot.set_title(f"{scene}: error vs stiffness contrast", fontsize=10)
        for ax in (top, bot):
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=8, loc="lower left" if ax is bot else "center left")
    save(fig, os.path.join(out_dir, "stability_vs_contrast.png"), written)


# ---------------------------------------------------------------- chart 3

def plot_feature_cost(rows, out_dir, written):
    frows = [r for r in rows if text(r, "feature")]
    if not frows:
        return
    scenes = list(group_by(frows, "scene").items())
    heights = [max(1, len(rs)) for _, rs in scenes]
    fig, axes = plt.subplots(len(scenes), 1, figsize=(8.0, 1.2 + 0.45 * sum(heights)
                                                      + 0.6 * len(scenes)),
                             squeeze=False, gridspec_kw={"height_ratios": heights})
    for ax, ((scene,), srows) in zip(axes[:, 0], scenes):
        # tell apart rows that share a feature name by the columns that differ between them
        labels = []
        for r in srows:
            same = [s for s in srows if text(s, "feature") == text(r, "feature")]
            extra = []
            for col, fmt in (("method", lambda v: v), ("contrast", lambda v: v + "x"),
                             ("tolerance", lambda v: "tol " + v)):
                if len({text(s, col) for s in same}) > 1:
                    v = text(r, col)
                    if col != "method" and finite(num(r, col)):
                        v = pretty_num(num(r, col))
                    extra.append(fmt(v))
            labels.append(text(r, "feature") + (f" ({', '.join(extra)})" if extra else ""))
        ms = [num(r, "median_ms_per_step") for r in srows]
        ys = list(range(len(srows)))[::-1]  # first row at the top
        vals = [m if finite(m) else 0.0 for m in ms]
        ax.barh(ys, vals, color="tab:blue", alpha=0.8)
        xmax = max([v for v in vals if v > 0] + [1e-9])
        for y, r, m, v in zip(ys, srows, ms, vals):
            it = num(r, "mean_iterations")
            if finite(m):
                s = f" {m:.3g} ms"
                if finite(it):
                    s += f", {it:.3g} it"
            else:
                st = text(r, "status") or "no time"
                s = f" {st}"
            if not status_ok(r) and finite(m):
                s += f" [{text(r, 'status')}]"
            ax.text(v, y, s, va="center", fontsize=8)
        ax.set_yticks(ys)
        ax.set_yticklabels(labels, fontsize=8)
        ax.set_xlim(0, xmax * 1.35)
        ax.set_xlabel("median time per step [ms]")
        cs = {text(r, "contrast") for r in srows}
        ctitle = ""
        if len(cs) == 1:
            c = num(srows[0], "contrast")
            ctitle = f", contrast {pretty_exp(c)}x" if finite(c) else ""
        ax.set_title(f"{scene}{ctitle}: cost per feature (text: mean PD iterations)",
                     fontsize=10)
        ax.grid(True, axis="x", alpha=0.3)
    save(fig, os.path.join(out_dir, "feature_cost.png"), written)


# ---------------------------------------------------------------- main

def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("csv", help="results.csv written by `diffphd bench`")
    ap.add_argument("--out", help="directory for the PNGs (default: the CSV's directory)")
    args = ap.parse_args(argv)
    if not os.path.isfile(args.csv):
        sys.exit(f"plot_bench: {args.csv}: no such file")
    out_dir = args.out or os.path.dirname(os.path.abspath(args.csv))
    os.makedirs(out_dir, exist_ok=True)
    rows = read_rows(args.csv)
    if not rows:
        print(f"plot_bench: {args.csv}: no rows, no charts written")
        return 0
    styles = Styles(method_order(rows))
    plain = [r for r in rows if not text(r, "feature")]
    written = []
    plot_speed_vs_accuracy(plain, styles, out_dir, written)
    plot_stability(plain, styles, out_dir, written)
    plot_feature_cost(rows, out_dir, written)
    if not written:
        print("plot_bench: no rows for any chart, no charts written")
    for p in written:
        print(f"plot_bench: wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
