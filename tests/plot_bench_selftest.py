#!/usr/bin/python3
"""Self-test of scripts/plot_bench.py on a synthetic results.csv (no diffphd build needed).

Writes a fake bench result (2 scenes x 3 methods x 3 tolerances x contrasts 1..1e6, with nan
and empty errors, a method that fails from contrast 1e4 on, and feature-cost rows) into a temp
dir, runs plot_bench.py on it, and checks the expected PNGs exist and are PNGs. Then runs it on
a CSV that lacks several columns, and on one with a header only, which must not crash either.
Exit 0 on success, 1 with a message otherwise.
"""
import csv
import math
import os
import random
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPT = os.path.join(HERE, "..", "scripts", "plot_bench.py")
PYTHON = "/usr/bin/python3" if os.path.exists("/usr/bin/python3") else sys.executable

COLUMNS = ["scene", "contrast", "method", "tolerance", "frames", "steps", "converged_steps",
           "mean_iterations", "max_iterations", "median_ms_per_step", "total_seconds",
           "max_rel_error", "max_rel_error_same_model", "min_jacobian", "status", "feature"]
SCENES = ["cantilever", "two material cube"]  # the space tests file-name sanitising
CONTRASTS = [1, 10, 100, 1e3, 1e4, 1e5, 1e6]
TOLS = {"diffphd": [1e-3, 1e-5, 1e-7], "pd": [1e-3, 1e-5, 1e-7], "newton": [1e-4, 1e-6, 1e-8]}
FEATURES = ["corotated+volume", "neo-hookean", "neo-hookean+logvolume", "damping on",
            "damping off", "anderson 0", "anderson 1", "anderson 5"]


def fake_rows():
    rng = random.Random(1)
    rows = []
    frames, steps = 50, 200
    for scene in SCENES:
        for c in CONTRASTS:
            lc = math.log10(c)
            for method, tols in TOLS.items():
                for tol in tols:
                    r = dict(scene=scene, contrast=f"{c:g}", method=method, tolerance=f"{tol:g}",
                             frames=frames, steps=steps, feature="", status="ok")
                    conv = steps
                    if method == "pd" and c >= 1e4:          # fails from 1e4x on
                        conv = rng.randint(0, steps - 1)
                        if c >= 1e5:
                            r["status"] = "non-finite"
                    if method == "diffphd" and c >= 1e6 and tol < 1e-6:  # hardest: a few misses
                        conv = steps - 3
                    r["converged_steps"] = conv
                    its = {"diffphd": 8, "pd": 30, "newton": 4}[method] * (1 + lc / 3) \
                        * (1 + 0.3 * math.log10(1e-3 / tol if method != "newton" else 1e-4 / tol))
                    r["mean_iterations"] = f"{its:.2f}"
                    r["max_iterations"] = int(its * 2)
                    ms = {"diffphd": 2.0, "pd": 1.5, "newton": 25.0}[method] * its / 8
                    r["median_ms_per_step"] = f"{ms:.4f}"
                    r["total_seconds"] = f"{ms * steps / 1000:.4f}"
                    model = 0.0 if method == "newton" else 0.02 * (1 + lc / 6)
                    err = model + tol * 10 ** (lc / 2) * rng.uniform(0.5, 2)
                    same = "nan" if method == "newton" else f"{tol * rng.uniform(0.5, 2):.3e}"
                    if r["status"] != "ok":
                        err, same = float("nan"), ""
                    if rng.random() < 0.05:                 # a few failed error measurements
                        err = float("nan")
                    r["max_rel_error"] = "nan" if math.isnan(err) else f"{err:.3e}"
                    r["max_rel_error_same_model"] = same
                    r["min_jacobian"] = "" if r["status"] != "ok" else f"{rng.uniform(0.2, 1):.3f}"
                    rows.append(r)
    for scene in SCENES:
        for feat in FEATURES:
            ms = rng.uniform(1, 10)
            rows.append(dict(scene=scene, contrast="1000", method="diffphd", tolerance="1e-05",
                             frames=frames, steps=steps, converged_steps=steps,
                             mean_iterations=f"{rng.uniform(5, 40):.1f}",
                             max_iterations=60, median_ms_per_step=f"{ms:.3f}",
                             total_seconds=f"{ms * steps / 1000:.3f}", max_rel_error="",
                             max_rel_error_same_model="", min_jacobian="0.5", status="ok",
                             feature=feat))
    # a failed feature run: no time at all
    rows.append(dict(scene=SCENES[0], contrast="1000", method="pd", tolerance="1e-05",
                     frames=frames, steps=steps, converged_steps=0, mean_iterations="nan",
                     max_iterations=0, median_ms_per_step="nan", total_seconds="",
                     max_rel_error="nan", max_rel_error_same_model="nan", min_jacobian="",
                     status="non-finite", feature="anderson 5"))
    return rows


def write_csv(path, rows, columns):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(r)


def run(args):
    p = subprocess.run([PYTHON, SCRIPT] + args, capture_output=True, text=True)
    sys.stdout.write(p.stdout)
    sys.stderr.write(p.stderr)
    return p


def check_pngs(out_dir, names):
    bad = []
    for n in names:
        p = os.path.join(out_dir, n)
        if not os.path.isfile(p) or os.path.getsize(p) == 0:
            bad.append(f"{n}: missing or empty")
            continue
        with open(p, "rb") as f:
            if f.read(8) != b"\x89PNG\r\n\x1a\n":
                bad.append(f"{n}: not a PNG")
    return bad


def main():
    failures = []
    with tempfile.TemporaryDirectory(prefix="plot_bench_selftest_") as tmp:
        rows = fake_rows()

        # 1. the full CSV, PNGs next to it
        full = os.path.join(tmp, "full")
        os.makedirs(full)
        write_csv(os.path.join(full, "results.csv"), rows, COLUMNS)
        p = run([os.path.join(full, "results.csv")])
        if p.returncode != 0:
            failures.append(f"full CSV: exit code {p.returncode}")
        expected = ["stability_vs_contrast.png", "feature_cost.png"]
        for scene in SCENES:
            for c in CONTRASTS:
                expected.append(f"speed_vs_accuracy_{scene.replace(' ', '_')}_{int(c)}x.png")
        failures += [f"full CSV: {b}" for b in check_pngs(full, expected)]
        extra = sorted(set(f for f in os.listdir(full) if f.endswith(".png")) - set(expected))
        if extra:
            failures.append(f"full CSV: unexpected files {extra}")
        for n in expected:
            if n not in p.stdout:
                failures.append(f"full CSV: {n} not reported as written")

        # 2. columns missing (no same-model error, no feature, no converged_steps), --out DIR
        cols = [c for c in COLUMNS if c not in ("max_rel_error_same_model", "feature",
                                                 "converged_steps", "min_jacobian")]
        src = os.path.join(tmp, "missing", "results.csv")
        os.makedirs(os.path.dirname(src))
        write_csv(src, [r for r in rows if not r["feature"]], cols)
        out = os.path.join(tmp, "missing", "charts")
        p = run([src, "--out", out])
        if p.returncode != 0:
            failures.append(f"missing columns: exit code {p.returncode}")
        exp2 = ["stability_vs_contrast.png",
                f"speed_vs_accuracy_{SCENES[0]}_1000000x.png"]
        failures += [f"missing columns: {b}" for b in check_pngs(out, exp2)]
        if os.path.exists(os.path.join(out, "feature_cost.png")):
            failures.append("missing columns: feature_cost.png drawn without feature rows")

        # 3. header only: no charts, no crash
        hdr = os.path.join(tmp, "empty", "results.csv")
        os.makedirs(os.path.dirname(hdr))
        write_csv(hdr, [], COLUMNS)
        p = run([hdr])
        if p.returncode != 0:
            failures.append(f"header-only CSV: exit code {p.returncode}")
        if any(f.endswith(".png") for f in os.listdir(os.path.dirname(hdr))):
            failures.append("header-only CSV: PNGs written")

        # 4. one tolerance per method, one contrast: no speed/stability chart, no crash
        one = os.path.join(tmp, "one", "results.csv")
        os.makedirs(os.path.dirname(one))
        write_csv(one, [r for r in rows if r["contrast"] == "1000" and not r["feature"]
                        and r["tolerance"] in ("1e-05", "1e-06")], COLUMNS)
        p = run([one])
        if p.returncode != 0:
            failures.append(f"single-tolerance CSV: exit code {p.returncode}")
        if any(f.endswith(".png") for f in os.listdir(os.path.dirname(one))):
            failures.append("single-tolerance CSV: PNGs written")

    if failures:
        print("plot_bench_selftest: FAILED")
        for f in failures:
            print("  " + f)
        return 1
    print(f"plot_bench_selftest: OK ({len(expected)} charts from the full CSV)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
