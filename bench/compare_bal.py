#!/usr/bin/env python3
"""Bundle adjustment side by side: dynamap's bundle_adjustment example and Ceres' ceres_bal (from
../shared/bench/peers/setup.sh) on the same BAL files, alternating runs, in one invocation.

usage: bench/compare_bal.py [--runs N] [--threads T] FILE...

Prints one Markdown table: initial and final cost, iterations and the median solve time of each
(Ceres: DENSE_SCHUR; dynamap: schur-dense), and the time ratio.
"""
import argparse, json, os, statistics, subprocess, sys

here = os.path.dirname(os.path.abspath(__file__))
ours = os.path.join(here, "..", "target", "release", "bundle_adjustment")
ceres = os.path.expanduser("~/.cache/dynamap-peers/bin/ceres_bal")


def run(cmd):
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("files", nargs="+")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    for tool in (ours, ceres):
        if not os.path.exists(tool):
            sys.exit(f"{tool} is missing (cargo build --release -p dynamap-apps; ../shared/bench/peers/setup.sh)")
    print("| problem | solver | cost initial | cost final | iterations | seconds (median of %d) |" % a.runs)
    print("|---|---|---|---|---|---|")
    for f in a.files:
        res = {"dynamap": [], "ceres": []}
        for _ in range(a.runs):
            res["ceres"].append(run([ceres, f, "--linear-solver", "dense_schur", "--threads", str(a.threads), "--max-iterations", "50"]))
            res["dynamap"].append(run([ours, f, "--linear-solver", "schur-dense", "--threads", str(a.threads), "--max-iterations", "50", "--quiet"]))
        med = {k: statistics.median(r["seconds"] for r in v) for k, v in res.items()}
        for k in ("dynamap", "ceres"):
            d = res[k][0]
            print(f"| {os.path.basename(f)} | {k} | {d['cost_initial']:.10g} | {d['cost_final']:.10g} | {d['iterations']} | {med[k]:.3f} |")
        print(f"| {os.path.basename(f)} | ratio dynamap/ceres | | | | {med['dynamap'] / med['ceres']:.2f} |")


if __name__ == "__main__":
    main()
