"""Bundle adjustment from Python: problems built from numpy arrays, BAL files in and out, and the
same optimum as the `bundle_adjustment` tool."""

import json
import subprocess

import numpy as np
import pytest

import dynamap
from conftest import binary


def rodrigues(w, x):
    theta = np.linalg.norm(w)
    if theta < 1e-12:
        return x + np.cross(w, x)
    k = w / theta
    return x * np.cos(theta) + np.cross(k, x) * np.sin(theta) + k * (k @ x) * (1 - np.cos(theta))


def project(camera, point):
    """BAL's camera model: P = R(ω) X + t, p = −P_xy / P_z, uv = f (1 + k₁ r² + k₂ r⁴) p."""
    p = rodrigues(camera[:3], point) + camera[3:6]
    p = -p[:2] / p[2]
    r2 = p @ p
    return camera[6] * (1 + camera[7] * r2 + camera[8] * r2 * r2) * p


def scene(seed, cameras=6, points=80):
    """Cameras on an arc looking at a cloud of points, exact observations."""
    rng = np.random.default_rng(seed)
    cams = []
    for k in range(cameras):
        a = 0.15 * (k - cameras / 2)
        w = np.array([0.0, a, 0.0])
        # the camera looks down −z: points at z ≈ −6 in front of it
        centre = np.array([3 * np.sin(a), 0.0, 3 * (1 - np.cos(a))])
        t = -rodrigues(w, centre)
        cams.append(np.concatenate([w, t, [500.0, 1e-3, -1e-4]]))
    pts = rng.normal(0, 1, (points, 3)) + [0, 0, -6]
    ci, pi, uv = [], [], []
    for j, x in enumerate(pts):
        for c in range(cameras):
            if rng.random() < 0.7 or c == j % cameras:
                ci.append(c)
                pi.append(j)
                uv.append(project(cams[c], x))
    return np.array(cams), pts, np.array(ci), np.array(pi), np.array(uv)


def test_a_problem_built_from_arrays_returns_to_its_exact_optimum():
    cams, pts, ci, pi, uv = scene(1)
    rng = np.random.default_rng(2)
    start_pts = pts + rng.normal(0, 0.02, pts.shape)
    start_cams = cams + np.concatenate([rng.normal(0, 1e-3, (len(cams), 6)), np.zeros((len(cams), 3))], axis=1)
    problem = dynamap.BalProblem(start_cams, start_pts, ci, pi, uv)
    assert problem.cost() > 1.0
    summary = problem.solve(max_iterations=100)
    assert summary.converged, summary.termination
    assert summary.final_cost < 1e-16 and problem.cost() < 1e-16
    (got_ci, got_pi, got_uv) = problem.observations
    np.testing.assert_array_equal(got_ci, ci)
    np.testing.assert_array_equal(got_pi, pi)
    np.testing.assert_array_equal(got_uv, uv)
    # the tool's --no-retriangulate: the same optimum from the same start
    again = dynamap.BalProblem(start_cams, start_pts, ci, pi, uv)
    plain = again.solve(max_iterations=100, retriangulate=False)
    assert plain.converged and plain.final_cost < 1e-16


def test_python_reaches_the_cost_of_the_bundle_adjustment_tool(tmp_path):
    cams, pts, ci, pi, uv = scene(3, cameras=8, points=120)
    rng = np.random.default_rng(4)
    uv = uv + rng.normal(0, 0.5, uv.shape)
    uv[::25] += 40.0  # outliers, for the kernel
    path = tmp_path / "problem.txt"
    dynamap.BalProblem(cams, pts + rng.normal(0, 0.01, pts.shape), ci, pi, uv).write(path)
    out = subprocess.run([binary("bundle_adjustment"), str(path), "--quiet", "--huber", "2"], check=True, capture_output=True, text=True)
    expected = json.loads(out.stdout.strip().splitlines()[-1])
    cameras, points, summary = dynamap.solve_bal(path, kernel="huber:2")
    assert abs(summary.final_cost - expected["cost_final"]) <= 1e-9 * expected["cost_final"]
    assert summary.num_iterations == expected["iterations"]
    assert cameras.shape == (8, 9) and points.shape == (120, 3)


def test_a_written_problem_reads_back_the_same(tmp_path):
    cams, pts, ci, pi, uv = scene(5)
    path = tmp_path / "p.txt"
    dynamap.BalProblem(cams, pts, ci, pi, uv).write(path)
    back = dynamap.BalProblem.read(path)
    np.testing.assert_array_equal(back.cameras, cams)
    np.testing.assert_array_equal(back.points, pts)
    np.testing.assert_array_equal(back.observations[2], uv)


def test_bad_bal_input_is_refused_clearly(tmp_path):
    cams, pts, ci, pi, uv = scene(6)
    with pytest.raises(ValueError, match="observation 0: point index 80 is outside 0..80"):
        bad = pi.copy()
        bad[0] = 80
        dynamap.BalProblem(cams, pts, ci, bad, uv)
    with pytest.raises(ValueError, match="cameras: expected n x 9"):
        dynamap.BalProblem(cams[:, :8], pts, ci, pi, uv)
    with pytest.raises(ValueError, match="differ in number"):
        dynamap.BalProblem(cams, pts, ci[:-1], pi, uv)
    path = tmp_path / "short.txt"
    path.write_text("2 1 1\n0 0 1.0 2.0\n1 2 3\n")
    with pytest.raises(dynamap.InputError, match="short.txt:"):
        dynamap.BalProblem.read(path)
    with pytest.raises(ValueError, match="linear_solver='qr'"):
        dynamap.BalProblem(cams, pts, ci, pi, uv).solve(linear_solver="qr")
