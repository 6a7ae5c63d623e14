"""Held-out check of NOTES 195's affine rule on real geometry: camel poses carried by an affine
map (`same`: a pose onto itself stretched along a random axis, sheared, or scaled per axis;
each should be laid by the map) and camel maps with the target stretched as well (`pairs`: pose
i onto pose j stretched 15-30 % along a random axis; the warp should stay, scored by the
ground-truth map as `nonrigid_register --ground-truth` scores it, placeholders left out).

Usage: python bench/camel_affine.py same|pairs [--seed 7] [--count 9] [--bin target/release/nonrigid_register]
(a Python with open3d 0.20 and numpy; the data in ../shared/data/nonrigid/camel_gallop).
"""
import argparse
import json
import os
import subprocess
import tempfile

import numpy as np
import open3d as o3d

DATA = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "nonrigid", "camel_gallop")


def read_mesh(path):
    """Vertices (in the file's order, which the ground-truth maps index) and the mesh."""
    m = o3d.io.read_triangle_mesh(path)
    return np.asarray(m.vertices).copy(), m


def write_mesh(path, v, m):
    out = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), m.triangles)
    o3d.io.write_triangle_mesh(path, out)


def stretch(rng, lo, hi):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return np.eye(3) + rng.uniform(lo, hi) * np.outer(axis, axis)


def affine(rng, case):
    kind = ("stretch", "shear", "per-axis")[case % 3]
    if kind == "stretch":
        return kind, stretch(rng, 0.15, 0.35)
    if kind == "shear":
        a = np.eye(3)
        i, j = rng.choice(3, 2, replace=False)
        a[i, j] = rng.uniform(0.15, 0.3)
        return kind, a
    return kind, np.diag(rng.uniform(0.8, 1.3, 3))


def register(binary, source, target, tmp):
    s, t, w = (os.path.join(tmp, n) for n in ("s.ply", "t.ply", "w.ply"))
    write_mesh(s, *source)
    write_mesh(t, *target)
    r = subprocess.run([binary, "meshes", s, t, "--output", w, "-q"], capture_output=True, text=True)
    j = json.loads(r.stdout.strip().splitlines()[-1])
    return j, np.asarray(o3d.io.read_triangle_mesh(w).vertices)


def flags(j):
    return f"registered {j['registered']!s:5s} placed_affine {j['placed_affine']!s:5s} placed_back {j['placed_back']!s:5s}"


def same(a, rng, tmp):
    for case in range(a.count):
        i = int(rng.integers(1, 11))
        v, f = read_mesh(os.path.join(DATA, f"camel-gallop-{i:02d}.off"))
        kind, m = affine(rng, case)
        c, diag = v.mean(0), np.linalg.norm(np.ptp(v, 0))
        t = (v - c) @ m.T + c + rng.normal(size=3) * 0.02 * diag
        j, w = register(a.bin, (v, f), (t, f), tmp)
        e = np.linalg.norm(w - t, axis=1)
        sv = " ".join(f"{x:.2f}" for x in np.linalg.svd(m)[1])
        print(f"pose {i:2d} {kind:8s} singular values {sv}  {flags(j)}  error mean "
              f"{100 * e.mean() / np.linalg.norm(np.ptp(t, 0)):.3f} % of the diagonal  {j['seconds']:.1f} s", flush=True)


def pairs(a, rng, tmp):
    maps = sorted(os.listdir(os.path.join(DATA, "maps")))
    for name in rng.choice(maps, a.count, replace=False):
        i, k = map(int, name.split("_to_"))
        v, f = read_mesh(os.path.join(DATA, f"camel-gallop-{i:02d}.off"))
        u, g = read_mesh(os.path.join(DATA, f"camel-gallop-{k:02d}.off"))
        truth = np.loadtxt(os.path.join(DATA, "maps", name), dtype=int)
        m = stretch(rng, 0.15, 0.3)
        c = u.mean(0)
        t = (u - c) @ m.T + c
        j, w = register(a.bin, (v, f), (t, g), tmp)
        scored = np.bincount(truth, minlength=len(t))[truth] <= 0.01 * len(truth)
        e = np.linalg.norm(w[scored] - t[truth[scored]], axis=1) / np.linalg.norm(np.ptp(t, 0))
        print(f"{name:8s} stretch {np.linalg.svd(m)[1][0]:.2f}  {flags(j)}  error mean "
              f"{100 * e.mean():.3f} % of the diagonal  {j['seconds']:.1f} s", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=("same", "pairs"))
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--count", type=int, default=9)
    ap.add_argument("--bin", default="target/release/nonrigid_register")
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)
    with tempfile.TemporaryDirectory() as tmp:
        (same if a.mode == "same" else pairs)(a, rng, tmp)


if __name__ == "__main__":
    main()
