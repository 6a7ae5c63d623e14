"""L-shaped flat sheets (a lattice with one corner cut out, no symmetry) stretched and turned:
does `nonrigid_register meshes` place them right, or refuse them, rather than report a wrong
answer as registered (NOTES 199)?

Usage: python bench/l_sheets.py [--count 8] [--seed 5] [--stretch 0.2] [--turn 30]
[--random-direction] [--noise F] [--bin target/release/nonrigid_register] [--dir /tmp/l_sheets]
(a Python with open3d 0.20, numpy and scipy). Each sheet (15–40 × 10–30 vertices, 0.3–2 by
0.2–1, a corner of 30–70 % of each side cut out) is placed as `symmetric_shapes.py` places its
shapes, stretched by 1 + S along its longest principal axis (or, with --random-direction, along
a random direction in space), then turned by DEG degrees about a random axis and moved by 4.3 %
of its diagonal; with --noise, each target vertex is then moved by a normal deviate of F times
the diagonal along each axis (the error is still measured against the noiseless target). The
line printed per sheet is the tool's exit code, `registered`,
`placed_affine`, `maps_apart`, and the largest and mean distance of a warped vertex from where
the stretch sent it (% of the largest displacement).
"""
import argparse
import os

import numpy as np
import open3d as o3d

from symmetric_shapes import maps_apart, mesh, place, register, stretch, turn


def l_sheet(rng):
    nx, ny = int(rng.integers(15, 40)), int(rng.integers(10, 30))
    sx, sy = rng.uniform(0.3, 2), rng.uniform(0.2, 1)
    xs, ys = np.meshgrid(np.linspace(0, sx, nx), np.linspace(0, sy, ny))
    v = np.c_[xs.ravel(), ys.ravel(), np.zeros(nx * ny)]
    cx, cy = int(nx * rng.uniform(0.3, 0.7)), int(ny * rng.uniform(0.3, 0.7))
    cells = [y * nx + x for y in range(ny - 1) for x in range(nx - 1) if not (x >= cx and y >= cy)]
    f = np.array([t for a in cells for t in ([a, a + 1, a + nx + 1], [a, a + nx + 1, a + nx])])
    used = np.unique(f)
    remap = -np.ones(len(v), int)
    remap[used] = np.arange(len(used))
    return f"L {nx}x{ny} cut {cx},{cy}", mesh(v[used], remap[f])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--count", type=int, default=8)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--stretch", type=float, default=0.2)
    ap.add_argument("--turn", type=float, default=30.0)
    ap.add_argument("--random-direction", action="store_true")
    ap.add_argument("--noise", type=float, default=0.0, help="target noise, a share of the diagonal")
    ap.add_argument("--bin", default="target/release/nonrigid_register")
    ap.add_argument("--dir", default="/tmp/l_sheets")
    a = ap.parse_args()
    os.makedirs(a.dir, exist_ok=True)
    rng = np.random.default_rng(a.seed)
    for i in range(a.count):
        name, m = l_sheet(rng)
        v, f = place(m, rng)
        if a.random_direction:
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            c = v.mean(0)
            moved = v + a.stretch * np.outer((v - c) @ axis, axis)
        else:
            moved = stretch(v, a.stretch)
        moved = turn(moved, a.turn, rng)
        noisy = moved
        if a.noise:
            diagonal = np.linalg.norm(np.ptp(moved, 0))
            noisy = moved + a.noise * diagonal * np.random.default_rng([a.seed, i]).normal(size=moved.shape)
        s, t, w = (os.path.join(a.dir, f"{i}_{k}.ply") for k in "stw")
        o3d.io.write_triangle_mesh(s, mesh(v, f))
        o3d.io.write_triangle_mesh(t, mesh(noisy, f))
        r, j = register(a.bin, s, t, w, f"{i:2d} {name:22s}")
        if j is None:
            continue
        apart = maps_apart(j)
        reach = np.linalg.norm(moved - v, axis=1).max()
        e = np.linalg.norm(np.asarray(o3d.io.read_triangle_mesh(w).vertices) - moved, axis=1) / reach
        print(f"{i:2d} {name:22s} exit {r.returncode} registered {j['registered']!s:5s} "
              f"placed_affine {j.get('placed_affine')!s:5s} maps apart {apart} "
              f"error {100 * e.max():5.1f} / {100 * e.mean():5.2f} %")


if __name__ == "__main__":
    main()
