#!/usr/bin/python3
"""Forward-solver benchmark: PD iterations and time per step for the plain-PD baseline
(Anderson off) and bounded Anderson with m = 1 and m = 5, over stiffness contrasts, on the
shipped cantilever and Armadillo twist scenes. All configurations run in this one invocation,
on the same machine, and the table reports each one against plain PD at the same contrast.

usage: bench/bench_forward.py [--cli build/examples/diffphd] [--out bench/results-forward]
                              [--contrasts 1,10,100,1000,10000] [--windows 0,1,5]
                              [--cantilever-frames 60] [--armadillo-frames 10] [--quick]
                              [--only cantilever|armadillo] [--gate paper|step-relative]
Writes OUT.csv and OUT.json, and prints a Markdown table (docs/benchmarks-forward.md keeps it).
"""
import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile


def run(cli, scene, contrast, window, frames, gate=None):
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [cli, "run", scene, "--contrast", str(contrast), "--anderson", str(window),
               "--frames", str(frames), "--no-frames", "--json", "--out", tmp]
        if gate:
            cmd += ["--gate", gate]
        env = dict(os.environ, OPENBLAS_NUM_THREADS=os.environ.get("OPENBLAS_NUM_THREADS", "1"))
        p = subprocess.run(cmd, capture_output=True, text=True, env=env)
        if p.returncode not in (0, 3):
            sys.exit(f"bench_forward: {' '.join(cmd)} failed ({p.returncode}):\n{p.stderr}")
        j = json.loads(p.stdout.strip().splitlines()[-1])
        with open(os.path.join(tmp, "stats.csv")) as f:
            rows = list(csv.DictReader(f))
        secs = sorted(float(r["seconds"]) for r in rows)
        j["median_ms_per_step"] = 1e3 * secs[len(secs) // 2] if secs else float("nan")
        its = sorted(int(r["iterations"]) for r in rows)
        j["median_iterations"] = its[len(its) // 2] if its else 0
        j["scene_file"] = scene
        j["window"] = window
        j["contrast_factor"] = contrast
        return j


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cli", default="build/examples/diffphd")
    ap.add_argument("--out", default="bench/results-forward")
    ap.add_argument("--contrasts", default="1,10,100,1000,10000")
    ap.add_argument("--windows", default="0,1,5")
    ap.add_argument("--cantilever-frames", type=int, default=60)
    ap.add_argument("--armadillo-frames", type=int, default=10)
    ap.add_argument("--quick", action="store_true", help="cantilever only, 10 frames")
    ap.add_argument("--only", choices=["cantilever", "armadillo"], help="run one scene only")
    ap.add_argument("--gate", choices=["paper", "step-relative"], help="dual-gate scale")
    a = ap.parse_args()
    contrasts = [float(c) for c in a.contrasts.split(",")]
    windows = [int(m) for m in a.windows.split(",")]
    scenes = [("scenes/cantilever_twist.json", 10 if a.quick else a.cantilever_frames)]
    if not a.quick:
        scenes.append(("scenes/armadillo_twist.json", a.armadillo_frames))
    if a.only:
        scenes = [s for s in scenes if a.only in s[0]]
    results = []
    for scene, frames in scenes:
        for c in contrasts:
            for m in windows:
                j = run(a.cli, scene, c, m, frames, a.gate)
                results.append(j)
                print(f"{j['name']:18s} contrast {c:>7g}x m={m}: {j['mean_iterations']:7.1f} it/step "
                      f"(max {j['max_iterations']}), {j['median_ms_per_step']:8.2f} ms/step, "
                      f"{j['converged_steps']}/{j['steps']} converged, min det F {j['min_jacobian']:.3f}",
                      file=sys.stderr, flush=True)
    keys = ["name", "contrast", "window", "anderson_window", "steps", "converged_steps",
            "mean_iterations", "median_iterations", "max_iterations", "aa_resets",
            "median_ms_per_step", "seconds_per_step", "min_jacobian", "vertices", "elements",
            "eps_rel", "gate", "h"]
    os.makedirs(os.path.dirname(a.out) or ".", exist_ok=True)
    with open(a.out + ".csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(results)
    with open(a.out + ".json", "w") as f:
        json.dump(results, f, indent=1)
    base = {(r["name"], r["contrast_factor"]): r for r in results if r["window"] == 0}
    print("| scene | contrast | method | mean it/step | max it | converged | median ms/step | "
          "it vs plain | total time vs plain | min det F |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in results:
        b = base.get((r["name"], r["contrast_factor"]))
        name = "plain PD" if r["window"] == 0 else f"Anderson m={r['window']}"
        it_ratio = r["mean_iterations"] / b["mean_iterations"] if b and b["mean_iterations"] else float("nan")
        t_ratio = r["seconds_per_step"] / b["seconds_per_step"] if b and b["seconds_per_step"] else float("nan")
        print(f"| {r['name']} | {r['contrast']:g}x | {name} | {r['mean_iterations']:.1f} | "
              f"{r['max_iterations']} | {r['converged_steps']}/{r['steps']} | "
              f"{r['median_ms_per_step']:.2f} | {it_ratio:.2f} | {t_ratio:.2f} | "
              f"{r['min_jacobian']:.3f} |")


if __name__ == "__main__":
    main()
