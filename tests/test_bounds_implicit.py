"""Bounds (issue 36): an implicit upper bound u(z) — ``upper=`` an ``Affine`` (u = Bz + c) or a
callable — solved by the Newton member's outer fixed point (each outer step: the box problem with
ζ(z_k) ≤ z ≤ u(z_k) frozen). Checked against an independent numpy reference written here (the outer
fixed point over reference_impl.reference_box_solve, a primal-dual active-set method with exact sparse
solves), against problems built with a known solution, and against the sign conditions at the
returned z with u(z); bad inputs are clear errors naming ``upper``."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from reference_impl import reference_box_solve
from test_bounds import m_matrix

INF = np.inf
AGREE = 1e-10   # relative agreement of z with the reference or the known solution
STATIONARY = ["nrm", "nrmm", "nrmaor", "nrmsor", "nrmgs", "nrmj", "mms", "two_sweep"]


# ---- problems and the reference ---------------------------------------------------------


def small_coupling(n, rng, norm=0.3):
    """A sparse B >= 0 with ‖B‖∞ = norm: u(z) = c + Bz is then a contraction of the outer map on an
    M-matrix with A·1 >= 0 (the box solution moves by at most the bounds' move in the max norm)."""
    B = sp.random(n, n, density=min(1.0, 3.0 / n), random_state=rng, data_rvs=lambda k: rng.uniform(0, 1, k))
    B = sp.csr_matrix(B + sp.eye(n) * 0.5)
    B = sp.csr_matrix(sp.diags(norm / abs(B).sum(axis=1).A1) @ B)
    B.sum_duplicates()
    B.sort_indices()
    return B


def known_problem(A, B, rng):
    """(q, lower, c, z*) with z* the solution of lower <= z <= c + Bz: a third of the rows on the
    upper bound u(z*) (w < 0), a third on the lower one (w > 0), the rest between (w = 0); a sixth of
    the lower bounds -inf (rows free below)."""
    n = A.shape[0]
    z = rng.uniform(-1, 1, n)
    state = rng.integers(0, 3, n)   # 0 at lower, 1 between, 2 at upper
    state[:3] = [0, 1, 2]
    gap = rng.uniform(0.2, 1.0, n)
    c = z - B @ z + np.where(state == 2, 0.0, gap)
    lower = np.where(state == 0, z, z - rng.uniform(0.2, 1.0, n))
    lower[(state != 0) & (rng.uniform(size=n) < 0.25)] = -INF
    w = np.where(state == 0, rng.uniform(0.5, 2, n), np.where(state == 2, -rng.uniform(0.5, 2, n), 0.0))
    return w - A @ z, lower, c, z


def reference_outer(A, q, lower, u_of, zeta_of=None, steps=300):
    """The outer fixed point in numpy: z ← S(ζ(z), u(z)), S the reference box solve; where the frozen
    bounds cross, the upper one wins (the rule of docs/SPEC.md). Ends when z repeats to rounding."""
    z = np.zeros(A.shape[0])
    for _ in range(steps):
        lo = lower if zeta_of is None else zeta_of(z)
        up = u_of(z)
        new = reference_box_solve(A, q, np.minimum(lo, up), up, z0=z).z
        if np.max(np.abs(new - z)) <= 1e-15 * max(1.0, np.max(np.abs(new))):
            return new
        z = new
    raise AssertionError("the reference outer fixed point did not settle")


def assert_mcp_at(A, q, z, lower, upper, mask, tol=1e-9):
    """PATH's sign conditions at z with the bounds' vectors at z (lower, upper), row by row relative
    to |A||z| + |q| + 1, and active_mask consistent with them."""
    w = A @ z + q
    t = tol * (abs(A) @ np.abs(z) + np.abs(q) + 1.0)
    assert np.all(z >= lower - t) and np.all(z <= upper + t)
    at_lower, at_upper = np.abs(z - lower) <= t, np.abs(z - upper) <= t
    between = ~(at_lower | at_upper)
    assert np.all(np.abs(w[between]) <= t[between])
    assert np.all(w[at_lower & ~at_upper] >= -t[at_lower & ~at_upper])
    assert np.all(w[at_upper & ~at_lower] <= t[at_upper & ~at_lower])
    assert np.all(at_upper[mask == 1]) and np.all(at_lower[mask == -1])
    assert np.all(np.abs(w[mask == 0]) <= t[mask == 0])


def rel_err(z, ref):
    return np.linalg.norm(z - ref) / max(np.linalg.norm(ref), 1e-300)


def _small():
    A = sp.csr_matrix(sp.diags([-1.0, 4.0, -1.0], [-1, 0, 1], shape=(6, 6)))
    return A, np.linspace(-2, 2, 6)


# ---- agreement with known solutions and the reference -----------------------------------


@pytest.mark.parametrize("n", [30, 400])
@pytest.mark.parametrize("symmetric", [True, False])
def test_affine_upper_finds_the_known_solution(n, symmetric):
    rng = np.random.default_rng([36, 2, n, symmetric])
    A = m_matrix(n, rng, symmetric)
    B = small_coupling(n, rng)
    q, lower, c, z_star = known_problem(A, B, rng)
    res = nrmicp.solve(A, q, lower, upper=nrmicp.Affine(B, c), tol=1e-12)
    assert res.success and res.method == "newton", res.message
    assert rel_err(res.z, z_star) < AGREE
    assert_mcp_at(A, q, res.z, lower, B @ res.z + c, res.active_mask)
    assert res.outer_iterations >= 2   # the bound moved with z: more than one box solve


@pytest.mark.parametrize("hierarchy", [None, "amg"])
def test_callable_upper_agrees_with_the_numpy_outer_fixed_point(hierarchy):
    """A nonlinear, nonlocal u(z) = c + 0.2 tanh(neighbours' mean of z), ζ None (z >= 0)."""
    rng = np.random.default_rng([36, 3])
    n = 300
    A = m_matrix(n, rng)
    q = rng.uniform(-3, 3, n) * A.diagonal()
    mean = sp.diags(1.0 / (abs(A).sum(axis=1).A1 - A.diagonal())) @ (sp.diags(A.diagonal()) - A)
    c = rng.uniform(0.2, 1.0, n)
    u = lambda z: c + 0.2 * np.tanh(mean @ z)   # noqa: E731
    res = nrmicp.solve(A, q, None, upper=u, tol=1e-12, hierarchy=hierarchy)
    assert res.success, res.message
    ref = reference_outer(A, q, np.zeros(n), u)
    assert rel_err(res.z, ref) < AGREE
    assert_mcp_at(A, q, res.z, np.zeros(n), u(res.z), res.active_mask)
    assert (res.active_mask == 1).sum() > 0 and (res.active_mask == -1).sum() > 0   # both bounds reached


def test_implicit_upper_with_an_implicit_lower_bound():
    """Both bounds depend on z (an Affine ζ and a callable u): one outer fixed point freezes both."""
    rng = np.random.default_rng([36, 4])
    n = 120
    A = m_matrix(n, rng, symmetric=False)
    q = rng.uniform(-3, 3, n) * A.diagonal()
    Bl, Bu = small_coupling(n, rng, 0.2), small_coupling(n, rng, 0.2)
    cl = rng.uniform(-1, -0.5, n)
    cu = rng.uniform(0.5, 1.0, n)
    zeta = nrmicp.Affine(Bl, cl)
    u = lambda z: cu + 0.2 * np.sin(Bu @ z)   # noqa: E731
    res = nrmicp.solve(A, q, zeta, upper=u, tol=1e-12)
    assert res.success, res.message
    ref = reference_outer(A, q, None, u, zeta_of=lambda z: Bl @ z + cl)
    assert rel_err(res.z, ref) < AGREE
    assert_mcp_at(A, q, res.z, Bl @ res.z + cl, u(res.z), res.active_mask)


def test_an_affine_upper_and_the_same_callable_give_the_same_answer():
    rng = np.random.default_rng([36, 5])
    n = 80
    A = m_matrix(n, rng)
    B = small_coupling(n, rng)
    q, lower, c, _ = known_problem(A, B, rng)
    affine = nrmicp.solve(A, q, lower, upper=nrmicp.Affine(B, c), tol=1e-12)
    called = nrmicp.solve(A, q, lower, upper=lambda z: B @ z + c, tol=1e-12)
    assert affine.success and called.success
    np.testing.assert_allclose(called.z, affine.z, rtol=0, atol=1e-12 * np.max(np.abs(affine.z)))
    np.testing.assert_array_equal(called.active_mask, affine.active_mask)


@pytest.mark.parametrize("lower", ["none", "constant", "with -inf"])
def test_a_constant_upper_as_a_callable_is_the_constant_path(lower):
    rng = np.random.default_rng([36, 6, len(lower)])
    n = 100
    A = m_matrix(n, rng)
    q = rng.uniform(-3, 3, n) * A.diagonal()
    lo = {"none": None, "constant": rng.uniform(-1, 0, n),
          "with -inf": np.where(rng.uniform(size=n) < 0.3, -INF, rng.uniform(-1, 0, n))}[lower]
    up = rng.uniform(0.1, 1, n)
    up[::7] = INF
    const = nrmicp.solve(A, q, lo, upper=up, tol=1e-12)
    called = nrmicp.solve(A, q, lo, upper=lambda z: up, tol=1e-12)
    assert const.success and called.success, called.message
    np.testing.assert_allclose(called.z, const.z, rtol=0, atol=1e-11)
    np.testing.assert_array_equal(called.active_mask, const.active_mask)


def test_upper_inf_everywhere_as_a_callable_is_the_obstacle_problem():
    A, q = _small()
    lcp = nrmicp.solve(A, q, np.full(6, -0.2), tol=1e-12)
    called = nrmicp.solve(A, q, np.full(6, -0.2), upper=lambda z: np.full(6, INF), tol=1e-12)
    assert called.success
    np.testing.assert_allclose(called.z, lcp.z, rtol=0, atol=1e-12)
    assert not np.any(called.active_mask == 1)


def test_scaling_and_solver_reuse_with_an_implicit_upper():
    """Rows scaled by 10^±2 (the same solution: a positive row scaling keeps every sign condition),
    solved with scale='both' by one Solver for an Affine and a callable upper."""
    rng = np.random.default_rng([36, 7])
    n = 60
    M = m_matrix(n, rng)
    B = small_coupling(n, rng)
    qM, lower, c, z_star = known_problem(M, B, rng)
    D = sp.diags(10.0 ** rng.uniform(-2, 2, n))
    A, q = sp.csr_matrix(D @ M), D @ qM
    A.sort_indices()
    solver = nrmicp.Solver(A, method="newton", scale="both")
    for upper in (nrmicp.Affine(B, c), lambda z: B @ z + c):
        res = solver.solve(q, lower, upper=upper, tol=1e-10)
        assert res.success, res.message
        assert rel_err(res.z, z_star) < AGREE


def test_residual_takes_upper_at_z():
    A, q = _small()
    z = np.linspace(-0.5, 0.7, 6)
    lower = np.full(6, -0.3)
    u = lambda v: 0.4 - 0.5 * v   # noqa: E731
    w = A @ z + q
    by_hand = np.linalg.norm(np.minimum(z - lower, np.maximum(z - u(z), w)))
    assert nrmicp.residual(A, q, z, lower, upper=u) == pytest.approx(by_hand, rel=1e-14)
    B = sp.csr_matrix(-0.5 * sp.eye(6))
    assert nrmicp.residual(A, q, z, lower, upper=nrmicp.Affine(B, np.full(6, 0.4))) == pytest.approx(by_hand, rel=1e-14)


def test_auto_picks_newton_for_an_implicit_upper():
    A, q = _small()
    res = nrmicp.solve(A, q, upper=lambda z: np.full(6, 0.5))
    assert res.method == "newton" and res.success


# ---- bounds that cross -------------------------------------------------------------------


def test_bounds_that_cross_at_every_z_are_not_a_success_and_say_so():
    """z >= 0 and z <= -1 + 0.1 z: no z lies between (u < 0 wherever z >= 0)."""
    A, q = _small()
    for upper in (lambda z: -1.0 + 0.1 * z, nrmicp.Affine(sp.csr_matrix(0.1 * sp.eye(6)), -np.ones(6))):
        res = nrmicp.solve(A, q, None, upper=upper, maxiter=50)
        assert not res.success
        assert "cross" in res.message and "upper(z)" in res.message and "zeta(z)" in res.message, res.message
        assert res.residual > 0.5   # the term z − ζ(z) = z <= -1 + 0.1 z on every row


# ---- refusals and bad input --------------------------------------------------------------


@pytest.mark.parametrize("method", STATIONARY)
def test_an_implicit_upper_on_a_stationary_method_names_newton(method):
    A, q = _small()
    opts = {"alpha": 1.0} if method in ("nrmm", "nrmsor") else {"alpha": 1.0, "beta": 0.5} if method == "nrmaor" else {}
    for upper in (nrmicp.Affine(sp.csr_matrix(0.1 * sp.eye(6)), np.ones(6)), lambda z: np.ones(6)):
        for zeta in (None, np.zeros(6)):
            with pytest.raises(ValueError, match="'newton'") as exc:
                nrmicp.solve(A, q, zeta, upper=upper, method=method, **opts)
            assert "upper" in str(exc.value)
            with pytest.raises(ValueError, match="'newton'"):
                nrmicp.Solver(A, method=method, **opts).solve(q, zeta, upper=upper)


def test_zeta_jacobian_with_an_implicit_upper_is_refused_naming_both():
    A, q = _small()
    with pytest.raises(ValueError, match="zeta_jacobian") as exc:
        nrmicp.solve(A, q, lambda z: np.zeros(6), upper=lambda z: np.ones(6),
                     zeta_jacobian=lambda z: sp.csr_matrix((6, 6)))
    assert "upper" in str(exc.value)


def _writes_into_z(z):
    z[0] = 1.0
    return np.ones(6)


BAD_IMPLICIT_UPPER = {
    "Affine B of wrong shape": (nrmicp.Affine(sp.eye(5, format="csr"), np.ones(6)), ValueError, "upper.B"),
    "Affine B not a matrix": (nrmicp.Affine("B", np.ones(6)), TypeError, "upper.B"),
    "Affine c of wrong length": (nrmicp.Affine(sp.eye(6, format="csr"), np.ones(5)), ValueError, "upper.c"),
    "Affine c nan": (nrmicp.Affine(sp.eye(6, format="csr"), np.r_[1, 1, np.nan, 1, 1, 1.0]), ValueError, "upper.c"),
    "Affine c -inf": (nrmicp.Affine(sp.eye(6, format="csr"), np.r_[1, 1, -INF, 1, 1, 1.0]), ValueError, "upper.c"),
    "callable of wrong length": (lambda z: np.ones(7), ValueError, "upper(z)"),
    "callable returning nan": (lambda z: np.r_[1, 1, np.nan, 1, 1, 1.0], ValueError, "upper(z)"),
    "callable returning -inf": (lambda z: np.r_[1, 1, 1, -INF, 1, 1.0], ValueError, "upper(z)"),
    "callable returning None": (lambda z: None, TypeError, "upper(z)"),
    "callable returning strings": (lambda z: ["1"] * 6, TypeError, "upper(z)"),
    "callable writing into z": (_writes_into_z, ValueError, "upper(z)"),
}


@pytest.mark.parametrize("name", sorted(BAD_IMPLICIT_UPPER))
def test_bad_implicit_upper_is_a_clear_error_naming_upper(name):
    A, q = _small()
    upper, exc, what = BAD_IMPLICIT_UPPER[name]
    for call in (lambda: nrmicp.solve(A, q, np.zeros(6), upper=upper),
                 lambda: nrmicp.Solver(A, method="newton").solve(q, None, upper=upper),
                 lambda: nrmicp.residual(A, q, np.zeros(6), None, upper=upper)):
        with pytest.raises(exc) as e:
            call()
        assert what in str(e.value), str(e.value)


def test_a_callable_upper_returning_inf_or_a_list_is_accepted():
    """+inf: no bound on that row; a list of numbers is converted as ζ's return value is."""
    A, q = _small()
    up = [0.3, INF, 0.3, INF, 0.3, INF]
    ref = nrmicp.solve(A, q, None, upper=np.array(up), tol=1e-12)
    res = nrmicp.solve(A, q, None, upper=lambda z: up, tol=1e-12)
    assert res.success
    np.testing.assert_allclose(res.z, ref.z, rtol=0, atol=1e-12)


# ---- the scene: a two-sided membrane under a ceiling that sags where the membrane heats it ------


@pytest.mark.parametrize("hierarchy", ["geometric", "amg", None])
def test_heated_two_sided_membrane_agrees_with_its_exact_fixed_point(hierarchy):
    from nrmicp import scenes

    p = scenes.build("two_sided_heated_2d", "small")   # m = 31, n = 961
    h = p.prolongations() if hierarchy == "geometric" else hierarchy
    res = p.solve(method="newton", hierarchy=h, tol=1e-11)
    assert res.success, res.message
    assert rel_err(res.z, p.z_exact) < AGREE
    u = p.upper(res.z)
    assert np.max(p.reference["ceiling"] - u) > 1e-3   # the ceiling did sag
    assert_mcp_at(p.A, p.q, res.z, p.zeta, u, res.active_mask, tol=1e-8)
    assert (res.active_mask == 1).sum() > 0 and (res.active_mask == -1).sum() > 0   # touches both
    assert p.residual(res.z) == pytest.approx(res.residual, rel=1e-6, abs=1e-12)


def test_an_implicit_upper_bound_lifted_to_inf_keeps_the_nested_start_finite():
    # The nested start re-takes u at each level and moves a row at its old upper bound to the new one: where
    # u(z) lifts the bound to +inf (no bound there) the row must become free, not start at +inf (a review's
    # case: the start went non-finite and the solve reported DIVERGED).
    k = 8
    n, h = 2 ** k - 1, 1.0 / 2 ** k
    x = np.arange(1, n + 1) * h
    A = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr")
    q, lower = -h * h * 50 * np.sin(2 * np.pi * x), np.full(n, -0.3)

    def interpolation(nc):
        rows = [r for j in range(nc) for r in (2 * j + 1, 2 * j, 2 * j + 2)]
        cols = [j for j in range(nc) for _ in range(3)]
        return sp.csr_matrix(([1.0, 0.5, 0.5] * nc, (rows, cols)), shape=(2 * nc + 1, nc))
    hierarchy, nc = [], (n - 1) // 2
    while nc >= 3:
        hierarchy.append(interpolation(nc))
        nc = (nc - 1) // 2
    left, middle = x < 0.2, (x >= 0.3) & (x < 0.45)

    def upper(z):   # the ceiling 0.25 over x < 0.2 is lifted once the membrane presses it further right
        u = np.full(n, 0.25)
        if np.mean(z[middle]) > 0.2:
            u[left] = np.inf
        return u
    lifted = np.full(n, 0.25)
    lifted[left] = np.inf
    ref = reference_box_solve(A, q, lower, lifted).z
    assert np.array_equal(upper(ref), lifted)   # the fixed point: the lifted ceiling
    for h_ in (hierarchy, None):
        res = nrmicp.solve(A, q, lower, upper=upper, method="newton", hierarchy=h_)
        assert res.success and np.all(np.isfinite(res.z)), res.message
        assert np.max(np.abs(res.z - ref)) < 1e-10
        assert_mcp_at(A, q, res.z, lower, upper(res.z), res.active_mask)
