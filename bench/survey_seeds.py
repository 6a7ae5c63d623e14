#!/usr/bin/env python3
"""Looping surveys over several layouts and seeds, one volume against sub-maps with loop closure
(issue 24, point 4), for one or more rigid_slam binaries run alternately.

usage: python3 bench/survey_seeds.py BIN [BIN ...] [--work DIR] [--cases room:51,twins:53,...]
                                     [--frames 900]

Each case LAYOUT:SEED is a survey generated once into DIR (`generate rigid DIR/LAYOUT-SEED --motion
survey --frames N --fps 15 --width 320 --height 240 --seed SEED --layout LAYOUT`, the Kinect sensor
model) and kept for later runs (delete its folder to generate it again). Every binary runs on it
with one volume and with `--submaps`; the binaries alternate case by case, so that the machine's
drift falls on all of them alike. Printed per
case and binary: the one volume's ATE, the sub-maps' ATE as tracked and corrected, the ratio of the
corrected ATE to the one volume's (issue 24 asks for at most 0.5), frames not tracked, and the loops
sorted by `bench/loop_check.py`'s rule (a loop is false when its keyframes' true camera centres are
more than 0.3 m apart; a kept false loop has a DCS weight above 0.5). A keyframe graph that was not
solved or did not converge gives no corrected ATE (the cell says so) and its case is left out of the
means. Then the means per binary. Generating needs `target/release/generate` (hard_suite.py's).

The default cases are the CI gate's room survey and the twin room and office surveys of BENCHMARKS.md
(seeds 51, 53, 52) and three seeds no setting was chosen on (61, 63, 62).
"""
import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from hard_suite import generate, run  # noqa: E402
from loop_check import classify  # noqa: E402

DEFAULT_CASES = "room:51,twins:53,office:52,room:61,twins:63,office:62"


def survey(work, layout, seed, frames):
    """The survey LAYOUT:SEED in `work`, generated unless it is there."""
    args = ["--motion", "survey", "--frames", str(frames), "--fps", "15", "--width", "320",
            "--height", "240", "--seed", str(seed), "--layout", layout, "-q"]
    return generate(f"{layout}-{seed}", args, work)


def slam(binary, seq, submaps):
    """rigid_slam's JSON line for `seq`, with one volume or with sub-maps."""
    out = run([binary, seq, "--quiet"] + (["--submaps"] if submaps else []))
    return json.loads(out.strip().splitlines()[-1])


def corrected(sub, seq):
    """The sub-maps' corrected ATE and the loops cell; the ATE is None, and the cell says why,
    when the keyframe graph was not solved or did not converge (its correction is not a result)."""
    try:
        true, false = classify(sub, seq)
    except ValueError as e:
        return None, f"not solved: {e}"
    kept = lambda ws: sum(1 for w in ws if w > 0.5)
    cell = f"{len(true)} ({kept(true)}) / {len(false)} ({kept(false)})"
    if sub["graph_converged"] is False:
        return None, cell + ", graph did not converge"
    return sub["ate_rmse"], cell


def mm(x):
    return "–" if x is None else f"{x * 1000:.2f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("binaries", nargs="+")
    ap.add_argument("--work", default="/tmp/survey_seeds")
    ap.add_argument("--cases", default=DEFAULT_CASES)
    ap.add_argument("--frames", type=int, default=900)
    a = ap.parse_args()
    cases = []
    for c in a.cases.split(","):
        layout, _, seed = c.partition(":")
        if not seed.isdigit():
            sys.exit(f"--cases: '{c}' is not LAYOUT:SEED")
        cases.append((layout, int(seed)))
    os.makedirs(a.work, exist_ok=True)
    print("| case | binary | one volume mm | sub-maps tracked mm | corrected mm | ratio | not tracked | "
          "loops true (kept) / false (kept) |")
    print("|---|---|---|---|---|---|---|---|")
    # per binary, the one volume's and the corrected ATE of each case (None where a run has none)
    ates = {b: [] for b in a.binaries}
    for i, (layout, seed) in enumerate(cases):
        seq = survey(a.work, layout, seed, a.frames)
        order = a.binaries if i % 2 == 0 else list(reversed(a.binaries))
        rows = {}
        for b in order:
            one, sub = slam(b, seq, False), slam(b, seq, True)
            fixed, loops = corrected(sub, seq)
            ratio = fixed / one["ate_rmse"] if fixed is not None and one["ate_rmse"] else None
            missed = (one["frames"] - one["tracked"], sub["frames"] - sub["tracked"])
            rows[b] = (f"| {layout}:{seed} | {b} | {mm(one['ate_rmse'])} | "
                       f"{mm(sub['ate_tracked'])} | {mm(fixed)} | "
                       f"{'–' if ratio is None else f'{ratio:.2f}'} | {missed[0]} / {missed[1]} | {loops} |")
            ates[b].append((one["ate_rmse"], fixed))
        for b in a.binaries:
            print(rows[b], flush=True)
    for b, pairs in ates.items():
        # a case without either ATE (nothing tracked, or a graph not solved or not converged) is
        # left out of the means, and said so
        both = [(o, c) for o, c in pairs if o is not None and c is not None]
        missing = len(pairs) - len(both)
        if not both:
            print(f"{b}: no case has both ATEs")
            continue
        one = sum(o for o, _ in both) / len(both)
        sub = sum(c for _, c in both) / len(both)
        note = f" ({missing} case(s) without an ATE left out)" if missing else ""
        print(f"mean over {len(both)} cases, {b}: one volume {one * 1000:.2f} mm, corrected {sub * 1000:.2f} mm{note}")


if __name__ == "__main__":
    main()
