"""Bounds (issue 36): lower <= z <= upper with infinite entries — the mixed complementarity problem
in PATH's and PETSc's convention (w = Az + q >= 0 where z = lower, <= 0 where z = upper, = 0
strictly between), solved by the Newton member. Checked against an independent reference
(reference_impl.reference_box_solve: a primal-dual active-set method with exact sparse solves, on
M-matrices and symmetric positive definite A, where it ends at the solution), known solutions and
the conditions themselves; bad bounds are clear exceptions naming the argument."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import nrmicp
from problems import readme_membrane
from reference_impl import box_residual, reference_box_solve
from snapshots import assert_unchanged, snapshot

INF = np.inf
AGREE = 1e-10   # relative agreement of z with the reference (exact solves on both sides)


# ---- problems ----------------------------------------------------------------------------


def m_matrix(n, rng, symmetric=True):
    """A random sparse nonsingular M-matrix (non-positive off-diagonal, strictly diagonally dominant)."""
    R = sp.random(n, n, density=min(1.0, 4.0 / n), random_state=rng, data_rvs=lambda k: rng.uniform(0, 1, k))
    R = sp.csr_matrix(R)
    R.setdiag(0)
    R.eliminate_zeros()
    if symmetric:
        R = (R + R.T) / 2
    return sp.csr_matrix(sp.diags(abs(R).sum(axis=1).A1 + rng.uniform(0.1, 1.0, n)) - R)


def spd_matrix(n, rng):
    """Symmetric, off-diagonal entries of both signs, strictly diagonally dominant: positive
    definite, not an M-matrix."""
    R = sp.random(n, n, density=min(1.0, 4.0 / n), random_state=rng, data_rvs=lambda k: rng.uniform(-1, 1, k))
    R = sp.csr_matrix(R + R.T)
    R.setdiag(0)
    R.eliminate_zeros()
    return sp.csr_matrix(R + sp.diags(abs(R).sum(axis=1).A1 + rng.uniform(0.1, 1.0, n)))


MATRICES = {"M sym": lambda n, rng: m_matrix(n, rng, True), "M nonsym": lambda n, rng: m_matrix(n, rng, False),
            "SPD": spd_matrix}

#: Row kinds of mixed_bounds: finite on both sides, lower only, upper only (lower -inf), free, fixed.
ROW_KINDS = ("two-sided", "lower only", "upper only", "free", "fixed")


def mixed_bounds(n, rng, p=(0.4, 0.15, 0.2, 0.15, 0.1)):
    """(lower, upper, kind per row) with every ROW_KINDS present for n >= 20."""
    kinds = rng.choice(len(ROW_KINDS), size=n, p=p)
    kinds[:len(ROW_KINDS)] = np.arange(len(ROW_KINDS))
    lower = rng.uniform(-1, 0, n)
    upper = lower + rng.uniform(0.1, 2, n)
    lower[kinds == 2] = -INF
    lower[kinds == 3] = -INF
    upper[(kinds == 1) | (kinds == 3)] = INF
    upper[kinds == 4] = lower[kinds == 4]
    return lower, upper, kinds


def random_q(A, rng):
    """q on the scale of A's diagonal: both bounds and the inside all reached."""
    return rng.uniform(-3, 3, A.shape[0]) * A.diagonal()


def random_box_problem(A, rng):
    """q, lower, upper of a random mixed box problem for A (mixed_bounds, then random_q, in that order)."""
    lower, upper, _ = mixed_bounds(A.shape[0], rng)
    return random_q(A, rng), lower, upper


def known_problem(A, rng):
    """(q, lower, upper, z*, state*) with the solution z* known: per row at its lower bound with w > 0
    (state -1), at its upper bound with w < 0 (+1), strictly between or free with w = 0 (0), fixed
    (lower = upper, w of either sign; state by w's sign, as active_mask reads it). q = w* - A z*."""
    n = A.shape[0]
    lower, upper, kinds = mixed_bounds(n, rng)
    state = rng.choice([-1, 0, 1], size=n)
    state[kinds == 3] = 0                       # free: w = 0
    state[(kinds == 1) & (state == 1)] = -1     # no upper bound to be at
    state[(kinds == 2) & (state == -1)] = 1     # no lower bound to be at
    z = np.where(state < 0, lower, np.where(state > 0, upper, 0.0))
    between = state == 0
    lo, hi = np.where(np.isfinite(lower), lower, -2.0), np.where(np.isfinite(upper), upper, 2.0)
    z[between] = lo[between] + rng.uniform(0.2, 0.8, between.sum()) * (hi - lo)[between]
    w = np.where(state < 0, rng.uniform(0.5, 1.5, n), np.where(state > 0, -rng.uniform(0.5, 1.5, n), 0.0))
    fixed = kinds == 4
    z[fixed] = lower[fixed]
    w[fixed] = rng.choice([-1.0, 1.0], fixed.sum()) * rng.uniform(0.5, 1.5, fixed.sum())
    state[fixed] = np.where(w[fixed] < 0, 1, -1)
    return w - A @ z, lower, upper, z, state


def two_sided_membrane(m, curved=True):
    """The README's membrane (A = -Delta_h on an m x m grid) pushed up on the right half and down on
    the left (f = 20 sign(x - 1/2), q = -f) between a lower and an upper obstacle: -/+(0.05 +
    0.2 (y - 1/2)^2) (curved), or -/+0.05 (flat). Both in contact (1171 rows each at m = 63)."""
    A, _, _ = readme_membrane(m)
    x = np.linspace(1, m, m) / (m + 1)
    X, Y = np.meshgrid(x, x)
    gap = (0.05 + 0.2 * (Y - 0.5) ** 2 if curved else np.full_like(Y, 0.05)).ravel()
    return A, -20.0 * np.sign(X - 0.5).ravel(), -gap, gap


def prolongations(m):
    """Bilinear interpolation of an m x m grid (m = 2^k - 1) from ((m - 1)/2)^2 nodes, down to 3 x 3."""
    Ps = []
    while m >= 7:
        mc = (m - 1) // 2
        rows = np.r_[2 * np.arange(mc) + 1, 2 * np.arange(mc), 2 * np.arange(mc) + 2]
        P1 = sp.csr_matrix((np.r_[np.ones(mc), np.full(2 * mc, 0.5)], (rows, np.tile(np.arange(mc), 3))),
                           shape=(m, mc))
        Ps.append(sp.csr_matrix(sp.kron(P1, P1)))
        m = mc
    return Ps


# ---- checks ------------------------------------------------------------------------------


def slack(lower, upper):
    """Two ulps of the larger finite bound of each row: the rounding a row at a bound may carry,
    since the core solves in y = z - lower (test_a_row_at_its_upper_bound_is_the_bound_exactly)."""
    big = np.maximum(np.abs(np.where(np.isfinite(lower), lower, 0.0)), np.abs(np.where(np.isfinite(upper), upper, 0.0)))
    return 2 * np.spacing(big)


def assert_in_box(z, lower, upper):
    lower, upper = np.broadcast_to(lower, z.shape), np.broadcast_to(upper, z.shape)
    s = slack(lower, upper)
    assert np.all(z >= lower - s), np.max(lower - z)
    assert np.all(z <= upper + s), np.max(z - upper)


def assert_mcp(A, q, lower, upper, res, tol=1e-9):
    """The conditions at res.z, row by row (to tol relative to |A||z| + |q| + 1), and active_mask
    consistent with them."""
    z = res.z
    w = A @ z + q
    t = tol * (abs(A) @ np.abs(z) + np.abs(q) + 1.0)
    assert_in_box(z, lower, upper)
    s = slack(lower, upper)
    at_lower, at_upper = np.abs(z - lower) <= s, np.abs(z - upper) <= s
    between = ~(at_lower | at_upper)
    assert np.all(np.abs(w[between]) <= t[between])
    assert np.all(w[at_lower & ~at_upper] >= -t[at_lower & ~at_upper])
    assert np.all(w[at_upper & ~at_lower] <= t[at_upper & ~at_lower])
    mask = res.active_mask
    assert mask.dtype == np.int8 and mask.shape == z.shape
    assert set(np.unique(mask)) <= {-1, 0, 1}
    assert np.all(at_lower[mask == -1]) and np.all(at_upper[mask == 1])
    assert np.all(np.abs(w[mask == 0]) <= t[mask == 0])


def rel_err(z, ref):
    return np.linalg.norm(z - ref) / max(np.linalg.norm(ref), 1e-300)


def solve_quiet(*args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # no warning on any of these problems
        return nrmicp.solve(*args, **kw)


# ---- agreement with the reference --------------------------------------------------------


@pytest.mark.parametrize("n", [20, 120, 500])
@pytest.mark.parametrize("kind", sorted(MATRICES))
def test_random_box_problems_agree_with_the_reference(kind, n):
    rng = np.random.default_rng([36, n, len(kind)])
    for _ in range(2):
        A = MATRICES[kind](n, rng)
        q, lower, upper = random_box_problem(A, rng)
        ref = reference_box_solve(A, q, lower, upper)
        res = solve_quiet(A, q, lower, upper=upper)
        assert res.success, res.message
        assert rel_err(res.z, ref.z) <= AGREE
        assert_mcp(A, q, lower, upper, res)
        assert abs(res.residual - box_residual(A, q, res.z, lower, upper)) <= 1e-12 * (1 + np.linalg.norm(q))


@pytest.mark.parametrize("kind", sorted(MATRICES))
def test_known_solutions_with_every_kind_of_row(kind):
    rng = np.random.default_rng([36, 1, len(kind)])
    A = MATRICES[kind](300, rng)
    q, lower, upper, z_star, state = known_problem(A, rng)
    ref = reference_box_solve(A, q, lower, upper)
    assert rel_err(ref.z, z_star) <= AGREE   # (the reference itself)
    res = solve_quiet(A, q, lower, upper=upper)
    assert res.success, res.message
    assert rel_err(res.z, z_star) <= AGREE
    assert rel_err(res.z, ref.z) <= AGREE
    assert_mcp(A, q, lower, upper, res)
    np.testing.assert_array_equal(res.active_mask, state)


def test_all_rows_free_is_a_linear_system():
    rng = np.random.default_rng(361)
    A = m_matrix(200, rng, symmetric=False)
    q = random_q(A, rng)
    z = spla.spsolve(sp.csc_matrix(A), -q)
    for lower, upper in [(np.full(200, -INF), np.full(200, INF)), (-INF, None), (-INF, INF)]:
        res = solve_quiet(A, q, lower, upper=upper)
        assert res.success, res.message
        assert rel_err(res.z, z) <= AGREE
        assert np.all(res.active_mask == 0)


def test_upper_only_rows_everywhere():
    rng = np.random.default_rng(362)
    A = m_matrix(150, rng)
    q = random_q(A, rng)
    upper = rng.uniform(-1, 1, 150)
    ref = reference_box_solve(A, q, np.full(150, -INF), upper)
    assert 0 < np.sum(ref.state == 1) < 150     # the upper bound is active somewhere, not everywhere
    for lower in (-INF, np.full(150, -INF)):
        res = solve_quiet(A, q, lower, upper=upper)
        assert res.success, res.message
        assert rel_err(res.z, ref.z) <= AGREE
        assert_mcp(A, q, np.full(150, -INF), upper, res)
        assert not np.any(res.active_mask == -1)


def test_fixed_rows_hold_their_value_whatever_w():
    rng = np.random.default_rng(363)
    A = spd_matrix(120, rng)
    q = random_q(A, rng)
    lower, upper, _ = mixed_bounds(120, rng)
    fixed = rng.uniform(size=120) < 0.3
    upper[fixed] = lower[fixed] = np.where(np.isfinite(lower[fixed]), lower[fixed], 0.25)
    res = solve_quiet(A, q, lower, upper=upper)
    assert res.success, res.message
    np.testing.assert_array_equal(res.z[fixed], lower[fixed])
    assert rel_err(res.z, reference_box_solve(A, q, lower, upper).z) <= AGREE
    assert_mcp(A, q, lower, upper, res)
    assert np.all(res.active_mask[fixed] != 0)
    everything_fixed = solve_quiet(A, q, np.full(120, 0.5), upper=0.5)
    assert everything_fixed.success and np.all(everything_fixed.z == 0.5)


def test_scalar_bounds_broadcast():
    rng = np.random.default_rng(364)
    A = m_matrix(100, rng)
    q = random_q(A, rng)
    ref = reference_box_solve(A, q, np.full(100, -1.0), np.full(100, 1.0))
    res = solve_quiet(A, q, -1.0, upper=1.0)
    assert rel_err(res.z, ref.z) <= AGREE
    assert rel_err(solve_quiet(A, q, None, upper=0.7).z, reference_box_solve(A, q, None, 0.7).z) <= AGREE


def test_upper_inf_everywhere_is_the_plain_lcp():
    """A lower bound with upper = +inf on every row is the Newton member's LCP: the same answer."""
    rng = np.random.default_rng(365)
    A = m_matrix(200, rng, symmetric=False)
    q = random_q(A, rng)
    c = rng.uniform(-1, 1, 200)
    lcp = solve_quiet(A, q, c, method="newton")
    for upper in (INF, np.full(200, INF)):
        np.testing.assert_array_equal(solve_quiet(A, q, c, upper=upper).z, lcp.z)
    far = solve_quiet(A, q, c, upper=np.full(200, 1e6))  # finite, never reached: the box path
    assert rel_err(far.z, lcp.z) <= AGREE
    assert rel_err(lcp.z, reference_box_solve(A, q, c, None).z) <= AGREE
    np.testing.assert_array_equal(far.active_mask, lcp.active_mask)
    assert set(np.unique(lcp.active_mask)) == {-1, 0}


def test_decoupled_rows_with_bounds():
    """Rows with only a diagonal entry (Dirichlet rows) have the LCP's closed form; with bounds the
    whole A is solved."""
    rng = np.random.default_rng(366)
    A = sp.lil_matrix(m_matrix(160, rng, symmetric=False))
    lone = np.arange(0, 160, 3)
    for i in lone:
        A.rows[i], A.data[i] = [i], [float(rng.uniform(0.5, 2.0))]
    A = sp.csr_matrix(A)
    q, lower, upper = random_box_problem(A, rng)
    ref = reference_box_solve(A, q, lower, upper)
    for scale in (False, "both"):
        res = solve_quiet(A, q, lower, upper=upper, scale=scale)
        assert res.success, res.message
        assert rel_err(res.z, ref.z) <= AGREE
        assert_mcp(A, q, lower, upper, res)
    # each lone row on its own: z_i = clip(-q_i / a_ii, lower_i, upper_i)
    d = A.diagonal()
    np.testing.assert_allclose(res.z[lone], np.clip(-q[lone] / d[lone], lower[lone], upper[lone]), rtol=1e-12)


# ---- stopping rule, inner solves, scaling, hierarchies -----------------------------------


def test_default_stopping_rule_and_explicit_tol():
    rng = np.random.default_rng(367)
    A = m_matrix(300, rng)
    q, lower, upper = random_box_problem(A, rng)
    ref = reference_box_solve(A, q, lower, upper)
    default = solve_quiet(A, q, lower, upper=upper)
    assert default.success and rel_err(default.z, ref.z) <= AGREE
    assert default.criterion["measure"] == "units"   # the units-free Res_E, with the bounds in it
    assert default.criterion["value"] < default.criterion["target"]
    for tol in (1e-12, 1e-6, 1e-2):
        res = solve_quiet(A, q, lower, upper=upper, tol=tol)
        assert res.success, res.message
        true = box_residual(A, q, res.z, lower, upper)
        assert true < tol
        assert abs(res.residual - true) <= 1e-12 * (1 + true)
        assert res.residual == pytest.approx(nrmicp.residual(A, q, res.z, lower, upper=upper), rel=1e-12, abs=1e-15)
        assert res.criterion["measure"] == "paper" and res.criterion["target"] == tol
        assert_in_box(res.z, lower, upper)


@pytest.mark.parametrize("kind", ["M sym", "M nonsym", "SPD"])
def test_inner_cg_agrees_with_the_direct_solve(kind):
    """inner='cg': CG (K symmetric) or BiCGSTAB, preconditioned by the V-cycle, on the reduced systems."""
    rng = np.random.default_rng([368, len(kind)])
    A = MATRICES[kind](400, rng)
    q, lower, upper = random_box_problem(A, rng)
    direct = solve_quiet(A, q, lower, upper=upper, tol=1e-12)
    for hierarchy in (None, "amg"):
        cg = solve_quiet(A, q, lower, upper=upper, inner="cg", tol=1e-12, hierarchy=hierarchy)
        assert cg.success, cg.message
        assert rel_err(cg.z, direct.z) <= AGREE
        assert_mcp(A, q, lower, upper, cg)


@pytest.mark.parametrize("scale", [False, "rows", "both"])
def test_scaling_with_bounds(scale):
    """A badly scaled M-matrix D_r A D_c (its bounds in z's units, / d_c): the same z for every scale=."""
    rng = np.random.default_rng(369)
    n = 250
    dr, dc = 10.0 ** rng.uniform(-3, 3, n), 10.0 ** rng.uniform(-3, 3, n)
    A0 = m_matrix(n, rng, symmetric=False)
    A = sp.csr_matrix(sp.diags(dr) @ A0 @ sp.diags(dc))
    lower, upper, _ = mixed_bounds(n, rng)
    lower, upper = lower / dc, upper / dc
    q = dr * random_q(A0, rng)
    ref = reference_box_solve(A, q, lower, upper)
    for hierarchy in (None, "amg"):
        with warnings.catch_warnings():   # (P^T A P of this nonsymmetric M-matrix may lose its positive diagonal)
            warnings.simplefilter("ignore", nrmicp.HierarchyWarning)
            res = nrmicp.solve(A, q, lower, upper=upper, scale=scale, hierarchy=hierarchy)
        assert res.success, res.message
        assert rel_err(res.z, ref.z) <= AGREE
        assert_mcp(A, q, lower, upper, res)


@pytest.mark.parametrize("hierarchy", [None, "amg", "list"])
def test_two_sided_membrane_agrees_with_the_reference_on_every_hierarchy(hierarchy):
    for m, curved in ((15, True), (31, False), (63, True)):
        A, q, lower, upper = two_sided_membrane(m, curved)
        ref = reference_box_solve(A, q, lower, upper)
        assert np.any(ref.state == -1) and np.any(ref.state == 1)   # both obstacles in contact
        h = prolongations(m) if hierarchy == "list" else hierarchy
        res = solve_quiet(A, q, lower, upper=upper, hierarchy=h)
        assert res.success, res.message
        # every level given is used (none dropped: the coarse operators keep a positive diagonal)
        assert len(res.level_steps) == {None: 1, "amg": len(res.level_steps), "list": len(h or []) + 1}[hierarchy]
        assert hierarchy is None or len(res.level_steps) > 1
        assert rel_err(res.z, ref.z) <= AGREE
        assert_mcp(A, q, lower, upper, res)


def _finest_steps(curved, hierarchy):
    """result.level_steps[0] of the two-sided membrane at m = 15, 31, 63."""
    steps = []
    for m in (15, 31, 63):
        A, q, lower, upper = two_sided_membrane(m, curved)
        h = prolongations(m) if hierarchy == "list" else hierarchy
        res = solve_quiet(A, q, lower, upper=upper, hierarchy=h)
        assert res.success, res.message
        steps.append(res.level_steps[0])
    return steps


@pytest.mark.parametrize("hierarchy", ["amg", "list"])
def test_two_sided_membrane_with_flat_obstacles_finest_steps_stay_flat(hierarchy):
    """Nested iteration keeps the finest steps flat as m grows (docs/MEASUREMENTS.md, "Bounds: nested
    iteration on the two-sided membrane")."""
    steps = _finest_steps(False, hierarchy)
    assert max(steps) - min(steps) <= 1, steps


@pytest.mark.parametrize("hierarchy", ["amg", "list"])
def test_two_sided_membrane_with_curved_obstacles_finest_steps_stay_flat(hierarchy):
    steps = _finest_steps(True, hierarchy)
    assert max(steps) - min(steps) <= 1, steps


# ---- start, callback, reuse, inputs untouched --------------------------------------------


def test_warm_start_and_a_start_outside_the_box():
    rng = np.random.default_rng(370)
    A = m_matrix(200, rng)
    q, lower, upper = random_box_problem(A, rng)
    ref = reference_box_solve(A, q, lower, upper)
    warm = solve_quiet(A, q, lower, upper=upper, x0=ref.z)
    assert warm.success and warm.nit == 0
    far = rng.uniform(-5, 5, 200)
    before = snapshot(far)
    res = solve_quiet(A, q, lower, upper=upper, x0=far)
    assert_unchanged(before, [far])
    assert res.success and rel_err(res.z, ref.z) <= AGREE


@pytest.mark.parametrize("scale", [False, "both"])
def test_callback_iterates_stay_in_the_box(scale):
    rng = np.random.default_rng(371)
    A = m_matrix(200, rng, symmetric=False)
    q, lower, upper = random_box_problem(A, rng)
    seen = []
    res = solve_quiet(A, q, lower, upper=upper, callback=lambda zk: seen.append(np.array(zk)), scale=scale,
                      x0=rng.uniform(-5, 5, 200), hierarchy="amg")
    assert res.success and len(seen) == res.nit + 1
    for z in seen:
        assert_in_box(z, lower, upper)
    np.testing.assert_array_equal(seen[-1], res.z)


def test_solver_reuse_with_different_bounds():
    rng = np.random.default_rng(372)
    A = m_matrix(200, rng, symmetric=False)
    solver = nrmicp.Solver(A, method="newton", hierarchy="amg")
    cases = []
    for _ in range(2):
        lower, upper, _ = mixed_bounds(200, rng)
        cases.append((random_q(A, rng), lower, upper))
    cases.append((random_q(A, rng), None, None))       # then the LCP
    cases.append((random_q(A, rng), -INF, rng.uniform(-1, 1, 200)))
    for q, lower, upper in cases + cases[:1]:            # and the first again
        res = solver.solve(q, lower, upper=upper)
        ref = reference_box_solve(A, q, lower, upper)
        assert res.success and rel_err(res.z, ref.z) <= AGREE


def test_nothing_the_user_passed_is_modified():
    A, q, lower, upper = two_sided_membrane(15)
    upper[::7] = INF
    lower[::5] = -INF
    x0 = np.random.default_rng(373).uniform(-1, 1, A.shape[0])
    hierarchy = prolongations(15)
    objs = [A, q, lower, upper, x0, *hierarchy]
    before = snapshot(*objs)
    for scale in (False, "both"):
        for inner in ("auto", "cg"):
            assert nrmicp.solve(A, q, lower, upper=upper, x0=x0, scale=scale, inner=inner, hierarchy=hierarchy).success
        assert nrmicp.Solver(A, method="newton", scale=scale).solve(q, lower, upper=upper, x0=x0).success
        nrmicp.residual(A, q, x0, lower, upper=upper)
    assert_unchanged(before, objs)


# ---- residual and active_mask ------------------------------------------------------------


def test_residual_with_upper_by_hand():
    """Res = ||mid(z - lower, z - upper, w)||_2, row by row (l <= u): mid(a, b, c) with a >= b."""
    A = sp.csr_matrix(np.diag([2.0, 1.0, 4.0, 1.0, 3.0]))
    q = np.array([-1.0, 0.5, -14.0, -3.0, 0.0])
    z = np.array([0.25, -1.0, 3.0, 2.0, 0.5])
    lower = np.array([0.0, -INF, 0.0, -INF, 0.5])
    upper = np.array([1.0, INF, 2.0, 1.5, 0.5])
    # w = Az + q = [-0.5, -0.5, -2, -1, 1.5]; (z - l, z - u, w) and their middle value:
    # row 0: between       (0.25, -0.75, -0.5)  -> -0.5
    # row 1: free          (inf, -inf, -0.5)    -> -0.5 (w)
    # row 2: above upper   (3, 1, -2)           -> 1
    # row 3: upper only    (inf, 0.5, -1)       -> 0.5
    # row 4: fixed at 0.5  (0, 0, 1.5)          -> 0
    expected = np.linalg.norm([-0.5, -0.5, 1.0, 0.5, 0.0])
    assert nrmicp.residual(A, q, z, lower, upper=upper) == pytest.approx(expected, rel=1e-15)
    assert box_residual(A, q, z, lower, upper) == pytest.approx(expected, rel=1e-15)
    # without upper: the paper's min(w, z - lower) (z - lower = +inf on rows free below: w)
    assert nrmicp.residual(A, q, z, lower) == pytest.approx(np.linalg.norm([-0.5, -0.5, -2.0, -1.0, 0.0]), rel=1e-15)
    assert nrmicp.residual(A, q, z, None, upper=INF) == nrmicp.residual(A, q, z)


def test_active_mask_on_every_result():
    """Stationary members (the LCP) carry active_mask too: -1 where z is at its obstacle."""
    rng = np.random.default_rng(374)
    A = m_matrix(100, rng)
    q = random_q(A, rng)
    for method in ("nrmgs", "newton"):
        res = nrmicp.solve(A, q, method=method, tol=1e-12)
        assert res.active_mask.dtype == np.int8
        np.testing.assert_array_equal(res.active_mask == -1, res.z <= res.w)
        assert not np.any(res.active_mask == 1)


def test_a_row_at_its_upper_bound_is_the_bound_exactly():
    """z = upper exactly where the upper bound is active (a user checks z <= upper: d <= 1 in phase-field)."""
    A = sp.csr_matrix(np.array([[1.0]]))
    res = nrmicp.solve(A, np.array([-10.0]), np.array([-0.1]), upper=np.array([0.3]))
    assert res.success and res.active_mask[0] == 1
    assert res.z[0] == 0.3


# ---- bad input -----------------------------------------------------------------------------


def _small():
    A = sp.csr_matrix(sp.diags([-1.0, 4.0, -1.0], [-1, 0, 1], shape=(6, 6)))
    return A, np.linspace(-2, 2, 6)


def test_lower_above_upper_names_both_and_the_first_index():
    A, q = _small()
    lower, upper = np.zeros(6), np.ones(6)
    lower[[2, 4]] = [2.0, 3.0]
    for call in (lambda: nrmicp.solve(A, q, lower, upper=upper),
                 lambda: nrmicp.Solver(A, method="newton").solve(q, lower, upper=upper),
                 lambda: nrmicp.residual(A, q, np.zeros(6), lower, upper=upper)):
        with pytest.raises(ValueError, match=r"index 2") as exc:
            call()
        assert "upper" in str(exc.value) and "zeta" in str(exc.value)
    with pytest.raises(ValueError, match=r"upper.*index 3|index 3.*upper"):   # zeta None: lower 0
        nrmicp.solve(A, q, None, upper=np.r_[1.0, 1.0, 1.0, -1.0, -1.0, 1.0])


BAD_UPPER = {
    "nan": (np.r_[1, np.nan, 1, 1, 1, 1.0], ValueError),
    "nan scalar": (np.nan, ValueError),
    "-inf": (np.r_[1, -INF, 1, 1, 1, 1.0], ValueError),
    "-inf scalar": (-INF, ValueError),
    "wrong length": (np.ones(7), ValueError),
    "empty": ([], ValueError),
    "2-D": (np.ones((6, 2)), ValueError),
    "complex": (np.ones(6) + 0j, TypeError),
    "complex scalar": (1 + 1j, TypeError),
    "object": (np.array([1, None, 1, 1, 1, 1], dtype=object), TypeError),
    "string": ("1", TypeError),
    "strings": (np.array(["1"] * 6), TypeError),
    "bool scalar": (True, TypeError),
    "sparse": (sp.csr_matrix(np.ones((1, 6))), TypeError),
    "masked": (np.ma.masked_array(np.ones(6), mask=[0, 1, 0, 0, 0, 0]), TypeError),
}   # (an Affine or callable upper is an implicit upper bound: tests/test_bounds_implicit.py)


@pytest.mark.parametrize("name", sorted(BAD_UPPER))
def test_bad_upper_is_a_clear_error_naming_upper(name):
    A, q = _small()
    upper, exc = BAD_UPPER[name]
    for call in (lambda: nrmicp.solve(A, q, np.zeros(6), upper=upper),
                 lambda: nrmicp.Solver(A, method="newton").solve(q, None, upper=upper),
                 lambda: nrmicp.residual(A, q, np.zeros(6), None, upper=upper)):
        with pytest.raises(exc, match="upper"):
            call()


@pytest.mark.parametrize("lower,what", [(np.r_[0, np.nan, 0, 0, 0, 0.0], "nan"), (np.r_[0, INF, 0, 0, 0, 0.0], "inf"),
                                        (INF, "inf"), (np.nan, "nan")])
def test_bad_lower_is_a_clear_error_naming_zeta(lower, what):
    A, q = _small()
    for upper in (None, np.ones(6)):
        with pytest.raises(ValueError, match="zeta") as exc:
            nrmicp.solve(A, q, lower, upper=upper)
        assert what in str(exc.value)


@pytest.mark.parametrize("method", ["nrm", "nrmm", "nrmaor", "nrmsor", "nrmgs", "nrmj", "mms", "two_sweep"])
def test_an_implicit_zeta_with_upper_on_a_stationary_method_names_newton(method):
    """The stationary members take constant bounds (tests/test_bounds_family.py); an Affine or
    callable ζ with upper is the Newton member's outer fixed point only."""
    A, q = _small()
    opts = {"alpha": 1.0} if method in ("nrmm", "nrmsor") else {"alpha": 1.0, "beta": 0.5} if method == "nrmaor" else {}
    affine = nrmicp.Affine(sp.csr_matrix(0.1 * sp.eye(6)), np.zeros(6))
    for zeta in (affine, lambda z: np.zeros(6)):
        with pytest.raises(ValueError, match="'newton'"):
            nrmicp.solve(A, q, zeta, upper=np.ones(6), method=method, **opts)
        with pytest.raises(ValueError, match="'newton'"):
            nrmicp.Solver(A, method=method, **opts).solve(q, zeta, upper=np.ones(6))


def test_an_implicit_lower_bound_with_upper_is_the_box_problem_at_its_fixed_point():
    """An Affine or callable ζ with upper (the outer fixed point): z solves the box problem whose lower
    bound is ζ(z) itself — checked against the reference at that lower bound — and the sign conditions hold."""
    A, q = _small()
    up = np.full(6, 0.4)
    affine = nrmicp.Affine(sp.csr_matrix(0.1 * sp.eye(6)), np.full(6, -0.3))
    for zeta, at in ((affine, lambda z: 0.1 * z - 0.3), (lambda z: -0.3 + 0.1 * np.sin(z), lambda z: -0.3 + 0.1 * np.sin(z))):
        res = nrmicp.solve(A, q, zeta, upper=up, tol=1e-12)
        assert res.success, res.message
        lower = at(res.z)
        ref = reference_box_solve(A, q, lower, up).z
        np.testing.assert_allclose(res.z, ref, rtol=0, atol=1e-10)
        w = A @ res.z + q
        assert np.all(res.z >= lower - 1e-12) and np.all(res.z <= up + 1e-12)
        assert np.all(w[res.active_mask == -1] >= -1e-10) and np.all(w[res.active_mask == 1] <= 1e-10)


def test_a_zeta_jacobian_with_bounds_is_refused_naming_it():
    A, q = _small()
    for zeta, upper in ((np.zeros(6), np.ones(6)), (-INF, None), (lambda z: np.zeros(6), np.ones(6))):
        with pytest.raises(ValueError, match="zeta_jacobian"):
            nrmicp.solve(A, q, zeta, upper=upper, zeta_jacobian=lambda z: sp.eye(6, format="csr"))


def test_valid_spellings_of_upper():
    """A list, ints, float32, a column (n, 1), a 0-d array, +inf: all the same problem."""
    A, q = _small()
    ref = nrmicp.solve(A, q, np.zeros(6), upper=np.full(6, 1.0)).z
    for upper in ([1] * 6, np.ones(6, dtype=np.int64), np.ones(6, dtype=np.float32), np.ones((6, 1)), np.array(1.0), 1):
        np.testing.assert_array_equal(nrmicp.solve(A, q, np.zeros(6), upper=upper).z, ref)
