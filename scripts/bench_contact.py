#!/usr/bin/env python3
"""Napkin-on-sphere contact benchmark: per-step forward time and PD iterations against the
fraction of vertices in contact (docs/benchmarks-contact.md).

Runs `diffphd run` on the shipped 25x25 napkin scenes (scenes/napkin_sphere_*.json) and on 50x50
copies of them (written to OUT/scenes/, cells [50, 50]), reads each run's stats.csv and writes
OUT/results-contact-SIZES.csv (one row per scene) and, with matplotlib,
OUT/contact_napkin_SIZES.png (SIZES: the --sizes list, e.g. 25_50).

Usage: scripts/bench_contact.py [--diffphd build/examples/diffphd] [--out bench/contact]
       [--frames 60] [--frames-50 20] [--sizes 25,50] [--timeout 1800]
"""
import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ["napkin_sphere_06", "napkin_sphere_24", "napkin_sphere_38", "napkin_sphere_50",
          "napkin_sphere_hetero"]


def scene_for(name, size, out):
    path = os.path.join(ROOT, "scenes", name + ".json")
    if size == 25:
        return path, name
    with open(path) as f:
        s = json.load(f)
    s["mesh"]["cells"] = [size, size]
    s["name"] = "%s_%dx%d" % (name, size, size)
    os.makedirs(os.path.join(out, "scenes"), exist_ok=True)
    p = os.path.join(out, "scenes", s["name"] + ".json")
    with open(p, "w") as f:
        json.dump(s, f, indent=1)
    return p, s["name"]


def summarise(stats_path, vertices):
    rows = list(csv.DictReader(open(stats_path)))
    t = [float(r["seconds"]) for r in rows]
    it = [int(r["iterations"]) for r in rows]
    frac = [float(r["contact_fraction"]) for r in rows]
    contact_rows = [r for r in rows if int(r["contact_points"]) > 0]
    tc = [float(r["seconds"]) for r in contact_rows]
    return {
        "steps": len(rows),
        "converged_steps": sum(int(r["converged"]) for r in rows),
        "median_step_seconds": statistics.median(t) if t else 0,
        "median_step_seconds_with_contact": statistics.median(tc) if tc else 0,
        "mean_iterations": sum(it) / len(it) if it else 0,
        "max_contact_fraction": max(frac) if frac else 0,
        "final_contact_fraction": frac[-1] if frac else 0,
        "final_active": int(rows[-1]["contact_active"]) if rows else 0,
        "max_worst_penetration": max(float(r["worst_penetration"]) for r in rows) if rows else 0,
        "max_complementarity": max(float(r["complementarity"]) for r in rows) if rows else 0,
        "max_cone_violation": max(float(r["cone_violation"]) for r in rows) if rows else 0,
        "ncp_lu": sum(int(r["ncp_lu"]) for r in rows),
        "ncp_cholesky": sum(int(r["ncp_ldlt"]) for r in rows),
        "ncp_krylov": sum(int(r.get("ncp_krylov", 0) or 0) for r in rows),
        "ncp_krylov_iterations": sum(int(r.get("ncp_krylov_iterations", 0) or 0) for r in rows),
        "seconds_ncp": sum(float(r["seconds_ncp"]) for r in rows),
        "seconds_delassus": sum(float(r["seconds_delassus"]) for r in rows),
        "seconds_total": sum(t),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--diffphd", default=os.path.join(ROOT, "build", "examples", "diffphd"))
    # (a relative --diffphd or --out is taken from the current directory)
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "contact"))
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--frames-50", type=int, default=20)
    ap.add_argument("--sizes", default="25,50")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--timeout", type=float, default=1800)
    a = ap.parse_args()
    a.diffphd = os.path.abspath(a.diffphd)
    a.out = os.path.abspath(a.out)
    os.makedirs(a.out, exist_ok=True)
    results = []
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    for size in [int(s) for s in a.sizes.split(",")]:
        for name in a.scenes.split(","):
            path, label = scene_for(name, size, a.out)
            frames = a.frames if size == 25 else a.frames_50
            run_dir = os.path.join(a.out, label)
            # Paths relative to the repository (run from it): the summaries name no machine path.
            cmd = [a.diffphd, "run", os.path.relpath(path, ROOT), "--out",
                   os.path.relpath(run_dir, ROOT), "--no-frames", "--frames", str(frames), "--json"]
            print("bench_contact: " + " ".join(cmd), file=sys.stderr, flush=True)
            t0 = time.time()
            try:
                p = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT,
                                   timeout=a.timeout)
                status = "ok" if p.returncode == 0 else "exit %d" % p.returncode
                summary = json.loads(p.stdout) if p.returncode == 0 else {}
            except subprocess.TimeoutExpired:
                status, summary = "timeout", {}
            row = {"scene": label, "size": size, "frames": frames, "status": status,
                   "wall_seconds": round(time.time() - t0, 2),
                   "vertices": summary.get("vertices", "")}
            stats = os.path.join(run_dir, "stats.csv")
            if os.path.exists(stats) and os.path.getsize(stats) > 0:
                row.update(summarise(stats, summary.get("vertices")))
            results.append(row)
            print("  " + json.dumps(row), file=sys.stderr, flush=True)
    keys = []
    for r in results:
        for k in r:
            if k not in keys:
                keys.append(k)
    tag = a.sizes.replace(",", "_")
    out_csv = os.path.join(a.out, "results-contact-%s.csv" % tag)
    with open(out_csv, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(results)
    print("bench_contact: wrote " + out_csv, file=sys.stderr)
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for size, marker in ((25, "o"), (50, "s")):
        rs = [r for r in results if r["size"] == size and "max_contact_fraction" in r]
        for het, color in ((False, "C0"), (True, "C3")):
            sel = [r for r in rs if ("hetero" in r["scene"]) == het]
            if not sel:
                continue
            x = [100 * r["max_contact_fraction"] for r in sel]
            lab = "%dx%d%s" % (size, size, " hetero" if het else "")
            ax[0].plot(x, [1e3 * r["median_step_seconds_with_contact"] for r in sel], marker,
                       color=color, label=lab)
            ax[1].plot(x, [r["mean_iterations"] for r in sel], marker, color=color, label=lab)
    ax[0].set_xlabel("vertices in contact (%)")
    ax[0].set_ylabel("median forward ms / step (steps with contact)")
    ax[0].set_yscale("log")
    ax[1].set_xlabel("vertices in contact (%)")
    ax[1].set_ylabel("mean PD iterations / step")
    for x in ax:
        x.legend()
        x.grid(alpha=0.3)
    fig.tight_layout()
    png = os.path.join(a.out, "contact_napkin_%s.png" % tag)
    fig.savefig(png, dpi=110)
    print("bench_contact: wrote " + png, file=sys.stderr)


if __name__ == "__main__":
    main()
