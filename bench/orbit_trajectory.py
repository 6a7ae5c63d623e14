#!/usr/bin/env python3
"""A looping ground-truth trajectory for `../shared/bench/render_sequence.py`: the camera circles
a table (radius 1.5 m ± 0.25 m, height 0.55 m ± 0.15 m) once per PERIOD seconds, looking at a point
that wanders ±0.25 m about the table's centre, so that it returns to every place once a lap.
Written at 90 Hz in TUM's format (camera z forward, y down), for scenes rendered by code the
tracker does not share (issue 24's held-out looping sequence).

usage: python3 bench/orbit_trajectory.py OUT.txt [--frames 2000] [--period 30] [--seed 7]

OUT.txt covers --frames frames at 30 Hz; --seed draws the phases of the radius, height and
target wobbles.
"""
import argparse
import numpy as np
from scipy.spatial.transform import Rotation


def pose(t, period, phase):
    a = 2 * np.pi * t / period
    r = 1.5 + 0.25 * np.sin(2 * a + phase[0])
    centre = np.array([r * np.cos(a), r * np.sin(a), 0.55 + 0.15 * np.sin(3 * a + phase[1])])
    target = np.array([0.25 * np.sin(a + phase[2]), 0.2 * np.cos(2 * a + phase[3]), -0.05])
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return centre, Rotation.from_matrix(np.stack([x, y, z], 1)).as_quat()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--period", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=7)
    a = ap.parse_args()
    phase = np.random.default_rng(a.seed).uniform(0, 6.28, 4)
    rows = ["# timestamp tx ty tz qx qy qz qw"]
    for k in range(a.frames * 3):
        t = k / 90.0
        c, q = pose(t, a.period, phase)
        rows.append("%.6f %.6f %.6f %.6f %.9f %.9f %.9f %.9f" % (t, *c, *q))
    with open(a.out, "w") as f:
        f.write("\n".join(rows) + "\n")


if __name__ == "__main__":
    main()
