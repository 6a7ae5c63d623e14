"""The solver from Python: residuals written in Python (analytic and numeric Jacobians), the
built-in residuals on every manifold, kernels, fixed variables, bounds, covariance, the summary,
and the errors."""

import math

import numpy as np
import pytest

import dynamap
from conftest import quaternion


def cubic_data(seed, n=60, noise=0.05):
    rng = np.random.default_rng(seed)
    x = np.linspace(-2, 2, n)
    y = 0.3 * x**3 - x**2 + 0.5 * x + 2 + rng.normal(0, noise, n)
    return x, y


def fit(x, y, jacobians, kernel=None):
    """A cubic through (x, y), one Python residual per point."""
    problem = dynamap.Problem()
    c = problem.add_variable(np.zeros(4))
    for xi, yi in zip(x, y):
        powers = np.array([xi**3, xi**2, xi, 1.0])
        if jacobians == "analytic":
            f = lambda c, p=powers, yi=yi: (np.array([p @ c - yi]), [p.reshape(1, 4)])
        else:
            f = lambda c, p=powers, yi=yi: np.array([p @ c - yi])
        problem.add_residual(f, [c], dim=1, jacobians=jacobians, kernel=kernel)
    return problem, c


@pytest.mark.parametrize("seed", [1, 2])
def test_a_python_curve_fit_reaches_the_least_squares_optimum(seed):
    x, y = cubic_data(seed)
    optimum = np.linalg.lstsq(np.vander(x, 4), y, rcond=None)[0]
    problem, c = fit(x, y, "analytic")
    summary = problem.solve()
    assert summary.converged, summary.termination
    np.testing.assert_allclose(problem.value(c), optimum, rtol=0, atol=1e-9)
    residual = np.vander(x, 4) @ optimum - y
    assert abs(summary.final_cost - 0.5 * residual @ residual) <= 1e-12


def test_numeric_jacobians_reach_the_same_optimum():
    x, y = cubic_data(3)
    optimum = np.linalg.lstsq(np.vander(x, 4), y, rcond=None)[0]
    problem, c = fit(x, y, "numeric")
    assert problem.solve().converged
    np.testing.assert_allclose(problem.value(c), optimum, rtol=0, atol=1e-7)


def exponential(y):
    """y = exp(m x + c) on x in [0, 5], one Python residual per point."""
    x = np.linspace(0, 5, len(y))
    problem = dynamap.Problem()
    mc = problem.add_variable([0.0, 0.0])

    def residual(p, xi, yi):
        e = math.exp(p[0] * xi + p[1])
        return np.array([e - yi]), [np.array([[xi * e, e]])]

    for xi, yi in zip(x, y):
        problem.add_residual(lambda p, xi=xi, yi=yi: residual(p, xi, yi), [mc], dim=1)
    return problem, mc


def test_an_exponential_model_recovers_its_parameters_from_exact_data():
    # Ceres' curve-fitting example, y = exp(m x + c), without noise: the optimum is (m, c)
    problem, mc = exponential(np.exp(0.3 * np.linspace(0, 5, 40) + 0.1))
    summary = problem.solve()
    assert summary.converged
    np.testing.assert_allclose(problem.value(mc), [0.3, 0.1], atol=1e-9)
    assert summary.final_cost < 1e-20


def test_a_kernel_keeps_outliers_from_dragging_the_fit():
    x, y = cubic_data(4, noise=0.01)
    y[::10] += 5.0
    truth = np.array([0.3, -1, 0.5, 2])
    plain, c0 = fit(x, y, "analytic")
    plain.solve()
    robust, c1 = fit(x, y, "analytic", kernel=("cauchy", 0.1))
    assert robust.solve().converged
    assert np.abs(robust.value(c1) - truth).max() < 0.05 < np.abs(plain.value(c0) - truth).max()


def test_builtin_factors_chain_poses_on_se2_and_se3():
    # a prior on the first pose and a between factor: the second pose is their composition
    p = dynamap.Problem()
    a = p.add_variable([0.0, 0.0, 0.0], "se2")
    b = p.add_variable([0.0, 0.0, 0.0], "se2")
    p.add_residual(dynamap.prior_se2([1.0, 2.0, math.pi / 2], np.eye(3)), [a])
    p.add_residual(dynamap.between_se2([1.0, 0.0, 0.0], np.eye(3) * 4), [a, b])
    assert p.solve().converged
    np.testing.assert_allclose(p.value(b), [1.0, 3.0, math.pi / 2], atol=1e-9)

    q = dynamap.Problem()
    a = q.add_variable([0, 0, 0, 0, 0, 0, 1], "se3")
    b = q.add_variable([0, 0, 0, 0, 0, 0, 1], "se3")
    za = [1.0, 0.0, 0.0, *quaternion([0, 0, math.pi / 2])]
    q.add_residual(dynamap.prior_se3(za, np.eye(6)), [a])
    q.add_residual(dynamap.between_se3([2.0, 0, 0, 0, 0, 0, 1], np.eye(6)), [a, b])
    assert q.solve().converged
    expected = [1.0, 2.0, 0.0, *quaternion([0, 0, math.pi / 2])]
    np.testing.assert_allclose(q.value(b), expected, atol=1e-9)


@pytest.mark.parametrize("manifold,start,tangent", [("quaternion", [0, 0, 0, 1], 3), ("so3", np.eye(3).flatten(), 3), ("so2", [0.3], 1)])
def test_a_python_residual_on_a_rotation_manifold_reaches_its_target(manifold, start, tangent):
    # r = the ambient difference from a target; numeric Jacobians through the manifold's ⊞
    if manifold == "quaternion":
        target = quaternion([0.2, -0.4, 0.9])
    elif manifold == "so3":
        target = dynamap_rotation([0.2, -0.4, 0.9]).flatten(order="F")
    else:
        target = np.array([-1.2])
    p = dynamap.Problem()
    v = p.add_variable(start, manifold)
    p.add_residual(lambda x: x - target, [v], dim=len(target), jacobians="numeric")
    s = p.solve()
    assert s.converged and s.unknowns == tangent
    np.testing.assert_allclose(p.value(v), target, atol=1e-8)


def dynamap_rotation(w):
    from conftest import rotation

    return rotation(quaternion(w))


def test_fixed_variables_stay_and_bounds_hold():
    p = dynamap.Problem()
    x = p.add_variable([0.0])
    y = p.add_variable([3.0])
    p.add_residual(lambda x, y: (np.array([x[0] - 1.0, y[0] - x[0]]), [np.array([[1.0], [-1.0]]), np.array([[0.0], [1.0]])]), [x, y], dim=2)
    p.set_fixed(y)
    p.set_bounds(x, [-1.0], [0.5])
    s = p.solve()
    assert s.converged and p.is_fixed(y)
    assert p.value(y)[0] == 3.0
    assert abs(p.value(x)[0] - 0.5) < 1e-9


def test_the_covariance_of_a_prior_is_its_information_inverted():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(6, 6))
    info = a @ a.T + 6 * np.eye(6)
    p = dynamap.Problem()
    v = p.add_variable([0.1, 0.2, 0.3, *quaternion([0.1, 0.2, 0.3])], "se3")
    p.add_residual(dynamap.prior_se3([0.1, 0.2, 0.3, *quaternion([0.1, 0.2, 0.3])], info), [v])
    (cov,) = p.covariance([v])
    np.testing.assert_allclose(cov, np.linalg.inv(info), rtol=1e-9, atol=1e-15)


def test_the_summary_reports_each_iteration_and_a_solve_that_did_not_converge():
    problem, _ = exponential(np.exp(0.3 * np.linspace(0, 5, 40) + 0.1))
    s = problem.solve(dynamap.Options(max_iterations=1, algorithm="dogleg"))
    assert not s.converged and s.termination == "iteration limit reached"
    assert [it["iteration"] for it in s.iterations] == [0, 1]
    assert s.iterations[0]["cost"] == s.initial_cost and s.iterations[-1]["cost"] == s.final_cost
    assert "iter" in s.table() and "stopped after 1 iterations" in s.table()
    assert set(s.timing) == {"setup", "evaluate", "assemble", "factorise", "step"}
    o = dynamap.Options(linear_solver="sparse", damping="diagonal")
    o.function_tolerance = 1e-12
    assert (o.linear_solver, o.damping, o.function_tolerance) == ("sparse", "diagonal", 1e-12)


def test_an_exception_in_a_python_residual_is_raised_by_solve():
    p = dynamap.Problem()
    x = p.add_variable([0.0])
    calls = []

    def fails(x):
        calls.append(1)
        if len(calls) > 3:
            raise RuntimeError("the model broke")
        return np.array([x[0] - 1.0]), [np.ones((1, 1))]

    p.add_residual(fails, [x], dim=1)
    with pytest.raises(RuntimeError, match="the model broke"):
        p.solve()
    assert np.isfinite(p.value(x)).all()


def test_a_python_residual_of_the_wrong_shape_is_named():
    p = dynamap.Problem()
    x = p.add_variable([0.0, 0.0])
    p.add_residual(lambda x: (x, [np.eye(2)]), [x], dim=2)
    p.add_residual(lambda x: (x, [np.eye(3)]), [x], dim=2)
    with pytest.raises(ValueError, match=r"residual block 1: Jacobian block 0 has shape \[3, 3\], expected \(2, 2\)"):
        p.solve()
    q = dynamap.Problem()
    y = q.add_variable([0.0])
    q.add_residual(lambda y: np.array([1.0, 2.0]), [y], dim=1, jacobians="numeric")
    with pytest.raises(ValueError, match="residual block 0: returned 2 residual rows, 1 were declared"):
        q.solve()


def test_bad_problem_definitions_raise_clear_errors():
    p = dynamap.Problem()
    x = p.add_variable([0.0])
    with pytest.raises(ValueError, match="unknown manifold 'se4'"):
        p.add_variable([0.0], "se4")
    with pytest.raises(dynamap.ProblemError, match="expected 7 coordinates, got 3"):
        p.add_variable([0.0, 0.0, 0.0], "se3")
    with pytest.raises(dynamap.ProblemError, match="not finite"):
        p.add_variable([math.nan])
    with pytest.raises(IndexError, match="variable 5 does not exist"):
        p.add_residual(lambda v: np.zeros(1), [5], dim=1, jacobians="numeric")
    with pytest.raises(ValueError, match="needs dim"):
        p.add_residual(lambda v: np.zeros(1), [x])
    with pytest.raises(ValueError, match="dim=0: a residual written in Python has at least one row"):
        p.add_residual(lambda v: np.zeros(0), [x], dim=0, jacobians="numeric")
    with pytest.raises(ValueError, match="unknown robust kernel 'hubber'"):
        p.add_residual(lambda v: np.zeros(1), [x], dim=1, kernel="hubber:1")
    with pytest.raises(ValueError, match="jacobians='auto'"):
        p.add_residual(lambda v: np.zeros(1), [x], dim=1, jacobians="auto")
    with pytest.raises(dynamap.ProblemError, match="residual expects 2 variables, got 1"):
        p.add_residual(dynamap.between_se2([0, 0, 0], np.eye(3)), [x])
    with pytest.raises(ValueError, match="not symmetric positive definite"):
        dynamap.between_se3([0, 0, 0, 0, 0, 0, 1], -np.eye(6))
    # a residual on variables of other sizes than it reads, a measurement that is no pose, a
    # point that is not finite (NOTES 170)
    a, b = p.add_variable([0.0, 0.0, 0.0]), p.add_variable([0.0, 0.0, 0.0])
    with pytest.raises(dynamap.ProblemError, match="expects 7 and 6"):
        p.add_residual(dynamap.between_se3([0, 0, 0, 0, 0, 0, 1], np.eye(6)), [a, b])
    with pytest.raises(ValueError, match="measurement: quaternion has norm 0"):
        dynamap.between_se3([0, 0, 0, 0, 0, 0, 0], np.eye(6))
    with pytest.raises(ValueError, match="measurement: .*not finite"):
        dynamap.prior_se2([0, math.nan, 0], np.eye(3))
    with pytest.raises(ValueError, match="must be finite"):
        dynamap.point_to_plane([math.nan, 0, 0], [0, 0, 0], [0, 0, 1])
    with pytest.raises(ValueError, match="Options has no field 'max_iteration'"):
        dynamap.Options(max_iteration=3)
    with pytest.raises(ValueError, match="unknown linear solver 'cg'"):
        dynamap.Options(linear_solver="cg")
    q = dynamap.Problem()
    q.add_variable([0.0])
    with pytest.raises(dynamap.SolveError, match="variable 0 is touched by no residual"):
        q.solve()


def test_python_residuals_are_called_on_the_calling_thread():
    import threading

    seen = set()
    x, y = cubic_data(7)
    problem = dynamap.Problem()
    c = problem.add_variable(np.zeros(4))
    for xi, yi in zip(x, y):
        powers = np.array([xi**3, xi**2, xi, 1.0])

        def f(c, p=powers, yi=yi):
            seen.add(threading.get_ident())
            return np.array([p @ c - yi]), [p.reshape(1, 4)]

        problem.add_residual(f, [c], dim=1)
    assert problem.solve().converged
    assert seen == {threading.get_ident()}


def se3_translation_residual(right):
    """r = t(X) − target on SE(3); its Jacobian for X ⊞ δ = X Exp(δ), δ = [ω; v], is [0, R]
    (or a wrong [0, I] when `right` is False)."""
    from conftest import rotation

    target = np.array([0.3, -0.2, 1.0])

    def f(x):
        r = rotation(x[3:])
        j = np.hstack([np.zeros((3, 3)), r if right else np.eye(3)])
        return x[:3] - target, [j]

    return f


@pytest.mark.parametrize("seed", range(5))
def test_check_jacobians_passes_right_jacobians_and_catches_wrong_ones(seed):
    rng = np.random.default_rng(seed)
    pose = np.concatenate([rng.normal(size=3), quaternion(rng.normal(size=3))])
    good = dynamap.check_jacobians(se3_translation_residual(True), [pose], ["se3"], dim=3)
    assert good["max_rel_error"] < 1e-6, good
    bad = dynamap.check_jacobians(se3_translation_residual(False), [pose], ["se3"], dim=3)
    assert bad["max_rel_error"] > 1e-2 and bad["worst_entry"][0] == 0, bad
    other = np.concatenate([rng.normal(size=3), quaternion(rng.normal(size=3))])
    z = np.concatenate([rng.normal(size=3), quaternion(rng.normal(size=3))])
    builtin = dynamap.check_jacobians(dynamap.between_se3(z, np.eye(6)), [pose, other], ["se3", "se3"])
    assert builtin["max_rel_error"] < 1e-6, builtin


def test_check_jacobians_refuses_what_it_cannot_check():
    with pytest.raises(ValueError, match="takes 2 variables, 1 values"):
        dynamap.check_jacobians(dynamap.between_se2([0, 0, 0], np.eye(3)), [[0, 0, 0]], ["se2"])
    with pytest.raises(ValueError, match="value 0: expected 7 coordinates"):
        dynamap.check_jacobians(dynamap.prior_se3([0, 0, 0, 0, 0, 0, 1], np.eye(6)), [[0, 0, 0]], ["se3"])
    with pytest.raises(ZeroDivisionError):
        dynamap.check_jacobians(lambda x: 1 / 0, [[0.0]], dim=1)
    # an SE(3) residual on vectors (the manifolds left at their default): a panic before NOTES 170
    with pytest.raises(ValueError, match="value 0: the residual expects a variable of 7 coordinates and 6"):
        dynamap.check_jacobians(dynamap.between_se3([0, 0, 0, 0, 0, 0, 1], np.eye(6)), [[0, 0, 0, 0, 0, 0, 1]] * 2)
