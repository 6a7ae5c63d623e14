"""Symmetric and asymmetric meshes made by Open3D, each registered onto itself bent: does
`nonrigid_register meshes` report the symmetric ones as sliding along themselves (NOTES 179)?

Usage: python bench/symmetric_shapes.py [--count 12] [--seed 20261206] [--bin target/release/nonrigid_register] [--dir /tmp/symmetric]
[--curvature 0.5] [--stretch S] [--turn DEG] [--only asymmetric]
(a Python with open3d 0.20, numpy and scipy). With --stretch, each shape is stretched by 1 + S along
its longest principal axis instead of bent (NOTES 187). With --turn, each target is then turned by
DEG degrees about a random axis and moved by 4.3 % of its diagonal (NOTES 196–197).

Symmetric: spheroids, capped cylinders, tori and cones of random proportions and facet counts.
Asymmetric: ellipsoids of three axes at least 15 % apart, spheres with random low-frequency
bumps (5–20 % of the radius), boxes of random sides, flat sheets of random aspect and
resolution. Each is turned at random, scaled by 0.05–5 and bent along one axis (curvature 0.5
over its diagonal); the line printed per shape is the tool's exit code, `registered`, the share
of the fit's source on the target, the two surfaces' slippage ratios, the round trip's ratio
(NOTES 188; – where it was not run), and the largest and mean distance of a warped vertex
from where the bend (or stretch) sent it (% of the largest displacement).
"""
import argparse
import json
import os
import subprocess

import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

Mesh = o3d.geometry.TriangleMesh


def mesh(v, f):
    return Mesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f))


def symmetric(rng):
    kind = rng.integers(4)
    if kind == 0:
        m = Mesh.create_sphere(1, int(rng.integers(10, 40)))
        m.vertices = o3d.utility.Vector3dVector(np.asarray(m.vertices) * [1, 1, rng.uniform(0.4, 2.5)])
        return "spheroid", m
    if kind == 1:
        return "cylinder", Mesh.create_cylinder(rng.uniform(0.1, 0.5), rng.uniform(0.3, 2), int(rng.integers(12, 60)), int(rng.integers(2, 20)))
    if kind == 2:
        return "torus", Mesh.create_torus(1, rng.uniform(0.1, 0.5), int(rng.integers(20, 80)), int(rng.integers(8, 30)))
    return "cone", Mesh.create_cone(rng.uniform(0.1, 0.5), rng.uniform(0.3, 2), int(rng.integers(12, 60)), int(rng.integers(2, 12)))


def sheet(rng):
    nx, ny = int(rng.integers(8, 60)), int(rng.integers(5, 30))
    sx, sy = rng.uniform(0.1, 2), rng.uniform(0.05, 1)
    xs, ys = np.meshgrid(np.linspace(0, sx, nx), np.linspace(0, sy, ny))
    v = np.c_[xs.ravel(), ys.ravel(), np.zeros(nx * ny)]
    cells = [y * nx + x for y in range(ny - 1) for x in range(nx - 1)]
    f = [t for a in cells for t in ([a, a + 1, a + nx + 1], [a, a + nx + 1, a + nx])]
    return f"sheet {nx}x{ny} {sx / sy:.1f}:1", mesh(v, np.array(f))


def asymmetric(rng):
    kind = rng.integers(4)
    if kind == 0:
        m = Mesh.create_sphere(1, 30)
        a = np.sort(rng.uniform(0.3, 1, 3))
        a[1] = a[0] * rng.uniform(1.15, 1.5)
        a[2] = a[1] * rng.uniform(1.15, 1.5)
        m.vertices = o3d.utility.Vector3dVector(np.asarray(m.vertices) * a)
        return "ellipsoid", m
    if kind == 1:
        m = Mesh.create_sphere(1, 30)
        v = np.asarray(m.vertices)
        r = np.ones(len(v))
        for _ in range(4):
            r += rng.uniform(0.05, 0.2) * np.sin(v @ (rng.normal(size=3) * rng.uniform(1, 3)) + rng.uniform(0, 6))
        m.vertices = o3d.utility.Vector3dVector(v * r[:, None])
        return "blob", m
    if kind == 2:
        return "box", Mesh.create_box(*rng.uniform(0.1, 1, 3)).subdivide_midpoint(int(rng.integers(2, 5)))
    return sheet(rng)


def place(m, rng):
    v = np.asarray(m.vertices)
    turn = Rotation.random(random_state=int(rng.integers(1 << 30)))
    return turn.apply(v - v.mean(0)) * rng.uniform(0.05, 5) + rng.normal(size=3), np.asarray(m.triangles)


def bend(v, curvature):
    c = v.mean(0)
    p = v - c
    r = np.linalg.norm(np.ptp(v, 0)) / curvature
    a = p[:, 0] / r
    return np.c_[(r - p[:, 2]) * np.sin(a), p[:, 1], r - (r - p[:, 2]) * np.cos(a)] + c


def stretch(v, amount):
    c = v.mean(0)
    axis = np.linalg.svd(v - c, full_matrices=False)[2][0]
    return v + amount * np.outer((v - c) @ axis, axis)


def turn(v, degrees, rng):
    """`v` turned by `degrees` about a random axis through its centroid and moved by 4.3 % of
    its bounding-box diagonal in a random direction."""
    c = v.mean(0)
    axis, away = (d / np.linalg.norm(d) for d in rng.normal(size=(2, 3)))
    r = Rotation.from_rotvec(np.radians(degrees) * axis)
    return r.apply(v - c) + c + 0.043 * np.linalg.norm(np.ptp(v, 0)) * away


def register(binary, s, t, w, label):
    """`nonrigid_register meshes S T --output W -q`: the finished process and its JSON line, or
    None for the JSON (printed with `label` and the tool's error) where it gave none."""
    r = subprocess.run([binary, "meshes", s, t, "--output", w, "-q"], capture_output=True, text=True)
    try:
        return r, json.loads(r.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        print(f"{label} exit {r.returncode}: {r.stderr.strip()[-200:]}")
        return r, None


def maps_apart(j):
    """The JSON's `maps_apart` as text: the distance and its limit, or – without it."""
    apart = j.get("maps_apart")
    return "–" if apart is None else f"{apart['apart']:.1e} (one under {apart['limit']:.1e})"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--count", type=int, default=12)
    ap.add_argument("--seed", type=int, default=20261206)
    ap.add_argument("--bin", default="target/release/nonrigid_register")
    ap.add_argument("--dir", default="/tmp/symmetric")
    ap.add_argument("--curvature", type=float, default=0.5, help="the bend's, over the diagonal")
    ap.add_argument("--stretch", type=float, default=None, help="stretch by 1 + S along the longest axis instead")
    ap.add_argument("--only", choices=("symmetric", "asymmetric"), default=None,
                    help="register only these (the shapes made are the same)")
    ap.add_argument("--turn", type=float, default=0.0,
                    help="then turn the target by this many degrees about a random axis and move it by 4.3 %% of its diagonal")
    a = ap.parse_args()
    os.makedirs(a.dir, exist_ok=True)
    rng = np.random.default_rng(a.seed)
    turns = np.random.default_rng([a.seed, 1])  # its own stream: the shapes stay those without --turn
    for kind, make in (("symmetric", symmetric), ("asymmetric", asymmetric)):
        for i in range(a.count):
            name, m = make(rng)
            m.remove_duplicated_vertices()
            v, f = place(m, rng)
            s, t, w = (os.path.join(a.dir, f"{kind}{i}_{k}.ply") for k in "stw")
            moved = bend(v, a.curvature) if a.stretch is None else stretch(v, a.stretch)
            if a.turn:
                moved = turn(moved, a.turn, turns)
            if a.only not in (None, kind):
                continue
            o3d.io.write_triangle_mesh(s, mesh(v, f))
            o3d.io.write_triangle_mesh(t, mesh(moved, f))
            r, j = register(a.bin, s, t, w, f"{kind:10s} {name:22s}")
            if j is None:
                continue
            slip = j["slippage"]
            aff = j.get("affine_slippage") or {}
            nan = float("nan")
            aff = {k: aff.get(k) if aff.get(k) is not None else nan for k in ("source", "target", "departure_from_rigid", "rigid_limit")}
            trip = j.get("round_trip")
            trip = "  –  " if trip is None else f"{trip['ratio']:.3f}"
            apart = maps_apart(j)
            reach = np.linalg.norm(moved - v, axis=1).max()
            e = np.linalg.norm(np.asarray(o3d.io.read_triangle_mesh(w).vertices) - moved, axis=1) / reach
            print(f"{kind:10s} {name:22s} exit {r.returncode} registered {j['registered']!s:5s} "
                  f"on_target {j['fit']['on_target']:.2f} slippage {slip['source']:.1e} {slip['target']:.1e} "
                  f"affine {aff['source']:.1e} {aff['target']:.1e} departure {aff['departure_from_rigid']:.1e} (rigid under {aff['rigid_limit']:.1e}) "
                  f"placed_affine {j.get('placed_affine')!s:5s} placed_rigid {j.get('placed_rigid')!s:5s} "
                  f"maps apart {apart} round trip {trip} "
                  f"error {100 * e.max():5.1f} / {100 * e.mean():5.2f} %")


if __name__ == "__main__":
    main()
