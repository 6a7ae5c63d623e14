#!/usr/bin/env python3
"""Hole and flying-pixel rates at depth discontinuities, split by the size of the jump.

depth_stats.py gives P(hole) and the flying share over all the jumps of a set of frames; both depend
on how large the scene's jumps are (a projector shadow is f*b*(1/z_near - 1/z_far) pixels wide, and a
narrow one is filled by the matching window). Binned by the jump in 1/z, the rates of the sensor model
can be compared with real frames whose scenes have other jumps.

depth_stats.py's 'flying' counts any valid pixel between the two sides of a jump, which includes a
curved or oblique surface turning away towards its silhouette (a noise-free render of our layouts
scores 5-18 % on it). 'mixed' counts only pixels that stand apart: between the two sides, and more
than 15 % of the jump (in 1/z) from each valid neighbour in the row, as a mixed return does; 'mixed
w/o hole' is its rate among the jumps without a hole, where the sensor's mixed returns show.

usage: edge_holes.py NAME=FX:SCALE:GLOB [NAME=...]     (20 frames spread over each set are used;
       run with the peers' venv python: it needs numpy, PIL and ../shared/bench/depth_stats.py)
"""
import glob, os, sys
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "bench"))
import depth_stats  # noqa: E402

BINS = [0.05, 0.15, 0.3, 0.6, np.inf]
STABLE = 0.012  # neighbours closer than this in 1/z (1/m) belong to one surface (depth_stats' value)
APART = 0.15  # a mixed pixel is this share of the jump away from each neighbour


def stable_runs(w):
    """(first, last) of each run of at least 3 valid pixels whose 1/z changes by less than STABLE."""
    with np.errstate(invalid="ignore"):
        near = np.abs(np.diff(w)) < STABLE
    ok = np.isfinite(w)
    ok &= np.r_[False, near] | np.r_[near, False]
    runs, start = [], None
    for i in range(len(w) + 1):
        if i < len(w) and ok[i] and start is not None and near[i - 1]:
            continue
        if start is not None and i - start >= 3:
            runs.append((start, i - 1))
        start = i if i < len(w) and ok[i] else None
    return runs


def row_jumps(z):
    """Per jump of one row: (side, hole pixels, jump in 1/z, flying, mixed)."""
    w = np.where(z > 0, 1.0 / np.where(z > 0, z, 1.0), np.nan)
    out = []
    runs = stable_runs(w)
    for (a0, a1), (b0, b1) in zip(runs[:-1], runs[1:]):
        if b0 - a1 - 1 > 60:
            continue
        wl, wr = np.median(w[max(a0, a1 - 2):a1 + 1]), np.median(w[b0:min(b1, b0 + 2) + 1])
        jump = abs(wl - wr)
        if jump < 0.05 or jump < 0.05 * min(wl, wr):
            continue
        gap = z[a1 + 1:b0]
        lo, hi = sorted((1 / wl, 1 / wr))
        margin = 3 * hi ** 2 / depth_stats.KQ
        between = np.flatnonzero((gap > lo + margin) & (gap < hi - margin)) + a1 + 1
        mixed = any(all(abs(w[j] - w[i]) > APART * jump for j in (i - 1, i + 1) if np.isfinite(w[j]))
                    for i in between)
        out.append((1 if wr > wl else -1, np.count_nonzero(gap == 0), jump, len(between) > 0, mixed))
    return out


def rates(spec):
    fx, scale, pattern = spec.split(":", 2)
    jumps = []
    paths = sorted(glob.glob(os.path.expanduser(pattern)))
    if len(paths) > 20:  # depth_stats.py's choice: 20 frames spread over the set
        paths = [paths[i] for i in np.linspace(0, len(paths) - 1, 20).round().astype(int)]
    for path in paths:
        z = depth_stats.load(path, float(scale))
        for row in z:
            jumps += row_jumps(row)
    return np.array(jumps, float).reshape(-1, 5)  # side, hole pixels, jump in 1/z, flying, mixed


def cell(e, m):
    n = int(m.sum())
    return f"n {n:5d} P {np.mean(e[m, 1] > 0):4.2f} fly {np.mean(e[m, 3]):4.2f}" if n else f"{'-':>22}"


def main():
    sets = dict(a.split("=", 1) for a in sys.argv[1:])
    if not sets:
        sys.exit(__doc__)
    table = {name: rates(spec) for name, spec in sets.items()}
    print(f"{'side':6} {'jump 1/m':11}" + "".join(f" {n:>22}" for n in table))
    for side, label in ((1, "near R"), (-1, "near L")):
        for lo, hi in zip(BINS[:-1], BINS[1:]):
            cells = [cell(e, (e[:, 0] == side) & (e[:, 2] >= lo) & (e[:, 2] < hi)) for e in table.values()]
            print(f"{label:6} {f'{lo:g}-{hi:g}':11}" + "".join(f" {c:>22}" for c in cells))
    print()
    print(f"{'all jumps':18}" + "".join(f" {n:>22}" for n in table))
    for label, f in (("n", lambda e: f"{len(e)}"),
                     ("P(hole)", lambda e: f"{np.mean(e[:, 1] > 0):.3f}"),
                     ("flying", lambda e: f"{np.mean(e[:, 3]):.3f}"),
                     ("mixed", lambda e: f"{np.mean(e[:, 4]):.4f}"),
                     ("jumps w/o hole", lambda e: f"{np.count_nonzero(e[:, 1] == 0)}"),
                     ("mixed w/o hole", lambda e: f"{np.mean(e[e[:, 1] == 0, 4]):.4f}" if np.any(e[:, 1] == 0) else "-")):
        print(f"{label:18}" + "".join(f" {f(e):>22}" for e in table.values()))


if __name__ == "__main__":
    main()
