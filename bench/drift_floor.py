#!/usr/bin/env python3
"""Re-judges `nonrigid_slam`'s colour-drift verdict (NOTES 112, 132, 134) under other floors, offline.

    bench/drift_floor.py collect OUT.json "plane:bend:3 cylinder:bend:7:simple" [FLAGS...]
    bench/drift_floor.py judge OUT.json

`collect` runs each case (surface:field:seed[:sensor], 100 frames or FRAMES) with the verdict off
(`--colour-drift-ratio 0`) and `-v`, and stores per frame its median chromaticity residual, the
quantisation step and the error over the samples the camera sees; cases already in OUT.json are
kept. `judge` judges every stored frame at several ratios against floors made from different early
frames and counts, as `bench/drift_verdict.py` does, frames within 5 mm judged drifted and frames
more than 1 cm off not judged. The runs had no verdict, so a refused frame's effect on the frames
after it (it is not fused) is not seen: a way to choose what to run with the verdict on, not its
result. BIN is the binary (default target/release/examples/nonrigid_slam).
"""
import json
import math
import os
import re
import statistics
import subprocess
import sys

from drift_verdict import BAD_MM, GOOD_MM, case_args

LINE = re.compile(r"frame (\d+): .*chromaticity residual ([0-9.NaN]+) of [0-9.NaN]+ "
                  r"\(step ([0-9.NaN]+)\), error [0-9.NaN]+ mm \(([0-9.NaN]+) mm seen\)")

# name, frames the floor needs, the floor from the tracked frames' residuals in order
FLOORS = [
    ("mean of 1-3 (now)", 3, lambda r: sum(r[:3]) / 3),
    ("mean of 2-4", 4, lambda r: sum(r[1:4]) / 3),
    ("max of 1-3", 3, lambda r: max(r[:3])),
    ("mean of 2-5", 5, lambda r: sum(r[1:5]) / 4),
    ("median of 1-5", 5, lambda r: statistics.median(r[:5])),
]


def collect(path, cases, flags):
    out = json.load(open(path)) if os.path.exists(path) else {}
    for case in cases.split():
        key = " ".join([case, *flags])
        if key in out:
            continue
        args = case_args(case, ["--colour-drift-ratio", "0", *flags])
        run = subprocess.run(args, capture_output=True, text=True)
        if run.returncode != 0:
            sys.exit(f"{case}: exit {run.returncode}\n{run.stderr[-2000:]}")
        rows = [[int(m[1]), float(m[2]), float(m[3]), float(m[4])]
                for m in LINE.finditer(run.stdout + run.stderr)]
        out[key] = rows
        with open(path + ".tmp", "w") as f:
            json.dump(out, f)
        os.replace(path + ".tmp", path)
        print(f"{key}: {len(rows)} frames", flush=True)


def judge(path):
    data = json.load(open(path))
    for ratio in (1.3, 1.4, 1.5):
        for name, need, floor_of in FLOORS:
            totals, per_case = [0, 0, 0, 0], []
            for rows in data.values():
                rows = [r for r in rows if r[0] > 0 and math.isfinite(r[1])]
                floor = floor_of([r[1] for r in rows])
                good = bad = good_refused = bad_fused = 0
                for i, (_, residual, step, seen) in enumerate(rows):
                    refused = i >= need and residual > ratio * max(floor, step)
                    good += seen < GOOD_MM
                    good_refused += seen < GOOD_MM and refused
                    bad += seen > BAD_MM
                    bad_fused += seen > BAD_MM and not refused
                per_case.append(f"{good_refused}/{good},{bad_fused}/{bad}")
                for j, v in enumerate((good_refused, good, bad_fused, bad)):
                    totals[j] += v
            print(f"ratio {ratio}, floor {name}: within 5 mm judged drifted {totals[0]}/{totals[1]}, "
                  f"over 1 cm not judged {totals[2]}/{totals[3]}  [{' '.join(per_case)}]")


def main():
    if len(sys.argv) >= 4 and sys.argv[1] == "collect":
        collect(sys.argv[2], sys.argv[3], sys.argv[4:])
    elif len(sys.argv) == 3 and sys.argv[1] == "judge":
        judge(sys.argv[2])
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
