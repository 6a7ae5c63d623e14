#!/usr/bin/env python3
"""Bundle adjustment side by side: dynamap's bundle_adjustment example and Ceres' ceres_bal (from
../shared/bench/peers/setup.sh) on the same BAL files, every configuration of each, runs
alternating, in one invocation.

usage: bench/compare_bal.py [--runs N] [--threads T] [--max-iterations N] [--huber D]
                            [--ours schur-dense,schur-sparse,...] [--ceres sparse_schur,...]
                            [--timeout S] [--json OUT] FILE...

Prints one Markdown table per file: for every configuration the initial and final cost, the
iterations, the median seconds of the solve alone and the largest peak resident set (the child's
ru_maxrss, which includes reading the file); then the best of ours against the best of Ceres (time
and memory ratios, and the relative difference of the final costs), and ours with --linear-solver
auto against the best of ours. A run that exceeds --timeout seconds is reported as such. With
--json, every configuration's figures are also written to OUT (a list of records: file,
configuration, seconds, rss_mb, cost_final, iterations; seconds null for a run that timed out), the
input of bench/scaling.py. Where ours ran on past Ceres' lowest final cost (a solve resumed
after re-triangulating its points), a row gives the iteration and the seconds at which it reached
that cost.
"""
import argparse, json, os, statistics, subprocess, sys, time

here = os.path.dirname(os.path.abspath(__file__))
ours = os.path.join(here, "..", "target", "release", "bundle_adjustment")
ceres = os.path.expanduser("~/.cache/dynamap-peers/bin/ceres_bal")


def run_measured(cmd, timeout):
    """The JSON line a run prints last, with the child's peak resident set (ru_maxrss, KB on Linux)
    as 'rss_mb'; None if it took over `timeout` seconds."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        os.dup2(w, 1)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 2)
        os.execv(cmd[0], cmd)
    os.close(w)
    chunks, t0, done = [], time.monotonic(), None
    os.set_blocking(r, False)
    while done is None:
        try:
            b = os.read(r, 1 << 16)
            if b:
                chunks.append(b)
        except BlockingIOError:
            pass
        wpid, status, usage = os.wait4(pid, os.WNOHANG)
        if wpid == pid:
            done = (status, usage)
            break
        if time.monotonic() - t0 > timeout:
            os.kill(pid, 9)
            os.wait4(pid, 0)
            os.close(r)
            return None
        time.sleep(0.01)
    os.set_blocking(r, True)
    while True:
        b = os.read(r, 1 << 16)
        if not b:
            break
        chunks.append(b)
    os.close(r)
    status, usage = done
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"{' '.join(cmd)} failed (exit {os.waitstatus_to_exitcode(status)})")
    res = json.loads(b"".join(chunks).decode().strip().splitlines()[-1])
    res["rss_mb"] = usage.ru_maxrss / 1024.0
    return res


def commands(f, a):
    common = ["--threads", str(a.threads), "--max-iterations", str(a.max_iterations)]
    cmds = {}
    for s in filter(None, a.ceres.split(",")):
        cmds["ceres " + s] = [ceres, f, "--linear-solver", s] + common + (["--huber", str(a.huber)] if a.huber else [])
    for s in filter(None, a.ours.split(",")):
        cmds["dynamap " + s] = [ours, f, "--linear-solver", s, "--quiet"] + common + (["--huber", str(a.huber)] if a.huber else [])
    return cmds


def table(f, a):
    cmds = commands(f, a)
    res = {k: [] for k in cmds}
    timed_out = set()
    for _ in range(a.runs):
        for k, c in cmds.items():
            if k in timed_out:
                continue
            r = run_measured(c, a.timeout)
            if r is None:
                timed_out.add(k)
            else:
                res[k].append(r)
    for k, rs in res.items():
        a.records.append({
            "file": os.path.basename(f),
            "configuration": k,
            "seconds": statistics.median(r["seconds"] for r in rs) if rs else None,
            "rss_mb": max(r["rss_mb"] for r in rs) if rs else None,
            "cost_final": rs[0]["cost_final"] if rs else None,
            "iterations": rs[0]["iterations"] if rs else None,
        })
    print(f"\n{os.path.basename(f)}\n")
    print(f"| configuration | cost initial | cost final | iterations | termination | seconds (median of {a.runs}) | peak RSS MB |")
    print("|---|---|---|---|---|---|---|")
    summary = {}
    for k, rs in res.items():
        if not rs:
            print(f"| {k} | | | | over {a.timeout:.0f} s | | |")
            continue
        d = rs[0]
        sec = statistics.median(r["seconds"] for r in rs)
        rss = max(r["rss_mb"] for r in rs)
        summary[k] = (sec, rss, d["cost_final"], d.get("linear_solver", ""))
        print(f"| {k} | {d['cost_initial']:.10g} | {d['cost_final']:.10g} | {d['iterations']} | {d.get('termination', '')} | {sec:.3f} | {rss:.0f} |")
    lowest = min((v[2] for v in summary.values()), default=0.0)

    def pick(prefix, near_lowest):
        ok = lambda v: not near_lowest or v[2] <= lowest * (1 + 1e-6)
        return min(((v, k) for k, v in summary.items()
                    if k.startswith(prefix) and not k.endswith(" auto") and ok(v)), default=None)

    for label, near in (("fastest", False), ("fastest within 1e-6 of the lowest cost", True)):
        bo, bc = pick("dynamap", near), pick("ceres", near)
        if bo and bc:
            (so, ro, co, _), ko = bo
            (sc, rc, cc, _), kc = bc
            print(f"| {label}: {ko} / {kc} | | rel. cost {(co - lowest) / lowest:.1e} / {(cc - lowest) / lowest:.1e} | | | ratio {so / sc:.2f} | ratio {ro / rc:.2f} |")
    reach_peer(res, summary)
    bo = pick("dynamap", False)
    if bo and "dynamap auto" in summary:
        sa, ra, ca, chosen = summary["dynamap auto"]
        print(f"| auto (chose {chosen}) / {bo[1]} | | | | | ratio {sa / bo[0][0]:.2f} | |")


def reach_peer(res, summary):
    """Where ours ran on past the lowest final cost of Ceres (its iterations resumed after a
    re-triangulation), the first iteration at or below that cost (within 1e-6) and the seconds
    to it, from the JSON line's 'costs' and 'seconds_at' (the first run's)."""
    peers = [v for k, v in summary.items() if k.startswith("ceres")]
    if not peers:
        return
    sc, _, cc, _ = min(peers, key=lambda v: (v[2], v[0]))
    target = cc * (1 + 1e-6)
    for k, rs in res.items():
        if not k.startswith("dynamap") or not rs or "seconds_at" not in rs[0]:
            continue
        d = rs[0]
        hit = next((i for i, c in enumerate(d["costs"]) if c <= target), None)
        if hit is not None and hit < len(d["costs"]) - 1:
            t = d["seconds_at"][hit]
            print(f"| {k} reaches Ceres' lowest final cost {cc:.10g} | | {d['costs'][hit]:.10g} | {hit} | | {t:.3f} (ratio {t / sc:.2f}) | |")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("files", nargs="+")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--max-iterations", type=int, default=50)
    ap.add_argument("--huber", type=float, default=0.0)
    ap.add_argument("--ours", default="schur-dense,schur-sparse,schur-iterative,auto")
    ap.add_argument("--ceres", default="dense_schur,sparse_schur,iterative_schur")
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument("--json", help="also write every configuration's figures here")
    a = ap.parse_args()
    a.records = []
    for tool in (ours, ceres):
        if not os.path.exists(tool):
            sys.exit(f"{tool} is missing (cargo build --release -p dynamap-apps; ../shared/bench/peers/setup.sh)")
    print(f"threads {a.threads}, {a.max_iterations} iterations, huber {a.huber or 'none'}, {time.strftime('%Y-%m-%d')}")
    for f in a.files:
        table(f, a)
        if a.json:
            # rewritten after every file, so a long run stopped part way keeps what it measured
            tmp = a.json + ".tmp"
            with open(tmp, "w") as out:
                json.dump(a.records, out, indent=1)
            os.replace(tmp, a.json)


if __name__ == "__main__":
    main()
