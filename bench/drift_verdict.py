#!/usr/bin/env python3
"""How `nonrigid_slam`'s colour-drift verdict (NOTES 112, 132) splits generated frames.

    bench/drift_verdict.py "plane:bend:3 cylinder:twist:7 sphere:wave:5:simple" [FLAGS...]

Cases are surface:field:seed[:sensor] (sensor kinect unless given). Each case runs 100 frames
(FRAMES in the environment) with `-v` and FLAGS; from the per-frame log it counts the frames whose
samples seen by the camera are within 5 mm of the truth and were judged drifted (not fused), the
frames more than 1 cm off that were fused (reported tracked), and the worst seen error of a fused
frame. BIN is the binary (default target/release/examples/nonrigid_slam).
"""
import os
import re
import subprocess
import sys

FRAME = re.compile(r"frame (\d+): .*error ([0-9.]+) mm \(([0-9.NaN]+) mm seen\)")
REFUSED = re.compile(r"WARN frame (\d+): not fused")


# a frame whose seen samples are within GOOD_MM of the truth is right, beyond BAD_MM wrong
GOOD_MM, BAD_MM = 5, 10


def case_args(case, flags):
    """`nonrigid_slam`'s command line for a case surface:field:seed[:sensor] with `-v`, BIN and
    FRAMES from the environment."""
    parts = case.split(":")
    surface, field, seed = parts[:3]
    sensor = parts[3] if len(parts) > 3 else "kinect"
    binary = os.environ.get("BIN", "target/release/examples/nonrigid_slam")
    frames = os.environ.get("FRAMES", "100")
    return [binary, "--surface", surface, "--field", field, "--seed", seed, "--sensor", sensor,
            "--max-frames", frames, "-v", *flags]


def run(case, flags):
    out = subprocess.run(case_args(case, flags), capture_output=True, text=True)
    log = out.stdout + out.stderr
    if out.returncode != 0:
        sys.exit(f"{case}: exit {out.returncode}\n{log[-2000:]}")
    refused = {int(m) for m in REFUSED.findall(log)}
    rows = [(int(m.group(1)), float(m.group(3))) for m in FRAME.finditer(log)]
    return refused, [(k, e) for k, e in rows if k > 0]


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    totals = [0, 0, 0, 0]
    for case in sys.argv[1].split():
        refused, rows = run(case, sys.argv[2:])
        good = [k for k, e in rows if e < GOOD_MM]
        bad = [k for k, e in rows if e > BAD_MM]
        good_refused = sum(k in refused for k in good)
        bad_fused = sum(k not in refused for k in bad)
        worst = max([e for k, e in rows if k not in refused] or [0.0])
        mean = sum(e for _, e in rows) / max(1, len(rows))
        print(f"{case}: within 5 mm refused {good_refused}/{len(good)}, over 1 cm fused "
              f"{bad_fused}/{len(bad)}, refused {len(refused)}, worst fused {worst:.1f} mm, "
              f"seen mean {mean:.1f} mm", flush=True)
        for i, v in enumerate([good_refused, len(good), bad_fused, len(bad)]):
            totals[i] += v
    print(f"total: within 5 mm refused {totals[0]}/{totals[1]}, over 1 cm fused "
          f"{totals[2]}/{totals[3]}")


if __name__ == "__main__":
    main()
