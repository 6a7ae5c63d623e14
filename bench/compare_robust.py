#!/usr/bin/env python3
"""Robust kernels against Ceres 2.1: the same problem, start, kernel and iteration cap in both.

For every case the script runs dynamap's binary (bundle_adjustment or pose_graph) and Ceres
(bench/ceres_robust.cc, built on first use against Debian's libceres-dev), and prints the final
costs, their relative difference, the times, and whether ours is at most Ceres' plus 1e-6 relative
(issue 22's target). With --curves it writes every case's per-iteration costs as JSON.

The suite (generated into --work, seeds from --seed):
- Ladybug 49 (../shared/data/bal/problem-49-7776-pre.txt) under huber:1 and cauchy:1;
- generated bundle adjustments (generate_problem bal: 2 % outliers, 1 px noise) of 50, 200 and
  1000 cameras under huber:2 and cauchy:2;
- pose graphs with 5 % wrong loop closures (generate_problem pose-graph): a planar circle, a
  sphere, and the real intel and sphere2500 graphs, under dcs:1 and cauchy:1, with our dogleg
  (pose_graph's default) and our Levenberg-Marquardt.

usage: python3 bench/compare_robust.py [--seed 3] [--work DIR] [--curves OUT.json]
                                       [--quick] [--max-iterations 50]
Needs `cargo build --release -p dynamap-apps` (the binaries in target/release/).
"""
import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data"
BIN = ROOT / "target" / "release"
PEERS = pathlib.Path(os.environ.get("PEERS_VENV", pathlib.Path.home() / ".cache" / "dynamap-peers")) / "bin"
TOLERANCE = 1e-6


def ceres_binary():
    exe = PEERS / "ceres_robust"
    src = ROOT / "bench" / "ceres_robust.cc"
    if not exe.exists() or exe.stat().st_mtime < src.stat().st_mtime:
        PEERS.mkdir(parents=True, exist_ok=True)
        subprocess.run(["g++", "-O3", "-DNDEBUG", "-march=native", "-std=c++17", str(src), "-o", str(exe),
                        "-I/usr/include/eigen3", "-lceres", "-lglog", "-lgflags", "-lpthread"], check=True)
    return exe


def last_json(cmd):
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def generate(work, seed, quick):
    work.mkdir(parents=True, exist_ok=True)
    gen = str(BIN / "generate_problem")
    cases = []
    ladybug = DATA / "bal" / "problem-49-7776-pre.txt"
    if ladybug.exists():
        for k in ["huber:1", "cauchy:1"]:
            cases.append(("bal", ladybug, k, "ladybug-49"))
    for n in [50, 200] if quick else [50, 200, 1000]:
        path = work / f"bal-{n}-s{seed}.txt"
        if not path.exists():
            last_json([gen, "bal", str(path), "--cameras", str(n), "--outliers", "0.02", "--seed", str(seed), "-q"])
        for k in ["huber:2", "cauchy:2"]:
            cases.append(("bal", path, k, f"bal-{n}"))
    graphs = [("circle", ["--shape", "circle", "--rings", "10", "--per-ring", "100"], 50),
              ("sphere", ["--shape", "sphere", "--rings", "20", "--per-ring", "50"], 50)]
    for name, edges in [("intel", 75), ("sphere2500", 250)]:
        if (DATA / "posegraph" / f"{name}.g2o").exists() and not quick:
            graphs.append((name, ["--from", str(DATA / "posegraph" / f"{name}.g2o")], edges))
    for name, flags, loops in graphs:
        path = work / f"pg-{name}-s{seed}.g2o"
        if not path.exists():
            last_json([gen, "pose-graph", str(path), *flags, "--false-loops", str(loops), "--seed", str(seed), "-q"])
        for k in ["dcs:1", "cauchy:1"]:
            cases.append(("g2o", path, k, f"{name}+{loops} wrong loops"))
    return cases


def run_case(kind, path, kernel, cap, ceres):
    if kind == "bal":
        big = "1000" in path.name
        ours_solver, ceres_solver = ("schur-sparse", "sparse_schur") if big else ("schur-dense", "dense_schur")
        ours = [last_json([str(BIN / "bundle_adjustment"), str(path), "--kernel", kernel, "--threads", "2",
                           "--max-iterations", str(cap), "--linear-solver", ours_solver, "-q"])]
        labels = [f"LM {ours_solver}"]
        theirs = last_json([str(ceres), "bal", str(path), "--loss", kernel, "--threads", "2",
                            "--max-iterations", str(cap), "--linear-solver", ceres_solver])
    else:
        ours, labels = [], []
        for algorithm in ["dogleg", "lm"]:
            ours.append(last_json([str(BIN / "pose_graph"), str(path), "--kernel", kernel, "--algorithm", algorithm,
                                   "--threads", "2", "--max-iterations", str(cap), "-q"]))
            labels.append(algorithm)
        theirs = last_json([str(ceres), "g2o", str(path), "--loss", kernel, "--threads", "2",
                            "--max-iterations", str(cap)])
    return ours, labels, theirs


def print_curves(curves, columns):
    """The cost after selected iterations, ours over Ceres', a row per problem and kernel (the first
    of our variants); a solve that stopped earlier shows its last cost."""
    shown = {}
    for c in curves:
        shown.setdefault((c["problem"], c["kernel"]), c)
    print()
    print("| problem | kernel | " + " | ".join(f"it {i}" for i in columns) + " |")
    print("|---|---|" + "---|" * len(columns))
    for (problem, kernel), c in shown.items():
        cells = []
        for i in columns:
            o, t = c["ours_costs"], c["ceres_costs"]
            cells.append(f"{o[min(i, len(o) - 1)]:.8g} / {t[min(i, len(t) - 1)]:.8g}")
        print(f"| {problem} | {kernel} | " + " | ".join(cells) + " |")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--work", type=pathlib.Path, default=pathlib.Path("/tmp/dynamap-robust"))
    ap.add_argument("--curves", type=pathlib.Path)
    ap.add_argument("--quick", action="store_true", help="skip the 1000-camera problem and the real graphs")
    ap.add_argument("--max-iterations", type=int, default=50)
    args = ap.parse_args()
    ceres = ceres_binary()
    cases = generate(args.work, args.seed, args.quick)
    print(f"# robust kernels against Ceres, seed {args.seed}, {args.max_iterations} iterations, "
          f"{time.strftime('%Y-%m-%d')}")
    print("| problem | kernel | ours | ours: final cost | Ceres: final cost | ours/Ceres − 1 | ours s | Ceres s | ok |")
    print("|---|---|---|---|---|---|---|---|---|")
    passed = failed = 0
    curves = []
    for kind, path, kernel, name in cases:
        ours, labels, theirs = run_case(kind, path, kernel, args.max_iterations, ceres)
        for o, label in zip(ours, labels):
            rel = o["cost_final"] / theirs["cost_final"] - 1.0
            ok = rel <= TOLERANCE and o["iterations"] <= args.max_iterations
            passed, failed = passed + ok, failed + (not ok)
            print(f"| {name} | {kernel} | {label} | {o['cost_final']:.10g} | {theirs['cost_final']:.10g} | "
                  f"{rel:+.2e} | {o['seconds']:.3f} | {theirs['seconds']:.3f} | {'yes' if ok else 'NO'} |")
            curves.append({"problem": name, "kernel": kernel, "ours": label, "ours_costs": o["costs"],
                           "ceres_costs": theirs["costs"], "ceres_final": theirs["cost_final"]})
        sys.stdout.flush()
    if args.curves:
        args.curves.write_text(json.dumps(curves))
    print_curves(curves, [0, 1, 2, 5, 10, 20, 30, 40, args.max_iterations])
    print(f"robust: {passed} passed, {failed} failed")
    return 0 if failed == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
