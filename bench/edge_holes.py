#!/usr/bin/env python3
"""Hole and flying-pixel rates at depth discontinuities, split by the size of the jump.

depth_stats.py gives P(hole) and the flying share over all the jumps of a set of frames; both depend
on how large the scene's jumps are (a projector shadow is f*b*(1/z_near - 1/z_far) pixels wide, and a
narrow one is filled by the matching window). Binned by the jump in 1/z, the rates of the sensor model
can be compared with real frames whose scenes have other jumps.

usage: edge_holes.py NAME=FX:SCALE:GLOB [NAME=...]     (the first 20 frames of each set are used;
       run with the peers' venv python: it needs numpy, PIL and ../shared/bench/depth_stats.py)
"""
import glob, os, sys
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "bench"))
import depth_stats  # noqa: E402

BINS = [0.05, 0.15, 0.3, 0.6, np.inf]


def rates(spec):
    fx, scale, pattern = spec.split(":", 2)
    jumps = []
    for path in sorted(glob.glob(os.path.expanduser(pattern)))[:20]:
        jumps += depth_stats.edges(depth_stats.load(path, float(scale)), float(fx))
    return np.array(jumps, float).reshape(-1, 4)  # side, hole pixels, jump in 1/z, flying


def main():
    sets = dict(a.split("=", 1) for a in sys.argv[1:])
    if not sets:
        sys.exit(__doc__)
    table = {name: rates(spec) for name, spec in sets.items()}
    print(f"{'side':6} {'jump 1/m':11}" + "".join(f" {n:>22}" for n in table))
    for side, label in ((1, "near R"), (-1, "near L")):
        for lo, hi in zip(BINS[:-1], BINS[1:]):
            cells = []
            for e in table.values():
                m = (e[:, 0] == side) & (e[:, 2] >= lo) & (e[:, 2] < hi)
                n = int(m.sum())
                cells.append(f"n {n:5d} P {np.mean(e[m, 1] > 0):4.2f} fly {np.mean(e[m, 3]):4.2f}" if n
                             else f"{'-':>22}")
            print(f"{label:6} {f'{lo:g}-{hi:g}':11}" + "".join(f" {c:>22}" for c in cells))


if __name__ == "__main__":
    main()
