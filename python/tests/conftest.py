"""Shared helpers of the Python tests: generated g2o graphs and the path of the Rust binaries."""

import math
import os
import pathlib

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]


def binary(name):
    """The Rust tool `name` from $DYNAMAP_BIN or the workspace's target/release (built by
    `cargo test --release` or `cargo build --release -p dynamap-apps`)."""
    folder = pathlib.Path(os.environ.get("DYNAMAP_BIN", ROOT / "target" / "release"))
    path = folder / name
    if not path.is_file():
        pytest.fail(f"{path} is missing: build it with `cargo build --release -p dynamap-apps`")
    return path


def quaternion(axis_angle):
    """[qx, qy, qz, qw] of a rotation vector."""
    angle = float(np.linalg.norm(axis_angle))
    if angle < 1e-12:
        return np.array([0.0, 0.0, 0.0, 1.0])
    axis = np.asarray(axis_angle) / angle
    return np.concatenate([axis * math.sin(angle / 2), [math.cos(angle / 2)]])


def rotation(q):
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def quaternion_of(r):
    """[qx, qy, qz, qw] of a rotation matrix (Shepperd's method)."""
    t = np.trace(r)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        return np.array([(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, s / 4])
    i = int(np.argmax(np.diag(r)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = math.sqrt(1.0 + r[i, i] - r[j, j] - r[k, k]) * 2
    q = np.zeros(4)
    q[i] = s / 4
    q[j] = (r[j, i] + r[i, j]) / s
    q[k] = (r[k, i] + r[i, k]) / s
    q[3] = (r[k, j] - r[j, k]) / s
    return q


def _num(x):
    """A number as text that reads back exactly."""
    return repr(float(x))


def _wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def write_graph_2d(path, n, seed, loops=20):
    """A 2-D walk round a circle with noisy odometry and loop closures, started from the noisy
    odometry: its optimum is not known in closed form, but every solver reaches the same one."""
    rng = np.random.default_rng(seed)
    truth = [np.array([5 * math.cos(2 * math.pi * k / n), 5 * math.sin(2 * math.pi * k / n), 2 * math.pi * k / n + math.pi / 2]) for k in range(n)]

    def between(a, b):
        c, s = math.cos(a[2]), math.sin(a[2])
        d = b[:2] - a[:2]
        return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], _wrap(b[2] - a[2])])

    def compose(a, z):
        c, s = math.cos(a[2]), math.sin(a[2])
        return np.array([a[0] + c * z[0] - s * z[1], a[1] + s * z[0] + c * z[1], _wrap(a[2] + z[2])])

    sigma = np.array([0.05, 0.05, 0.01])
    edges = [(k, k + 1) for k in range(n - 1)]
    edges += [tuple(sorted(rng.choice(n, 2, replace=False))) for _ in range(loops)]
    lines, start = [], [truth[0]]
    measured = {}
    for i, j in edges:
        measured[(i, j)] = between(truth[i], truth[j]) + rng.normal(0, sigma)
    for k in range(n - 1):
        start.append(compose(start[-1], measured[(k, k + 1)]))
    for k, p in enumerate(start):
        lines.append(f"VERTEX_SE2 {k} " + " ".join(map(_num, p)))
    info = 1 / sigma**2
    for i, j in edges:
        z = measured[(i, j)]
        values = [*z, info[0], 0, 0, info[1], 0, info[2]]
        lines.append(f"EDGE_SE2 {i} {j} " + " ".join(map(_num, values)))
    pathlib.Path(path).write_text("\n".join(lines) + "\n")


def write_graph_3d(path, n, seed, loops=15):
    """A 3-D helix with noisy odometry and loop closures, started from the noisy odometry."""
    rng = np.random.default_rng(seed)
    poses = []
    for k in range(n):
        a = 2 * math.pi * k / 40
        r = rotation(quaternion([0.0, 0.0, a + math.pi / 2]))
        poses.append((r, np.array([4 * math.cos(a), 4 * math.sin(a), 0.05 * k])))

    def between(a, b):
        return a[0].T @ b[0], a[0].T @ (b[1] - a[1])

    def noisy(z):
        dr = rotation(quaternion(rng.normal(0, 0.01, 3)))
        return z[0] @ dr, z[1] + rng.normal(0, 0.05, 3)

    edges = [(k, k + 1) for k in range(n - 1)]
    edges += [tuple(sorted(rng.choice(n, 2, replace=False))) for _ in range(loops)]
    measured = {e: noisy(between(poses[e[0]], poses[e[1]])) for e in edges}
    start = [poses[0]]
    for k in range(n - 1):
        r, t = start[-1]
        zr, zt = measured[(k, k + 1)]
        start.append((r @ zr, t + r @ zt))
    lines = []
    for k, (r, t) in enumerate(start):
        q = quaternion_of(r)
        lines.append(f"VERTEX_SE3:QUAT {k} " + " ".join(map(_num, [*t, *q])))
    # g2o's order: translation first, then rotation
    info = np.diag([1 / 0.05**2] * 3 + [1 / 0.01**2] * 3)
    upper = " ".join(_num(info[a, b]) for a in range(6) for b in range(a, 6))
    for i, j in edges:
        zr, zt = measured[(i, j)]
        q = quaternion_of(zr)
        lines.append(f"EDGE_SE3:QUAT {i} {j} " + " ".join(map(_num, [*zt, *q])) + " " + upper)
    pathlib.Path(path).write_text("\n".join(lines) + "\n")
