#!/usr/bin/env python3
"""Sorts the loops of a rigid_slam run into true and false ones by the ground truth (issue 24,
point 4: "no false loop is accepted, or the robust kernel rejects it").

usage: python3 bench/loop_check.py RUN.json SEQUENCE_DIR [--near 0.3]

RUN.json holds rigid_slam's JSON line (`rigid_slam SEQ --submaps --quiet > RUN.json`); SEQUENCE_DIR
is the generated sequence (groundtruth.txt gives the true poses; each loop's keyframes are found
by the stamps in the JSON line, or by line of associations.txt for a run that gave none). A loop
joins two keyframes; it is true when their true camera centres are within --near metres (a loop
measured between views of one place), false otherwise (two places that look alike, as in the
twin room). A loop is kept when its DCS weight at the graph's solution is above
0.5. Prints one line: loops, true ones kept, false ones kept, and the largest weight of a false
loop; exits 1 when a false loop was kept or a loop has no weight (the graph was not solved).
"""
import argparse
import bisect
import json
import math
import sys


def stamps(seq):
    out = []
    with open(f"{seq}/associations.txt") as f:
        for line in f:
            if line.strip() and not line.startswith("#"):
                out.append(float(line.split()[0]))
    return out


def ground_truth(seq):
    t, p = [], []
    with open(f"{seq}/groundtruth.txt") as f:
        for line in f:
            if line.strip() and not line.startswith("#"):
                v = line.split()
                t.append(float(v[0]))
                p.append([float(x) for x in v[1:4]])
    return t, p


def classify(run, seq, near=0.3):
    """The DCS weights of `run`'s loops (rigid_slam's JSON line, parsed) split into true ones (the
    keyframes' true camera centres within `near` metres in sequence `seq`) and false ones; raises
    ValueError for a loop without a weight (the graph was not solved)."""
    frames = stamps(seq)
    t, p = ground_truth(seq)

    def centre(frame, stamp):
        # the ground truth's pose nearest in time (its stamps ascend); the loop's own stamp when
        # the run gave one, else the frame number (counted from 1) as a line of associations.txt,
        # which holds only when the reader kept every line
        s = stamp if stamp is not None else frames[frame - 1]
        i = bisect.bisect_left(t, s)
        j = min((j for j in (i - 1, i) if 0 <= j < len(t)), key=lambda j: abs(t[j] - s))
        return p[j]

    true, false = [], []
    for e in run["loop_events"]:
        if e["weight"] is None:
            # no weight: the graph was not solved, so no loop can be called switched off
            raise ValueError(f"loop {e['from']}-{e['to']} has no DCS weight (the keyframe graph was not solved)")
        d = math.dist(centre(e["from"], e.get("from_stamp")), centre(e["to"], e.get("to_stamp")))
        (true if d <= near else false).append(e["weight"])
    return true, false


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run")
    ap.add_argument("sequence")
    ap.add_argument("--near", type=float, default=0.3)
    a = ap.parse_args()
    with open(a.run) as f:
        lines = [l for l in f.read().splitlines() if l.strip()]
    run = json.loads(lines[-1])
    try:
        true, false = classify(run, a.sequence, a.near)
    except ValueError as e:
        sys.exit(f"{a.run}: {e}")
    kept_false = sum(1 for w in false if w > 0.5)
    print(
        f"{a.run}: {len(true) + len(false)} loops; true {len(true)} (kept {sum(1 for w in true if w > 0.5)}); "
        f"false {len(false)} (kept {kept_false}, largest weight {max(false, default=0.0):.2g}); "
        f"ATE {1e3 * run['ate_tracked']:.2f} mm tracked, {1e3 * run['ate_rmse']:.2f} mm corrected"
    )
    sys.exit(1 if kept_false else 0)


if __name__ == "__main__":
    main()
