"""The stationary members with bounds lower <= z <= upper (PATH's convention: w = Az + q >= 0 where
z = lower, <= 0 where z = upper, = 0 between), against references written here:

(a) the first iterates of every member agree with a plain numpy version of the same iteration, the
    member's LCP form with |x| replaced by m(x) = 2 mid(lo', x, hi') - x (cpp detail/modulus.hpp);
(b) every member converges to the exact solution of small box problems on H+-matrices (free rows,
    upper-only rows, two-sided and fixed rows), computed by a numpy primal-dual active-set method;
(c) the MCP sign conditions hold at the returned z, checked directly;
(d) method='auto' takes nrmgs on a row-dominant A with bounds, as without bounds.
"""
import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp

STATIONARY = [m for m in nrmicp.METHODS if m != "newton"]
N = 30
GAMMA = 2.0   # not the default 1: exercises gamma in lo' = gamma lo / (2 Omega1) and in the start


# ---- problems -------------------------------------------------------------------------------

def h_plus_matrix(seed, symmetric):
    """A sparse H+-matrix that is not an M-matrix (off-diagonal entries of both signs): rows
    strictly dominant by a fifth of the diagonal; symmetric ones are positive definite too."""
    rng = np.random.default_rng(seed)
    R = sp.random(N, N, density=0.15, random_state=rng, data_rvs=lambda k: rng.uniform(-1, 1, k)).toarray()
    np.fill_diagonal(R, 0.0)
    if symmetric:
        R = (R + R.T) / 2
    d = 1.25 * np.abs(R).sum(axis=1) + rng.uniform(0.5, 2.0, N)
    return sp.csr_matrix(R + np.diag(d))


def row_bounds(seed):
    """lower, upper with every kind of row: two-sided, lower only, upper only, free, fixed."""
    rng = np.random.default_rng(seed + 100)
    lower = rng.uniform(-1, 0.5, N)
    upper = lower + rng.uniform(0.2, 1.5, N)
    kind = np.arange(N) % 5
    lower[kind == 2] = -np.inf              # upper only
    upper[kind == 1] = np.inf               # lower only
    lower[kind == 3], upper[kind == 3] = -np.inf, np.inf   # free
    upper[kind == 4] = lower[kind == 4]     # fixed (lower = upper)
    return lower, upper


def designed_problem(seed, symmetric=False):
    """(A, q, lower, upper, z*): q = w* - A z* from a chosen solution with rows at lower (w > 0),
    at upper (w < 0) and strictly between (w = 0)."""
    rng = np.random.default_rng(seed + 200)
    A = h_plus_matrix(seed, symmetric)
    lower, upper = row_bounds(seed)
    place = rng.integers(0, 3, N)          # 0: at lower, 1: between, 2: at upper
    place[~np.isfinite(lower) & (place == 0)] = 1
    place[~np.isfinite(upper) & (place == 2)] = 1
    place[lower == upper] = 0
    lo, hi = np.where(np.isfinite(lower), lower, -2.0), np.where(np.isfinite(upper), upper, 2.0)
    z = np.where(place == 0, lower, np.where(place == 2, upper, lo + rng.uniform(0.2, 0.8, N) * (hi - lo)))
    w = np.where(place == 0, rng.uniform(0.5, 2, N), np.where(place == 2, -rng.uniform(0.5, 2, N), 0.0))
    w[lower == upper] = rng.uniform(-2, 2, (lower == upper).sum())   # a fixed row's w has any sign
    return A, w - A @ z, lower, upper, z


# ---- the exact solution: primal-dual active sets (Hintermüller–Ito–Kunisch) ------------------

def active_set_solution(A, q, lower, upper, maxit=100):
    """The box problem solved by the primal-dual active-set method: with x = z - w/diag(A), rows
    with x < lower are held at lower, x > upper at upper, the others solve (Az + q)_i = 0."""
    A = A.toarray()
    d = np.diag(A)
    z = np.clip(np.zeros(N), lower, upper)
    seen = set()
    for _ in range(maxit):
        x = z - (A @ z + q) / d
        at_lo, at_hi = x < lower, (x > upper) & ~(x < lower)
        key = (at_lo.tobytes(), at_hi.tobytes())
        if key in seen:
            break
        seen.add(key)
        free = ~(at_lo | at_hi)
        z = np.where(at_lo, lower, np.where(at_hi, upper, 0.0))
        z[free] = np.linalg.solve(A[np.ix_(free, free)], -q[free] - A[np.ix_(free, ~free)] @ z[~free])
    assert mcp_violation(sp.csr_matrix(A), q, z, lower, upper) < 1e-12   # the reference itself is exact
    return z


def mcp_violation(A, q, z, lower, upper):
    """max over rows of the violated MCP condition: z outside [lower, upper]; w < 0 at lower, w > 0 at
    upper, w != 0 strictly between (a row at both bounds, lower = upper, may have any w)."""
    w = A @ z + q
    scale = 1.0 + np.abs(z).max() + np.abs(q).max()
    tie = 1e-10 * scale
    at_lo, at_hi = np.abs(z - lower) <= tie, np.abs(z - upper) <= tie
    bad = np.maximum(lower - z, z - upper)
    bad = np.maximum(bad, np.where(at_lo & ~at_hi, -w, 0.0))
    bad = np.maximum(bad, np.where(at_hi & ~at_lo, w, 0.0))
    bad = np.maximum(bad, np.where(~at_lo & ~at_hi, np.abs(w), 0.0))
    return float(bad.max() / scale)


# ---- the numpy reference of the box iteration ----------------------------------------------

def member_setup(method, A):
    """(options for nrmicp, M, N, Omega1, Omega2, phi, theta, M2) of a member, every parameter given."""
    A = A.toarray()
    D, L, U = np.diag(np.diag(A)), -np.tril(A, -1), -np.triu(A, 1)
    d = np.diag(A)
    om1 = np.linspace(0.7, 1.0, N)   # Omega1 != I where the member has it, <= I: Omega2 = D >= D Omega1
    phi = np.linspace(0.0, 0.3, N)
    if method == "nrm":
        opts = dict(omega1=om1, omega2=d, phi=phi)   # Omega2 >= D Omega1: Theorem 4.2 (M = A, N = 0)
        return opts, A, 0 * A, om1, d, phi, 1.0, None
    if method == "nrmm":
        alpha = 1.5 * d.max()
        return dict(alpha=alpha), A, 0 * A, np.ones(N), np.full(N, alpha), np.zeros(N), 1.0, None
    a, b = {"nrmaor": (1.1, 0.9), "nrmsor": (0.9, 0.9), "nrmgs": (1, 1), "nrmj": (1, 0), "mms": (1, 0.8),
            "two_sweep": (1, 1)}[method]
    M = (D - b * L) / a
    opts = {"nrmaor": dict(alpha=a, beta=b, omega1=om1, phi=phi), "nrmsor": dict(alpha=a, omega1=om1),
            "nrmgs": dict(phi=phi), "nrmj": {}, "mms": dict(alpha=a, beta=b), "two_sweep": dict(theta=0.8)}[method]
    has_om1 = "omega1" in opts
    has_phi = "phi" in opts
    return (opts, M, M - A, om1 if has_om1 else np.ones(N), d, phi if has_phi else np.zeros(N),
            opts.get("theta", 1.0), D - U if method == "two_sweep" else None)


def reference_iterates(A, q, lower, upper, method, k, z_update="explicit"):
    """z(0), ..., z(k) of the member's box iteration in plain numpy, from z0 = 0:
    y = z - s, q' = q + As, m(x) = 2 clip(x, lo', hi') - x with lo' = gamma lo/(2 Omega1),
    (Omega2 + (M + phi) Omega1) x(k+1) = (N + phi) Omega1 x(k) + (Omega2 - A Omega1) m(x(k)) - gamma q'
    (two_sweep: the SPEC's form with m in place of |.|), y = Omega1 (m(x) + x)/gamma."""
    _, M, Nm, om1, om2, phi, theta, M2 = member_setup(method, A)
    Ad = A.toarray()
    s = np.where(np.isfinite(lower), lower, np.where(np.isfinite(upper), upper, 0.0))
    lo, hi = np.where(np.isfinite(lower), 0.0, -np.inf), upper - s
    lo1, hi1 = GAMMA * lo / (2 * om1), GAMMA * hi / (2 * om1)
    qs = q + Ad @ s

    def m(x):
        return 2 * np.clip(x, lo1, hi1) - x

    def z_of(x):
        if z_update == "solve":
            return np.linalg.solve(Ad, om2 * (m(x) - x) / GAMMA - qs) + s
        return om1 * (m(x) + x) / GAMMA + s

    y0 = -s
    x = GAMMA / 2 * (y0 / om1 - (Ad @ y0 + qs) / om2)
    Lm = np.diag(om2) + (M + np.diag(phi)) * om1
    x_prev, zs = x, [z_of(x)]
    for _ in range(k):
        if M2 is None:
            rhs = ((Nm + np.diag(phi)) * om1) @ x + (np.diag(om2) - Ad * om1) @ m(x) - GAMMA * qs
        else:
            rhs = Nm @ x + (np.diag(om2) - M2) @ m(x) + (M2 - Ad) @ m(x_prev) - GAMMA * qs
        x_prev, x = x, theta * np.linalg.solve(Lm, rhs) + (1 - theta) * x
        zs.append(z_of(x))
    return zs


def core_iterates(A, q, lower, upper, method, k, **extra):
    opts = member_setup(method, A)[0]
    zs = []
    nrmicp.solve(A, q, lower, upper=upper, method=method, gamma=GAMMA, tol=1e-300, maxiter=k,
                 callback=lambda zk: zs.append(np.array(zk)), **opts, **extra)
    return zs


# ---- (a) the same iteration ----------------------------------------------------------------

@pytest.mark.parametrize("method", STATIONARY)
@pytest.mark.parametrize("symmetric", [False, True])
def test_first_iterates_agree_with_the_numpy_box_iteration(method, symmetric):
    A, q, lower, upper, _ = designed_problem(1, symmetric)
    ref = reference_iterates(A, q, lower, upper, method, 6)
    got = core_iterates(A, q, lower, upper, method, 6)
    assert len(got) == 7
    for k, (zr, zc) in enumerate(zip(ref, got)):
        assert np.allclose(zc, zr, rtol=0, atol=1e-10 * (1 + np.abs(zr).max())), (method, k)


@pytest.mark.parametrize("method", ["nrmgs", "nrm", "mms"])
def test_z_update_solve_gives_the_numpy_iterates(method):
    A, q, lower, upper, _ = designed_problem(2)
    ref = reference_iterates(A, q, lower, upper, method, 4, z_update="solve")
    got = core_iterates(A, q, lower, upper, method, 4, z_update="solve")
    for zr, zc in zip(ref, got):
        assert np.allclose(zc, zr, rtol=0, atol=1e-10 * (1 + np.abs(zr).max()))


@pytest.mark.parametrize("method", STATIONARY)
def test_a_bound_that_never_binds_gives_the_lcp_iterates_bit_for_bit(method):
    """lower = 0 and an upper bound of 1e30 on one row: the box path (s = 0), where m(x) =
    2 min(hi', max(0, x)) - x equals |x| exactly for x < hi', so every iterate is the LCP's."""
    A, q, _, _, _ = designed_problem(3)
    lcp, box = [], []
    nrmicp.solve(A, q, method=method, tol=1e-12, callback=lambda zk: lcp.append(np.array(zk)))
    nrmicp.solve(A, q, np.zeros(N), upper=np.r_[np.full(N - 1, np.inf), 1e30], method=method, tol=1e-12,
                 callback=lambda zk: box.append(np.array(zk)))
    assert len(lcp) == len(box) > 3
    assert all(np.array_equal(a, b) for a, b in zip(lcp, box))


# ---- (b), (c) the exact solution and the MCP conditions ---------------------------------------

@pytest.mark.parametrize("method", STATIONARY)
@pytest.mark.parametrize("seed", [4, 5])
def test_converges_to_the_active_set_solution(method, seed):
    A, q, lower, upper, z_designed = designed_problem(seed, symmetric=(seed == 5))
    exact = active_set_solution(A, q, lower, upper)
    assert np.allclose(exact, z_designed, atol=1e-12)   # the reference found the designed solution
    r = nrmicp.solve(A, q, lower, upper=upper, method=method, gamma=GAMMA, tol=1e-12, maxiter=5000,
                     **member_setup(method, A)[0])
    assert r.success, r.message
    assert np.abs(r.z - exact).max() < 1e-10
    assert mcp_violation(A, q, r.z, lower, upper) < 1e-12
    # z = y + s with y clamped to the box: exact at lower, within one rounding of upper - lower + lower
    assert np.all(r.z >= lower) and np.all(r.z <= upper + 2e-16 * np.abs(upper))


@pytest.mark.parametrize("method", STATIONARY)
def test_default_parameters_converge_on_a_random_box_problem(method):
    """Each member with its own defaults (nrm/nrmm: Omega2 = I resp. alpha I on an SPD A, where the
    Cayley transform's 2-norm < 1; the others: Omega2 = D on an H+-matrix), q random."""
    A = h_plus_matrix(6, symmetric=True)
    lower, upper = row_bounds(6)
    q = np.random.default_rng(6).uniform(-3, 3, N)
    exact = active_set_solution(A, q, lower, upper)
    r = nrmicp.solve(A, q, lower, upper=upper, method=method, tol=1e-12, maxiter=5000)
    assert r.success, r.message
    assert np.abs(r.z - exact).max() < 1e-10
    assert mcp_violation(A, q, r.z, lower, upper) < 1e-12
    mask = r.active_mask
    two_valued = lower < upper   # (a fixed row's mask follows the sign of w)
    assert np.all(mask[(r.z == upper) & two_valued] == 1) and np.all(mask[(r.z == lower) & two_valued] == -1)


def test_upper_only_and_free_rows_with_zeta_none():
    """zeta None with an upper bound: lower 0 where upper is finite, and z free nowhere; rows with
    upper = +inf are the LCP's."""
    A = h_plus_matrix(7, symmetric=False)
    upper = np.where(np.arange(N) % 2 == 0, 0.3, np.inf)
    q = np.random.default_rng(7).uniform(-3, 3, N)
    exact = active_set_solution(A, q, np.zeros(N), upper)
    for method in ("nrmgs", "two_sweep", "nrmj"):
        r = nrmicp.solve(A, q, upper=upper, method=method, tol=1e-12, maxiter=5000)
        assert r.success and np.abs(r.z - exact).max() < 1e-10, method


def test_anderson_converges_with_bounds():
    A, q, lower, upper, z = designed_problem(8)
    r = nrmicp.solve(A, q, lower, upper=upper, method="nrmgs", accelerate="anderson", tol=1e-12)
    assert r.success and np.abs(r.z - z).max() < 1e-10


def test_solver_reuses_its_setup_for_bounds_and_lcp():
    A, q, lower, upper, z = designed_problem(9)
    s = nrmicp.Solver(A, method="nrmsor", alpha=1.2)
    boxed = s.solve(q, lower, upper=upper, tol=1e-12)
    lcp = s.solve(q, tol=1e-12)
    assert np.abs(boxed.z - z).max() < 1e-10
    assert np.abs(lcp.z - active_set_solution(A, q, np.zeros(N), np.full(N, np.inf))).max() < 1e-10


# ---- (d) method='auto' ----------------------------------------------------------------------

def test_auto_takes_nrmgs_on_a_dominant_matrix_with_bounds():
    A, q, lower, upper, z = designed_problem(10)
    r = nrmicp.solve(A, q, lower, upper=upper, tol=1e-12)
    assert r.method == "nrmgs" and np.abs(r.z - z).max() < 1e-10


def test_auto_takes_newton_on_a_laplacian_with_bounds():
    n = 50
    A = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n), format="csr")
    q = -np.ones(n) / n**2
    r = nrmicp.solve(A, q, np.full(n, -np.inf), upper=np.full(n, 0.05), tol=1e-12)
    assert r.method == "newton" and r.success
    assert mcp_violation(A, q, r.z, np.full(n, -np.inf), np.full(n, 0.05)) < 1e-12


@pytest.mark.parametrize("method", ["nrmgs", "nrmsor", "newton"])
@pytest.mark.parametrize("scale", [None, "rows"])
def test_polish_lands_a_box_answer_on_the_active_set_solution(method, scale):
    """polish=True on a box problem: Newton steps within the bounds the member was given (every kind of
    row, also after the 'rows' equilibration) take a loosely solved answer to the exact one; the answer
    the member stopped at is not (polished False would mean the polish was skipped)."""
    A, q, lower, upper, _ = designed_problem(4)
    exact = active_set_solution(A, q, lower, upper)
    loose = nrmicp.solve(A, q, lower, upper=upper, method=method, tol=1e-4, scale=scale, maxiter=5000)
    r = nrmicp.solve(A, q, lower, upper=upper, method=method, tol=1e-4, scale=scale, maxiter=5000, polish=True)
    assert r.success, r.message
    if np.abs(loose.z - exact).max() > 1e-12:   # (newton may land on it at once: nothing left to polish)
        assert r.polished, r.message
    assert np.abs(r.z - exact).max() < 1e-12
    assert mcp_violation(A, q, r.z, lower, upper) < 1e-12
    assert np.all(r.z >= lower) and np.all(r.z <= upper + 2e-16 * np.abs(upper))


@pytest.mark.parametrize("kind", ["affine", "callable"])
def test_polish_keeps_an_implicit_upper_bound(kind):
    """An implicit upper bound u(z) = u0 + 0.05 z (Affine or callable; Newton's polish takes it as the solve did):
    a loose answer (tol 1e-2, z 2e-4 off, outside u(z) by as much) is polished onto the answer of a tight solve,
    within its own bound."""
    from nrmicp.scenes.obstacle import obstacle_2d
    pb = obstacle_2d(15, exact=False)
    A, psi, q = sp.csr_matrix(pb.A), pb.zeta, pb.q
    u0 = psi + 0.02
    up = nrmicp.Affine(0.05 * sp.identity(pb.n, format="csr"), u0) if kind == "affine" else (lambda z: u0 + 0.05 * z)
    tight = nrmicp.solve(A, q, psi, upper=up, method="newton", tol=1e-13)
    r = nrmicp.solve(A, q, psi, upper=up, method="newton", tol=1e-2, polish=True)
    assert r.success and r.polished, r.message
    assert np.abs(r.z - tight.z).max() < 1e-12
    assert np.all(r.z >= psi) and np.all(r.z <= u0 + 0.05 * r.z + 1e-15)
