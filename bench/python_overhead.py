#!/usr/bin/env python3
"""The Python bindings' overhead (issue 28), printed as tables:

1. g2o pose graphs solved by `dynamap.solve_pose_graph(path)` against the `pose_graph` binary on
   the same file: the wall time of the call (read, solve, poses returned as numpy arrays) against
   the binary's process, and each one's solve seconds, with the chi2 each reached;
2. a residual written in Python, y = exp(m x + c) under a Cauchy(0.1) kernel on the same data,
   solved by dynamap (Jacobians from the callable, and numeric), by GTSAM's Python CustomFactor
   (Levenberg-Marquardt, the same kernel), and by the same residual written in Rust
   (`curve_fitting --data`, automatic derivatives).

Runs alternate between the systems (this machine's speed drifts); the median of --repeat runs is
printed. Run it in a virtual environment where `dynamap` is installed (pip install ./python);
GTSAM runs in the peers' environment (../shared/bench/peers/setup.sh).

    python bench/python_overhead.py [--graphs G.g2o ...] [--points 2000] [--repeat 5]
"""

import argparse
import json
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

import dynamap

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "posegraph"
PEERS_PYTHON = pathlib.Path.home() / ".cache" / "dynamap-peers" / "bin" / "python"

GTSAM_FIT = r"""
import json, sys, time
import numpy as np
import gtsam
data = np.loadtxt(sys.argv[1])
from functools import partial
def error(x, y, this, values, jacobians):
    p = values.atVector(this.keys()[0])
    e = np.exp(p[0] * x + p[1])
    if jacobians is not None:
        jacobians[0] = np.array([[x * e, e]])
    return np.array([e - y])
graph = gtsam.NonlinearFactorGraph()
model = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(0.1), gtsam.noiseModel.Unit.Create(1))
for x, y in data:
    graph.add(gtsam.CustomFactor(model, [0], partial(error, float(x), float(y))))
initial = gtsam.Values()
initial.insert(0, np.array([0.0, 0.0]))
params = gtsam.LevenbergMarquardtParams()
params.setMaxIterations(100)
params.setRelativeErrorTol(1e-10)
params.setAbsoluteErrorTol(0)
start = time.perf_counter()
optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
result = optimizer.optimize()
seconds = time.perf_counter() - start
print(json.dumps({"seconds": seconds, "cost": graph.error(result), "iterations": optimizer.iterations(),
                  "estimate": list(result.atVector(0))}))
"""


def median(xs):
    return statistics.median(xs)


def pose_graphs(paths, repeat):
    print("| graph | binary wall s | binary solve s | Python call s | Python solve s | call / binary | chi2 binary | chi2 Python |")
    print("|---|---|---|---|---|---|---|---|")
    binary = ROOT / "target" / "release" / "pose_graph"
    for path in paths:
        walls, solves, calls, py_solves = [], [], [], []
        for _ in range(repeat):
            start = time.perf_counter()
            out = subprocess.run([binary, str(path), "--quiet"], check=True, capture_output=True, text=True)
            walls.append(time.perf_counter() - start)
            tool = json.loads(out.stdout.strip().splitlines()[-1])
            solves.append(tool["seconds"])
            start = time.perf_counter()
            poses, summary = dynamap.solve_pose_graph(str(path))
            calls.append(time.perf_counter() - start)
            py_solves.append(summary.total_seconds)
        chi2 = dynamap.PoseGraph.read(path).chi2(poses)
        w, c = median(walls), median(calls)
        print(f"| {path.name} | {w:.3f} | {median(solves):.3f} | {c:.3f} | {median(py_solves):.3f} | {c / w:.2f} | {tool['chi2_final']:.6f} | {chi2:.6f} |")


def exponential_problem(data, jacobians):
    problem = dynamap.Problem()
    mc = problem.add_variable([0.0, 0.0])
    for x, y in data:
        if jacobians == "analytic":
            def f(p, x=x, y=y):
                e = np.exp(p[0] * x + p[1])
                return np.array([e - y]), [np.array([[x * e, e]])]
        else:
            def f(p, x=x, y=y):
                return np.array([np.exp(p[0] * x + p[1]) - y])
        problem.add_residual(f, [mc], dim=1, jacobians=jacobians, kernel="cauchy:0.1")
    return problem, mc


def curve_fit(points, repeat, seed):
    rng = np.random.default_rng(seed)
    x = 5.0 * np.arange(points) / points
    y = np.exp(0.3 * x + 0.1) + rng.normal(0, 0.02, points)
    outliers = rng.random(points) < 0.2
    y[outliers] = rng.random(outliers.sum()) * 8.0
    data = np.column_stack([x, y])
    folder = pathlib.Path(tempfile.mkdtemp())
    path = folder / "points.txt"
    np.savetxt(path, data, fmt="%.17g")
    script = folder / "gtsam_fit.py"
    script.write_text(GTSAM_FIT)
    rows = {k: [] for k in ["python", "numeric", "gtsam", "rust"]}
    last = {}
    for _ in range(repeat):
        for kind in ["analytic", "numeric"]:
            problem, mc = exponential_problem(data, kind)
            s = problem.solve()
            key = "python" if kind == "analytic" else "numeric"
            rows[key].append(s.total_seconds)
            last[key] = (s.final_cost, s.num_iterations, problem.value(mc), s.converged)
        if PEERS_PYTHON.exists():
            out = subprocess.run([PEERS_PYTHON, script, path], check=True, capture_output=True, text=True)
            g = json.loads(out.stdout.strip().splitlines()[-1])
            rows["gtsam"].append(g["seconds"])
            last["gtsam"] = (g["cost"], g["iterations"], g["estimate"], None)
        out = subprocess.run([ROOT / "target" / "release" / "curve_fitting", "--data", path, "--quiet"], check=True, capture_output=True, text=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        rows["rust"].append(r["robust_seconds"])
        last["rust"] = (r["robust_cost"], r["robust_iterations"], r["robust"], None)
    names = {
        "python": "dynamap, residual in Python (its Jacobian)",
        "numeric": "dynamap, residual in Python (numeric Jacobian)",
        "gtsam": "GTSAM CustomFactor (Python)",
        "rust": "dynamap, residual in Rust (curve_fitting --data)",
    }
    print(f"\ny = exp(m x + c), {points} points (20 % outliers), Cauchy(0.1), seed {seed}, median of {repeat}:\n")
    print("| system | solve s | iterations | ms / iteration | final cost | m, c |")
    print("|---|---|---|---|---|---|")
    for k, name in names.items():
        if not rows[k]:
            print(f"| {name} | not run | | | | |")
            continue
        cost, its, est, _ = last[k]
        t = median(rows[k])
        print(f"| {name} | {t:.4f} | {its} | {1e3 * t / max(its, 1):.2f} | {cost:.10g} | {est[0]:.6f}, {est[1]:.6f} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--graphs", nargs="*", type=pathlib.Path,
                    default=[DATA / n for n in ["M3500.g2o", "city10000.g2o", "sphere2500.g2o", "parking-garage.g2o", "torus3D.g2o"]])
    ap.add_argument("--points", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print(f"dynamap {dynamap.__version__}, Python {sys.version.split()[0]}, {time.strftime('%Y-%m-%d')}\n")
    pose_graphs(args.graphs, args.repeat)
    curve_fit(args.points, args.repeat, args.seed)


if __name__ == "__main__":
    main()
