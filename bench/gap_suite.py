#!/usr/bin/env python3
"""Gaps in the stream (issue 24, point 2): frames dropped at random points of a long sequence, some
followed by an unreadable or a blank depth frame, tracked by rigid_slam and scored per gap.

usage: python3 bench/gap_suite.py SEQ [--gaps 20] [--lengths 0.5,1,3] [--seed 1] [--after 0.25]
                                  [--work DIR] [--json OUT] [--slam-args "--submaps ..."]

SEQ is a TUM-layout sequence with groundtruth.txt (e.g. one made by `generate rigid ... --motion
orbit`). The gaps start at depth frames drawn (seeded) after the first --after share of the sequence,
each at least its length plus 1 s after the last; their lengths cycle through --lengths in a seeded
order. The depth and colour frames whose stamps fall in a gap are removed from depth.txt and rgb.txt
(the stream skipped them); after every third gap the first depth frame that nearest-stamp
association pairs with colour (the one rigid_slam is given) is an unreadable file, after every third
(offset by one) an all-zero depth image. The intact sequence is tracked as the reference.

Per gap: recovered when one of the first 5 depth frames after the gap is reported tracked with its
pose (after the SE(3) alignment of the whole estimate, as the ATE's) within 10 cm and 5 deg of the
truth. Over the run: ATE RMSE over the frames reported tracked, against the intact run's, and the
frames reported tracked that are more than 10 cm or 5 deg off (silent failures; there must be none).
Prints one line per gap and a JSON summary.
"""
import argparse, json, os, shutil, subprocess, sys, tempfile
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from hard_suite import SLAM, errors, load_tum  # noqa: E402

WINDOW = 5  # frames after a gap within which the track must be found again
MAX_T, MAX_R = 0.10, 5.0  # a tracked frame further off than this is a silent failure


def read_list(path):
    return [l.split() for l in open(path) if l.strip() and not l.startswith("#")]


def write_list(path, rows, title):
    with open(path, "w") as f:
        f.write(f"# {title}\n# timestamp filename\n")
        for r in rows:
            f.write(" ".join(r) + "\n")


def plan(stamps, n, lengths, after, rng):
    """(first depth index, length s) of n gaps, in stream order: each gap and the second after it
    take their room, and the rest of the span is shared out at random between them."""
    order = [lengths[k % len(lengths)] for k in rng.permutation(n)]
    t0, t1 = stamps[0] + after * (stamps[-1] - stamps[0]), stamps[-1]
    slack = (t1 - t0) - sum(L + 1.0 for L in order)
    if slack < 0:
        sys.exit(f"cannot place {n} gaps of {lengths} s in {t1 - t0:.1f} s; use fewer or a longer sequence")
    cuts, used, out = np.sort(rng.uniform(0, slack, n)), 0.0, []
    for cut, L in zip(cuts, order):
        out.append((int(np.searchsorted(stamps, t0 + cut + used)), L))
        used += L + 1.0
    return out


def associated(depth, rgb, max_difference=0.02):
    """Indices of the depth stamps that nearest-stamp association pairs with a colour stamp: all
    pairs closer than max_difference, taken closest first, each stamp used once (TUM's
    associate.py, as rigid_slam's --max-difference does it)."""
    pairs = []
    for i, t in enumerate(depth):
        lo, hi = np.searchsorted(rgb, t - max_difference), np.searchsorted(rgb, t + max_difference)
        pairs += [(abs(rgb[k] - t), i, k) for k in range(lo, hi) if abs(rgb[k] - t) < max_difference]
    used_d, used_c = set(), set()
    for _, i, k in sorted(pairs):
        if i not in used_d and k not in used_c:
            used_d.add(i)
            used_c.add(k)
    return used_d


def make_gapped(seq, out, gaps):
    """Writes the gapped copy of seq into out; returns per gap (first frame after it, fault)."""
    depth, rgb = read_list(os.path.join(seq, "depth.txt")), read_list(os.path.join(seq, "rgb.txt"))
    stamps = np.array([float(r[0]) for r in depth])
    drop, after = np.zeros(len(depth), bool), []
    rgb_drop = np.zeros(len(rgb), bool)
    rgb_stamps = np.array([float(r[0]) for r in rgb])
    for k, (i, L) in enumerate(gaps):
        t = stamps[i]
        drop |= (stamps >= t) & (stamps < t + L)
        rgb_drop |= (rgb_stamps >= t) & (rgb_stamps < t + L)
        j = int(np.searchsorted(stamps, t + L))
        after.append((j, ("none", "unreadable", "blank")[k % 3]))
    paired = associated(stamps[~drop], rgb_stamps[~rgb_drop])
    kept = np.flatnonzero(~drop)
    delivered = {int(kept[i]) for i in paired}
    # the fault goes on the first depth frame after the gap that association delivers
    faulted = [(next((i for i in range(j, len(stamps)) if i in delivered), j), f) for j, f in after]
    os.makedirs(os.path.join(out, "depth"), exist_ok=True)
    for name in ("groundtruth.txt", "intrinsics.txt"):
        shutil.copy(os.path.join(seq, name), out)
    os.symlink(os.path.join(os.path.abspath(seq), "rgb"), os.path.join(out, "rgb"))
    faults = {j: f for j, f in faulted}
    rows = []
    for k, (s, name) in enumerate(depth):
        if drop[k]:
            continue
        src, dst = os.path.join(os.path.abspath(seq), name), os.path.join(out, name)
        if faults.get(k) == "unreadable":
            with open(dst, "wb") as f:
                f.write(b"\x89PNG\r\n\x1a\n not an image")
        elif faults.get(k) == "blank":
            from PIL import Image
            w, h = Image.open(src).size
            Image.fromarray(np.zeros((h, w), np.uint16)).save(dst)
        else:
            os.symlink(src, dst)
        rows.append([s, name])
    write_list(os.path.join(out, "depth.txt"), rows, "depth maps")
    write_list(os.path.join(out, "rgb.txt"), [r for r, d in zip(rgb, rgb_drop) if not d], "color images")
    return after, stamps


def track(seq, est, extra=()):
    p = subprocess.run([SLAM, seq, "--quiet", "--output", est, *extra], capture_output=True, text=True)
    if p.returncode not in (0, 1):
        sys.exit(f"rigid_slam {seq} failed ({p.returncode}):\n{p.stderr[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def scored(gt, est):
    """(stamps, translation errors, rotation errors) of the estimate's frames."""
    trans, rot = errors(gt, est)
    return load_tum(est)[0], trans, rot


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("seq")
    ap.add_argument("--gaps", type=int, default=20)
    ap.add_argument("--lengths", default="0.5,1,3")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--after", type=float, default=0.25)
    ap.add_argument("--work")
    ap.add_argument("--json")
    ap.add_argument("--slam-args", default="", help="more flags for rigid_slam, e.g. --submaps")
    a = ap.parse_args()
    work = a.work or tempfile.mkdtemp(prefix="gaps-")
    out = os.path.join(work, "gapped")
    shutil.rmtree(out, ignore_errors=True)
    stamps = np.array([float(r[0]) for r in read_list(os.path.join(a.seq, "depth.txt"))])
    gaps = plan(stamps, a.gaps, [float(x) for x in a.lengths.split(",")], a.after, np.random.default_rng(a.seed))
    after, stamps = make_gapped(a.seq, out, gaps)
    gt = os.path.join(a.seq, "groundtruth.txt")
    intact_est, gapped_est = os.path.join(work, "intact.txt"), os.path.join(work, "gapped.txt")
    extra = a.slam_args.split()
    intact, run = track(a.seq, intact_est, extra), track(out, gapped_est, extra)
    _, it, _ = scored(gt, intact_est)
    es, trans, rot = scored(gt, gapped_est)
    good = {round(s, 6) for s, t, r in zip(es, trans, rot) if t <= MAX_T and r <= MAX_R}
    silent = int(np.sum((trans > MAX_T) | (rot > MAX_R)))
    recovered = 0
    print(f"{'gap':>3} {'frame':>6} {'s':>4} {'fault':>10} {'recovered after':>16}")
    for k, ((i, L), (j, fault)) in enumerate(zip(gaps, after)):
        window = [round(s, 6) for s in stamps[j:j + WINDOW]]
        hit = next((n for n, s in enumerate(window) if s in good), None)
        recovered += hit is not None
        print(f"{k:3d} {i:6d} {L:4.1f} {fault:>10} {'-' if hit is None else f'{hit + 1} frames':>16}")
    res = {"sequence": a.seq, "gaps": a.gaps, "recovered": recovered, "window": WINDOW,
           "intact_ate_m": float(np.sqrt(np.mean(it ** 2))), "ate_m": float(np.sqrt(np.mean(trans ** 2))),
           "tracked": len(es), "frames": run["frames"], "silent_failures": silent,
           "max_error_m": float(trans.max()), "max_error_deg": float(rot.max()),
           "fps": run["fps"], "relocalised": run.get("relocalised"), "intact_fps": intact["fps"]}
    print(json.dumps(res))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f)


if __name__ == "__main__":
    main()
