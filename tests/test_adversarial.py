"""Findings of an adversarial run on the stationary members (issue 38): an iteration that stops
moving ends STAGNATED at once, infeasibility the data show is named, the reported Res is the
returned z's, and the returned z is finite whenever the start was."""
import math

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp

STATIONARY = [m for m in nrmicp.METHODS if m != "newton"]
ACCELERATE = ["none", "anderson"]


def _res(A, q, z, zeta_of_z):
    """Res(z) in plain numpy: ‖min(Az + q, z − ζ(z))‖₂."""
    return float(np.linalg.norm(np.minimum(A.toarray() @ z + q, z - zeta_of_z)))


def _escape_case():
    """The run's case: row 0 of A zero with q_0 < 0, so nrm grows z_0 by the same amount each step
    while Res stays bit-identical from iteration 0 on."""
    A = sp.csr_matrix(np.array([[0, 0, 0], [0, 3e-323, -1e-323], [0, 0, 0]]))
    return A, np.array([-0.0512, -1.3045, 0.0229])


def _diagonal_option(method, n):
    """What a member needs on an A without a positive diagonal (the paper's nrm needs nothing)."""
    return {"nrm": {}, "nrmm": {"alpha": 1.0}}.get(method, {"omega2": np.ones(n)})


@pytest.mark.parametrize("accelerate", ACCELERATE)
@pytest.mark.parametrize("method", STATIONARY)
def test_res_bit_identical_while_z_moves_is_stagnated_at_once(method, accelerate):
    """maxiter = 2**31 - 1 took 65 s to end STAGNATED (nrm), 10**6 ended MAX_ITERATIONS."""
    A, q = _escape_case()
    res = nrmicp.solve(A, q, method=method, tol=7.8e-13, gamma=11.59, maxiter=2**31 - 1, accelerate=accelerate,
                       **_diagonal_option(method, 3))
    assert res.status == nrmicp.Status.STAGNATED, res.message
    assert res.iterations <= 10
    assert "bit-identical" in res.message and "max|z| kept growing" in res.message
    assert "row 0 of A is zero and q[0] = -0.0512 < 0" in res.message
    assert res.residual == pytest.approx(_res(A, q, res.z, 0), rel=1e-14)


@pytest.mark.parametrize("accelerate", ACCELERATE)
@pytest.mark.parametrize("method", STATIONARY)
def test_iterate_that_no_longer_changes_is_stagnated_at_once(method, accelerate):
    """x ≈ 1e20 and each step moves it by 2e-10, below its rounding: x is bitwise fixed at a point
    that is not a solution (Res = a·z = 2e-10 > tol). The rounding-floor rule needed
    stall_iterations (100) iterations for it."""
    A, q = sp.csr_matrix([[1e-30]]), np.array([0.0])
    opts = {"alpha": 1.0} if method == "nrmm" else {"omega2": [1.0]}
    res = nrmicp.solve(A, q, x0=[2e20], method=method, tol=1e-12, accelerate=accelerate, **opts)
    assert res.status == nrmicp.Status.STAGNATED, res.message
    assert res.iterations <= 10
    assert "the iterate no longer changes: a fixed point of the iteration that is not a solution" in res.message
    assert res.residual == pytest.approx(_res(A, q, res.z, 0), rel=1e-14) and res.residual > 1e-12


# ---- infeasibility named ---------------------------------------------------------------------

@pytest.mark.parametrize("method", ["nrm", "newton"])
def test_infeasible_one_by_one_lcp_says_so(method):
    """A = [[0]], q = [-1]: w = -1 whatever z; it ended 'STAGNATED ... iteration 0' and no more."""
    res = nrmicp.solve(sp.csr_matrix([[0.0]]), [-1.0], method=method)
    assert not res.success
    assert "row 0 of A is zero and q[0] = -1 < 0" in res.message and "no solution" in res.message
    assert "try method" not in res.message  # no parameter advice for a problem without solution


@pytest.mark.parametrize("q3, bounds", [(-50.0, "free"), (-50.0, "lower"), (50.0, "free_upper")])
def test_a_zero_row_no_bound_can_hold_is_named_in_a_box_problem(q3, bounds):
    """Found by review: the infeasibility rule skipped bounded problems. Row 3 of A zero: w_3 = q_3 for every z,
    which vanishes nowhere; q_3 < 0 needs an upper bound to rest at, q_3 > 0 a lower one."""
    n = 6
    A = sp.lil_matrix(sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n)) * 49)
    A[3, :] = 0
    A = sp.csr_matrix(A)
    lower, upper = np.zeros(n), None
    if bounds != "lower":
        lower[3] = -np.inf
    if bounds == "free_upper":
        upper = np.full(n, 1.0)
    if bounds == "lower":   # (a bounded problem by its upper bound elsewhere; row 3 has lower 0, no upper)
        upper = np.where(np.arange(n) == 3, np.inf, 1.0)
    res = nrmicp.solve(A, np.full(n, q3), lower, upper=upper, method="newton")
    assert not res.success
    side = "upper" if q3 < 0 else "lower"
    assert f"row 3 of A is zero and q[3] = {q3:g}: w_3 = q_3 never vanishes and z_3 has no {side} bound" in res.message


@pytest.mark.parametrize("method", nrmicp.METHODS)
def test_row_without_positive_entry_and_negative_q_is_named(method):
    """Row 1 = (1, 3, 0) with q_1 < 0 is feasible; row 2 = (0, -1, -0.5) with q_2 = -0.5 gives
    w_2 = -z_1 - 0.5 z_2 - 0.5 < 0 for every z >= 0."""
    A = sp.csr_matrix(np.array([[2.0, 0, 0], [1.0, 3.0, 0], [0, -1.0, -0.5]]))
    q = np.array([1.0, -1.0, -0.5])
    res = nrmicp.solve(A, q, method=method, maxiter=50, **_diagonal_option(method, 3))
    assert not res.success
    assert "row 2 of A has no positive entry and q[2] = -0.5 < 0" in res.message, res.message


def test_constant_obstacle_shifts_q_in_the_infeasibility_test():
    """ζ = c: z = y + c, y >= 0, so w = A y + (q + A c); row 0 = (-0.5, 0) with q_0 = 1, c_0 = 4 gives
    (q + A c)_0 = -1 < 0. With c_0 = 0.5 the same row is feasible and nothing is claimed."""
    A = sp.csr_matrix(np.array([[-0.5, 0.0], [0.0, 1.0]]))
    q = np.array([1.0, -1.0])
    bad = nrmicp.solve(A, q, zeta=np.array([4.0, 0.0]), method="nrm", maxiter=50)
    assert not bad.success and "(q + A c)[0] = -1 < 0" in bad.message, bad.message
    fine = nrmicp.solve(A, q, zeta=np.array([0.5, 0.0]), method="nrm", maxiter=50)
    assert "no solution" not in fine.message, fine.message


def test_feasible_problem_cut_short_claims_no_infeasibility():
    A = sp.csr_matrix(np.array([[4.0, -1.0], [-1.0, 4.0]]))
    res = nrmicp.solve(A, [-1.0, 1.0], method="nrm", maxiter=1)
    assert res.status == nrmicp.Status.MAX_ITERATIONS
    assert "no solution" not in res.message


# ---- the reported Res is the returned z's ---------------------------------------------------

def test_reported_res_is_that_of_the_returned_z_at_a_huge_start():
    """nrmm on A = 0 with an Affine ζ from a start of 1e59: the returned iterate has entries of
    1e59, where z − ζ(z) cancels to the last bits. The reported Res must be that of the returned z:
    nrmicp.residual's, and an exactly rounded evaluation (math.fsum) agrees with it; a dense
    product in another order gives 1.7e43 (which is what an oracle with a different summation order
    reports: the rounding of Res at such a z, ~eps * 1e59, not a second residual)."""
    rng = np.random.default_rng(533)
    n = 15
    A = sp.csr_matrix((n, n))
    B = sp.csr_matrix(rng.uniform(-0.2, 0.2, (n, n)) * (rng.random((n, n)) < 0.5))
    c, q = rng.standard_normal(n), 0.1 * rng.standard_normal(n)
    x0 = rng.uniform(-1, 1, n) * 1e59
    res = nrmicp.solve(A, q, nrmicp.Affine(B, c), x0=x0, method="nrmm", alpha=0.0069, gamma=0.89, scale="rows",
                       maxiter=300, stall_iterations=5)
    assert not res.success and np.all(np.isfinite(res.z))
    assert res.residual == nrmicp.residual(A, q, res.z, nrmicp.Affine(B, c))
    Bd = B.toarray()
    g = np.array([math.fsum(np.r_[res.z[i], -Bd[i] * res.z, -c[i]]) for i in range(n)])  # exactly rounded
    assert res.residual == pytest.approx(float(np.linalg.norm(np.minimum(q, g))), rel=1e-12)


# ---- a finite start gives a finite z ---------------------------------------------------------

def _huge_matrix(rng, n):
    """Entries 5e292 ... 6e296 (the run's range), a full diagonal: scale=True divides by ~1e148."""
    A = sp.random(n, n, density=0.05, random_state=rng, data_rvs=lambda k: 10.0 ** rng.uniform(292.7, 296.8, k))
    A = sp.lil_matrix(A)
    A.setdiag(10.0 ** rng.uniform(292.7, 296.8, n))
    return sp.csr_matrix(A)


@pytest.mark.parametrize("seed", [4, 5, 6])
def test_scaled_start_overflowing_returns_a_finite_z_nrmaor(seed):
    """nrmaor, scale=True, n = 185, x0 up to 6.7e172: x0 / d_c overflows in the scaled variables
    (d_c ~ 1e-148); entries of z were returned non-finite."""
    rng = np.random.default_rng(seed)
    n = 185
    A = _huge_matrix(rng, n)
    q = rng.standard_normal(n)
    x0 = 10.0 ** rng.uniform(0, 172.8, n)
    res = nrmicp.solve(A, q, x0=x0, method="nrmaor", scale=True)
    assert not res.success
    assert np.all(np.isfinite(res.z)), res.message
    assert np.array_equal(res.z, x0)  # nothing finite was reached: the start stands in


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_scaled_start_overflowing_returns_a_finite_z_nrm(seed):
    """nrm, scale=True, one x0 entry -1.6e296: -inf entries were returned."""
    rng = np.random.default_rng(seed)
    n = 30
    A = _huge_matrix(rng, n)
    q = rng.standard_normal(n)
    x0 = rng.uniform(0, 1, n)
    x0[int(rng.integers(n))] = -1.6e296
    res = nrmicp.solve(A, q, x0=x0, method="nrm", scale=True)
    assert not res.success
    assert np.all(np.isfinite(res.z)), res.message
