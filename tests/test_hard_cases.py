"""Hard cases stay numerically honest.

Every case below is solved under several configurations (method x stabilizer). For each solve:

* no crash: the only exceptions allowed are the documented ones for a matrix the method cannot
  use (ValueError naming the left matrix / omega2 for a non-positive diagonal, LinAlgError for a
  singular factorization), and only on cases flagged ``may_refuse``;
* z is finite, and ``residual`` is Res(z) of the returned z (recomputed here in plain numpy);
* success=True only if Res(z), recomputed here in plain numpy, is < tol;
* success=True on a case with a known solution z*: the true error obeys the documented bound
  ``error_bound`` (see ``Case.bound``), or failure is an explicit non-CONVERGED status;
* cases with a guaranteed unique solution and a certified (or known-easy) configuration must converge.

Documented error bound (Chen & Xiang, Math. Program. 106 (2006), Thm 2.1/2.2): for an LCP with a
P-matrix A and r(z) = min(z, Az + q),

    ||z − z*||_∞ ≤ max_{d ∈ [0,1]^n} ||(I − D + DA)⁻¹||_∞ · ||r(z)||_∞,

and for an H+-matrix the max is ≤ κ_CX = ||⟨A⟩⁻¹ max(Λ, I)||_∞ (Λ = diag A). A constant
obstacle is the shifted LCP (same bound). For ζ with ∞-norm Lipschitz constant L on a matrix
whose obstacle-to-solution map is ∞-nonexpansive (M-matrices with nonnegative row sums), the
bound becomes κ_CX·||r||_∞ / (1 − L); for the other ICPs we use that formula as a heuristic and
say so in ``Case.bound_kind``. For P-matrices that are not H+ (2 x 2 and tiny dense cases) the max over
d is estimated by sampling the vertices and random points, times a safety factor of 4.

The certificate (nrmicp.convergence_bound) verdict per case is recorded in CERT_TABLE and
printed by ``python tests/test_hard_cases.py``.
"""
from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import nrmicp
from nrmicp.scenes.bai import bai_matrix

TOL = 1e-8


# ---------------------------------------------------------------------------------------------
# building blocks


def lap1d(m):
    return sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])


def lap2d(m):
    I = sp.identity(m)
    return sp.csr_matrix(sp.kron(I, lap1d(m)) + sp.kron(lap1d(m), I))


def bai(m, mu=4.0):
    """Bai's symmetric matrix of the scene."""
    return bai_matrix(m, mu=mu)


def convection(m, p, upwind):
    """-Δu + b·∇u on an m x m grid (h-scaled): off-diagonals in x are -1 - p, -1 + p (central) or
    -1 - 2p, -1 (upwind); p = b h / 2 is the cell Peclet number."""
    I = sp.identity(m)
    if upwind:
        Dx = sp.diags([(-1 - 2 * p) * np.ones(m - 1), (2 + 2 * p) * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
    else:
        Dx = sp.diags([(-1 - p) * np.ones(m - 1), 2 * np.ones(m), (-1 + p) * np.ones(m - 1)], [-1, 0, 1])
    return sp.csr_matrix(sp.kron(I, Dx) + sp.kron(lap1d(m), I) + 0.1 * sp.identity(m * m))


def known_parts(n, seed, degenerate=0.0):
    """g*, w* with a mixed active set; a fraction `degenerate` of the indices has g*_i = w*_i = 0."""
    rng = np.random.default_rng(seed)
    u = rng.random(n)
    active = u < 0.5
    g = np.where(active, 0.0, rng.uniform(0.5, 1.5, n))
    w = np.where(active, rng.uniform(0.5, 1.5, n), 0.0)
    if degenerate:
        deg = rng.random(n) < degenerate
        g[deg] = 0.0
        w[deg] = 0.0
    return g, w


def comparison(A):
    A = sp.csr_matrix(A)
    C = -abs(A)
    C.setdiag(abs(A.diagonal()))
    return C.toarray()


def is_h_plus(A):
    A = sp.csr_matrix(A)
    if np.any(A.diagonal() <= 0):
        return False
    C = comparison(A)
    try:
        Ci = np.linalg.inv(C)
    except np.linalg.LinAlgError:
        return False
    return bool(np.all(Ci >= -1e-12) and np.isfinite(Ci).all())


def kappa_hplus(A):
    """Chen–Xiang: ||<A>^-1 max(Λ, I)||_∞ for an H+-matrix A."""
    A = sp.csr_matrix(A)
    C = comparison(A)
    L = np.maximum(A.diagonal(), 1.0)
    return float(np.abs(np.linalg.solve(C, np.diag(L))).sum(axis=1).max())


def kappa_sampled(A, samples=300, seed=0):
    """max_d ||(I − D + DA)⁻¹||_∞ estimated on vertices (n ≤ 10) and random d, times 4."""
    A = np.asarray(sp.csr_matrix(A).toarray())
    n = A.shape[0]
    rng = np.random.default_rng(seed)
    ds = [np.array(v, float) for v in itertools.product((0.0, 1.0), repeat=n)] if n <= 10 else []
    ds += list(rng.random((samples, n)))
    best = 0.0
    for d in ds:
        M = np.eye(n) - np.diag(d) + np.diag(d) @ A
        best = max(best, np.abs(np.linalg.inv(M)).sum(axis=1).max())
    return 4.0 * best


# ---------------------------------------------------------------------------------------------
# the cases


@dataclass
class Case:
    name: str
    A: sp.csr_matrix
    q: np.ndarray
    zeta: object = None           # None | ndarray | Affine | callable
    z_star: Optional[np.ndarray] = None
    lipschitz: float = 0.0        # ∞-norm Lipschitz constant of ζ (for the bound and the certificate)
    unique: bool = True           # a P-matrix: exactly one solution
    must_converge: tuple = ()     # configurations (names in CONFIGS) that must reach tol here
    may_refuse: bool = False      # the method may refuse A with a documented exception
    setup: dict = field(default_factory=dict)  # extra set-up options (e.g. omega2 for a zero diagonal)
    bound_kind: str = ""

    def bound(self):
        """κ such that ||z − z*||_∞ ≤ κ ||min(w, g)||_∞ (+ rounding) documents the true error."""
        if self.z_star is None or self.lipschitz >= 1:
            return None
        if is_h_plus(self.A):
            k = kappa_hplus(self.A)
            self.bound_kind = "Chen–Xiang (H+)" + (" / (1 − L), heuristic for ICP" if self.lipschitz else "")
        elif self.A.shape[0] <= 10:
            k = kappa_sampled(self.A)
            self.bound_kind = "sampled max_d ||(I−D+DA)^-1|| x 4" + (" / (1 − L)" if self.lipschitz else "")
        else:
            return None
        return k / (1.0 - self.lipschitz)


def _known_lcp(name, A, seed=0, degenerate=0.0, **kw):
    A = sp.csr_matrix(A)
    g, w = known_parts(A.shape[0], seed, degenerate)
    return Case(name, A, w - A @ g, None, g, **kw)


def _known_sin_icp(name, A, c, seed=0, degenerate=0.0, **kw):
    A = sp.csr_matrix(A)
    n = A.shape[0]
    g, w = known_parts(n, seed, degenerate)
    rng = np.random.default_rng(seed + 1)
    z = g + rng.uniform(-1, 1, n)
    s = z - g - c * np.sin(z)

    def zeta(x):
        return c * np.sin(x) + s

    return Case(name, A, w - A @ z, zeta, z, lipschitz=c, **kw)


def _known_obstacle(name, A, seed=0, scale_c=1.0, **kw):
    A = sp.csr_matrix(A)
    n = A.shape[0]
    g, w = known_parts(n, seed)
    rng = np.random.default_rng(seed + 3)
    c = rng.uniform(-1, 1, n) * scale_c
    z = g + c
    return Case(name, A, w - A @ z, c, z, **kw)


def _ill_laplacian(m, cond):
    """2D Laplacian shifted so that its smallest eigenvalue is λmax/cond: an M-matrix with
    condition number ≈ cond."""
    L = lap2d(m)
    k = np.arange(1, m + 1)
    ev = 2 - 2 * np.cos(k * np.pi / (m + 1))
    lmin, lmax = 2 * ev.min(), 2 * ev.max()
    mu = lmax / cond
    return sp.csr_matrix(L + (mu - lmin) * sp.identity(m * m))


def _p_not_hplus_random(n, seed):
    """A positive-definite nonsymmetric matrix S + K (S SPD, K skew with a large norm): every
    principal submatrix is positive definite, so A is a P-matrix; <A> is not an M-matrix."""
    rng = np.random.default_rng(seed)
    G = rng.normal(size=(n, n))
    S = G @ G.T / n + 0.5 * np.eye(n)
    K = rng.normal(size=(n, n))
    K = 3 * (K - K.T)
    return S + K


def _badly_scaled(m, seed, kind):
    """Bai μ=4 with rows and columns scaled by factors in [1e-3, 1e3] (entries span ~1e-6..1e6)."""
    rng = np.random.default_rng(seed)
    B = bai(m)
    n = B.shape[0]
    dr = 10.0 ** rng.uniform(-3, 3, n)
    dc = 10.0 ** rng.uniform(-3, 3, n)
    A = sp.csr_matrix(sp.diags(dr) @ B @ sp.diags(dc))
    g, w = known_parts(n, seed)
    # Solution of the scaled problem: z = Dc⁻¹ z_B, w = Dr w_B.
    if kind == "lcp":
        z = g / dc
        return Case("badly-scaled-lcp", A, dr * w - A @ z, None, z, unique=True)
    c = rng.uniform(-1, 1, n) / dc
    z = g / dc + c
    return Case("badly-scaled-obstacle", A, dr * w - A @ z, c, z, unique=True)


def _nonsmooth(m, seed=0):
    """ζ(z) = 0.2·max(z − 1, 0) − 0.1·min(z, 0) + s (Lipschitz 0.2, nonsmooth at 0 and 1)."""
    A = bai(m)
    n = A.shape[0]
    g, w = known_parts(n, seed)
    rng = np.random.default_rng(seed + 5)
    z = g + rng.choice([-1.0, 0.0, 1.0, 2.0], n)   # many z*_i exactly at the kinks

    def base(x):
        return 0.2 * np.maximum(x - 1, 0) - 0.1 * np.minimum(x, 0)

    s = z - g - base(z)

    def zeta(x):
        return base(x) + s

    return Case("nonsmooth-zeta", A, w - A @ z, zeta, z, lipschitz=0.2)


def _empty_rows_cols():
    """Bai m=4 with row and column 5 emptied (no stored entries at all) and q_5 > 0: z_5 = 0."""
    A = bai(4).tolil()
    A[5, :] = 0
    A[:, 5] = 0
    A = sp.csr_matrix(A)
    A.eliminate_zeros()
    g, w = known_parts(16, 3)
    g[5], w[5] = 0.0, 2.0
    return Case("empty-row-col", A, w - A @ g, None, g, may_refuse=True, setup=dict(omega2=1.0),
                must_converge=("nrm", "nrmgs"))


def _explicit_zeros():
    A = bai(4)
    n = A.shape[0]
    rows = np.repeat(np.arange(n), np.diff(A.indptr))
    # store a zero at (i, n-1-i) for every i (some coincide with existing entries: skip those)
    extra = [(i, n - 1 - i) for i in range(n) if A[i, n - 1 - i] == 0]
    r = np.concatenate([rows, [e[0] for e in extra]])
    c = np.concatenate([A.indices, [e[1] for e in extra]])
    v = np.concatenate([A.data, np.zeros(len(extra))])
    Az = sp.csr_matrix((v, (r, c)), shape=A.shape)   # COO -> CSR keeps the explicit zeros
    assert Az.nnz > A.nnz
    case = _known_lcp("explicit-zeros", Az, seed=4, must_converge=("nrm", "nrmgs", "nrmgs+anderson"))
    return case


def _duplicates():
    A = bai(4)
    coo = A.tocoo()
    # split every entry into two halves: COO with duplicates summing to A
    r = np.concatenate([coo.row, coo.row])
    c = np.concatenate([coo.col, coo.col])
    v = np.concatenate([coo.data / 2, coo.data / 2])
    D = sp.coo_matrix((v, (r, c)), shape=A.shape)
    g, w = known_parts(16, 5)
    return Case("duplicate-entries", D, w - A @ g, None, g, must_converge=("nrm", "nrmgs", "nrmgs+anderson"))


def build_cases(size="small"):
    """The suite. size 'small' for the tests, 'moderate' for benchmarks/stabilizers.py."""
    m = 8 if size == "small" else 16
    cases = []
    # ill-conditioned: 2D Laplacian shifted to condition numbers 1e4 and 1e7 (M-matrices)
    for cond in (1e4, 1e7):
        cases.append(_known_lcp(f"laplacian-cond{cond:.0e}-lcp", _ill_laplacian(m, cond)))
        cases.append(_known_sin_icp(f"laplacian-cond{cond:.0e}-icp", _ill_laplacian(m, cond), 0.05))
    # the documented trouble case: Laplacian, μ = 0, ζ = 0.05 sin(z) + s
    cases.append(_known_sin_icp("laplacian-mu0-icp", lap2d(2 * m), 0.05,
                                must_converge=("nrmgs+anderson+explicit", "nrm+explicit")))
    # nonsymmetric convection-dominated: upwind (M-matrix) and central (P, not H+: PD + skew)
    cases.append(_known_lcp("convection-upwind-p10", convection(m, 10.0, True), must_converge=("nrmgs",)))
    cases.append(_known_lcp("convection-central-p5", convection(m, 5.0, False)))
    # H+ but neither symmetric nor an M-matrix (mixed-sign off-diagonals, diagonally dominant)
    rng = np.random.default_rng(7)
    n = m * m
    R = sp.random(n, n, density=4.0 / n, random_state=7, data_rvs=lambda k: rng.uniform(-1, 1, k))
    R.setdiag(0)
    R = sp.csr_matrix(R)
    Hp = sp.csr_matrix(R + sp.diags(abs(R).sum(axis=1).A1 * 1.05 + 0.01))
    cases.append(_known_lcp("hplus-nonsym", Hp, must_converge=("nrmgs", "nrm")))
    # P-matrices that are not H+
    cases.append(_known_lcp("p-not-hplus-2x2", np.array([[1.0, 2.0], [-2.0, 1.0]]), seed=1))
    cases.append(_known_lcp("p-not-hplus-upper-2x2", np.array([[1.0, 4.0], [0.0, 1.0]]), seed=2))
    cases.append(_known_lcp("p-not-hplus-random-6", _p_not_hplus_random(6, 3), seed=3))
    # badly scaled rows and columns
    cases.append(_badly_scaled(m // 2 + 2, 11, "lcp"))
    cases.append(_badly_scaled(m // 2 + 2, 12, "obstacle"))
    # degenerate solutions: 30% of indices with g*_i = w*_i = 0
    cases.append(_known_lcp("degenerate-lcp", bai(m), degenerate=0.3, must_converge=("nrmgs", "nrm")))
    cases.append(_known_sin_icp("degenerate-icp", bai(m), 0.1, degenerate=0.3, must_converge=("nrmgs",)))
    # ζ's Lipschitz constant around and beyond the certificate's bound (Bai μ = 4)
    for c in (0.5, 0.9, 1.5, 3.0):
        cases.append(_known_sin_icp(f"lipschitz-{c}", bai(m), c))
    cases.append(_nonsmooth(m))
    # near-singular: 1D Neumann Laplacian (singular, PSD) + 1e-10 I
    Ln = lap1d(4 * m).tolil()
    Ln[0, 0] = Ln[-1, -1] = 1.0
    Ns = sp.csr_matrix(Ln + 1e-10 * sp.identity(4 * m))
    rng = np.random.default_rng(9)
    cases.append(Case("near-singular", Ns, rng.uniform(-1, 1, 4 * m), None, None, unique=True))
    # not P: no solution (infeasible) and several solutions
    cases.append(Case("not-P-no-solution", sp.csr_matrix(np.array([[1.0, -1.0], [-1.0, 1.0]])),
                      np.array([-1.0, -1.0]), unique=False))
    # nrm's Lm = I + A = [[2, 2], [2, 2]] is singular: refused (LinAlgError) on every machine
    cases.append(Case("not-P-three-solutions", sp.csr_matrix(np.array([[1.0, 2.0], [2.0, 1.0]])),
                      np.array([-1.0, -1.0]), unique=False, may_refuse=True))
    cases.append(Case("not-P-negative-diag", sp.csr_matrix(-np.eye(3)), np.ones(3), unique=False,
                      may_refuse=True))
    # n = 1
    cases.append(Case("n1-lcp", sp.csr_matrix([[2.0]]), np.array([-4.0]), None, np.array([2.0]),
                      must_converge=("nrm", "nrmgs")))
    cases.append(Case("n1-obstacle", sp.csr_matrix([[2.0]]), np.array([-4.0]), np.array([3.0]), np.array([3.0]),
                      must_converge=("nrm", "nrmgs")))
    cases.append(Case("n1-icp", sp.csr_matrix([[3.0]]), np.array([-3.0]), lambda z: 0.5 * np.cos(z),
                      None, lipschitz=0.5))
    cases.append(_empty_rows_cols())
    cases.append(_explicit_zeros())
    cases.append(_duplicates())
    return cases


# configurations: name -> solve options
CONFIGS = {
    "nrmgs": dict(method="nrmgs"),
    "nrm": dict(method="nrm"),
    "nrmgs+explicit": dict(method="nrmgs", z_update="explicit"),
    "nrm+explicit": dict(method="nrm", z_update="explicit"),
    "nrmgs+anderson": dict(method="nrmgs", accelerate="anderson"),
    "nrmgs+anderson+explicit": dict(method="nrmgs", accelerate="anderson", z_update="explicit"),
    "nrmgs+scale": dict(method="nrmgs", scale="both"),
    "nrmgs+scale_rows": dict(method="nrmgs", scale="rows"),
    "nrm+scale": dict(method="nrm", scale="both"),
}


#: The status of every (case x configuration) solve, one letter per configuration in the order of
#: CONFIGS: C converged, S stagnated, M max_iterations, D diverged; V ValueError and L LinAlgError
#: for the documented refusals. Iteration counts are deterministic, so a change of any pair (a
#: regression from CONVERGED to STAGNATED, or an improvement) must be made here on purpose.
STATUS_LETTER = {"CONVERGED": "C", "STAGNATED": "S", "MAX_ITERATIONS": "M", "DIVERGED": "D",
                 "ValueError": "V", "LinAlgError": "L"}
#                                   nrmgs, nrm, nrmgs+explicit, nrm+explicit, nrmgs+anderson,
#                                   nrmgs+anderson+explicit, nrmgs+scale, nrmgs+scale_rows, nrm+scale
EXPECTED_STATUS = {
    "laplacian-cond1e+04-lcp": "CCCCCCCCC",
    "laplacian-cond1e+04-icp": "CSCCCCCCS",
    "laplacian-cond1e+07-lcp": "CCCCCCCCC",
    "laplacian-cond1e+07-icp": "CSCCCCCCS",
    "laplacian-mu0-icp":       "CCCCCCCCC",
    "convection-upwind-p10":   "CCCCCCCCC",
    "convection-central-p5":   "DCDCCCDDC",
    "hplus-nonsym":            "CCCCCCCCC",
    "p-not-hplus-2x2":         "DCDCCCDDC",
    "p-not-hplus-upper-2x2":   "CCCCCCCCC",
    "p-not-hplus-random-6":    "DCDCDDDDC",
    "badly-scaled-lcp":        "CSCSCCCCC",
    "badly-scaled-obstacle":   "CSCSCCCCC",
    "degenerate-lcp":          "CCCCCCCCC",
    "degenerate-icp":          "CCCCCCCCC",
    "lipschitz-0.5":           "CCCSCCCCC",
    "lipschitz-0.9":           "CCCSCCCCC",
    "lipschitz-1.5":           "CCCSCCCCC",
    "lipschitz-3.0":           "SCSSSSSMS",
    "nonsmooth-zeta":          "CCCSCCCCC",
    "near-singular":           "CCCCCCCCC",
    "not-P-no-solution":       "SSSSSSSSS",  # nrm: z runs away along (1, 1) with Res constant (was M)
    "not-P-three-solutions":   "CLCLCCCCL",
    "not-P-negative-diag":     "VLVLVVVVL",
    "n1-lcp":                  "CCCCCCCCC",
    "n1-obstacle":             "CCCCCCCCC",
    "n1-icp":                  "CCCCCCCCC",
    "empty-row-col":           "CCCCCCCCC",
    "explicit-zeros":          "CCCCCCCCC",
    "duplicate-entries":       "CCCCCCCCC",
}


# ---------------------------------------------------------------------------------------------
# the invariants


def numpy_residual(case, z):
    """Res(z) in plain numpy, from the ORIGINAL data (duplicates summed by scipy's matmul)."""
    A = sp.csr_matrix(case.A) if not isinstance(case.A, np.ndarray) else case.A
    w = A @ z + case.q
    zt = case.zeta
    if zt is None:
        g = z
    elif callable(zt):
        g = z - np.asarray(zt(z), float)
    else:
        g = z - np.asarray(zt, float)
    return float(np.linalg.norm(np.minimum(w, g))), np.minimum(w, g)


def run(case, config, *, tol=TOL, maxiter=3000):
    opts = dict(CONFIGS[config], **case.setup)
    if opts.get("method") in ("nrm", "nrmm") and "omega2" in case.setup:
        pass
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", nrmicp.ConversionWarning)
        return nrmicp.solve(case.A, case.q, case.zeta, tol=tol, maxiter=maxiter, **opts)


def check_honest(case, config, res, tol=TOL, maxiter=3000):
    assert np.all(np.isfinite(res.z)), f"{case.name}/{config}: non-finite z"
    assert res.z.shape == case.q.shape
    r_np, rvec = numpy_residual(case, res.z)
    if res.success:
        assert res.status == nrmicp.Status.CONVERGED
        assert r_np < tol, f"{case.name}/{config}: success with Res = {r_np:.3e} >= tol"
    else:
        assert res.status != nrmicp.Status.CONVERGED
        assert res.iterations <= maxiter
    # the reported residual is the residual of the returned z (the best iterate)
    if np.isfinite(res.residual):
        assert res.residual == pytest.approx(r_np, rel=1e-6, abs=1e-13)
    # w = Az + q of the returned z
    A = sp.csr_matrix(case.A)
    np.testing.assert_allclose(res.w, A @ res.z + case.q, rtol=1e-9, atol=1e-9 * (1 + np.abs(res.w).max()))
    if res.success and case.z_star is not None and case.unique:
        kappa = case.bound()
        if kappa is not None:
            err = np.abs(res.z - case.z_star).max()
            allowed = kappa * np.abs(rvec).max() + 1e-9 * (1 + np.abs(case.z_star).max())
            assert err <= allowed, f"{case.name}/{config}: error {err:.3e} > bound {allowed:.3e} ({case.bound_kind})"


CASES = build_cases("small")
CASE_IDS = [c.name for c in CASES]


@pytest.mark.parametrize("config", list(CONFIGS))
@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_hard_case_is_honest(case, config):
    expected = EXPECTED_STATUS[case.name][list(CONFIGS).index(config)]
    try:
        res = run(case, config)
    except (ValueError, np.linalg.LinAlgError) as exc:
        assert case.may_refuse, f"{case.name}/{config}: unexpected {type(exc).__name__}: {exc}"
        assert "omega2" in str(exc) or "left matrix" in str(exc) or "singular" in str(exc)
        assert STATUS_LETTER[type(exc).__name__] == expected, f"{case.name}/{config}: {exc}"
        return
    check_honest(case, config, res)
    if config in case.must_converge:
        assert res.success, f"{case.name}/{config}: {res.message}"
    assert STATUS_LETTER[res.status.name] == expected, f"{case.name}/{config}: {res.message} (expected {expected})"


def test_expected_status_covers_every_pair():
    assert set(EXPECTED_STATUS) == set(CASE_IDS)
    assert all(len(v) == len(CONFIGS) and set(v) <= set(STATUS_LETTER.values()) for v in EXPECTED_STATUS.values())


@pytest.mark.parametrize("method", ["nrm", "nrmgs"])
def test_documented_divergence_is_cured(method):
    """Laplacian μ = 0, ζ = 0.05 sin z + s on a 48 x 48 grid (a size where it fails): the paper's
    z-update ('solve') does not converge, the explicit z-update and explicit + Anderson do."""
    case = _known_sin_icp("laplacian-mu0-icp-48", lap2d(48), 0.05)
    paper = nrmicp.solve(case.A, case.q, case.zeta, method=method, z_update="solve", tol=TOL, maxiter=3000)
    assert paper.status in (nrmicp.Status.STAGNATED, nrmicp.Status.MAX_ITERATIONS), paper.message
    assert numpy_residual(case, paper.z)[0] >= TOL
    for accelerate in ("none", "anderson"):
        res = nrmicp.solve(case.A, case.q, case.zeta, method=method, z_update="explicit", accelerate=accelerate,
                           tol=TOL, maxiter=3000)
        assert res.success, res.message
        assert numpy_residual(case, res.z)[0] < TOL
        # Chen–Xiang for this M-matrix (A = ⟨A⟩, A⁻¹ ≥ 0): κ = ||A⁻¹ max(Λ, 1)||_∞, one sparse solve
        kappa = float(spla.spsolve(sp.csc_matrix(case.A), np.maximum(case.A.diagonal(), 1.0)).max())
        assert np.abs(res.z - case.z_star).max() <= kappa * TOL / (1 - case.lipschitz)


@pytest.mark.parametrize("config", ["nrmgs", "nrm", "nrmgs+anderson", "nrmgs+explicit", "nrmgs+scale"])
@pytest.mark.parametrize("name", ["laplacian-cond1e+04-lcp", "degenerate-icp", "badly-scaled-obstacle", "n1-lcp"])
def test_unreachable_tol_stagnates(name, config):
    """tol = 1e-300 cannot be met in floating point: STAGNATED well before maxiter, best iterate."""
    case = next(c for c in CASES if c.name == name)
    maxiter = 100_000
    res = run(case, config, tol=1e-300, maxiter=maxiter)
    if res.success:  # only legitimate when the iterate is exact (Res = 0, e.g. n = 1)
        assert numpy_residual(case, res.z)[0] < 1e-300
        return
    assert res.status == nrmicp.Status.STAGNATED, res.message
    assert res.iterations < maxiter // 10
    check_honest(case, config, res, tol=1e-300, maxiter=maxiter)
    # the best iterate is as good as a tol = 1e-8 solve
    good = run(case, config)
    if good.success:
        assert res.residual <= max(good.residual, 1e-10)


@pytest.mark.parametrize("kind", ["lcp", "obstacle"])
def test_scaling_solves_the_badly_scaled_problem(kind):
    case = next(c for c in CASES if c.name == f"badly-scaled-{kind}")
    res = run(case, "nrmgs+scale")
    check_honest(case, "nrmgs+scale", res)
    assert res.success, res.message
    assert res.scaling["kind"] == "both"


def test_duplicates_and_explicit_zeros_do_not_change_the_answer():
    base = bai(4)
    for name in ("duplicate-entries", "explicit-zeros"):
        case = next(c for c in CASES if c.name == name)
        res = run(case, "nrmgs")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", nrmicp.ConversionWarning)
            ref = nrmicp.solve(base if name == "duplicate-entries" else sp.csr_matrix(case.A.toarray()), case.q)
        np.testing.assert_allclose(res.z, ref.z, atol=1e-10)


# ---------------------------------------------------------------------------------------------
# the README's stabilizer table ("Stabilizers"): moderate size, nrmgs, maxiter 3000,
# against the paper's z-update ('solve' for an ICP)

STABILIZERS = {"explicit": dict(z_update="explicit"), "anderson": dict(accelerate="anderson", anderson_m=5),
               "scale": dict(scale="both"),
               "explicit+anderson": dict(accelerate="anderson", anderson_m=5, z_update="explicit")}
_ANDERSON_FIXES = ["laplacian-mu0-icp", "convection-central-p5", "p-not-hplus-2x2", "lipschitz-3.0", "near-singular"]
_EXPLICIT_FIXES = ["laplacian-cond1e+04-icp", "laplacian-cond1e+07-icp", "laplacian-mu0-icp"]
#: stabilizer -> (cases it turns from failure into convergence, cases it turns into failure)
README_STABILIZER_TABLE = {
    "explicit": (_EXPLICIT_FIXES, []),
    "anderson": (_ANDERSON_FIXES, ["lipschitz-1.5"]),
    "scale": ([], []),
    "explicit+anderson": (sorted(set(_EXPLICIT_FIXES + _ANDERSON_FIXES) - {"lipschitz-3.0"}), []),
}


def _converges(case, method, opts):
    opts = dict({"z_update": "explicit" if case.zeta is None else "solve"}, **opts, **case.setup)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", nrmicp.ConversionWarning)
            res = nrmicp.solve(case.A, case.q, case.zeta, method=method, tol=TOL, maxiter=3000, **opts)
    except (ValueError, np.linalg.LinAlgError):
        return False
    return res.success and numpy_residual(case, res.z)[0] < TOL


@pytest.fixture(scope="module")
def moderate_cases():
    return build_cases("moderate")


def test_readme_stabilizer_table(moderate_cases):
    plain = {c.name: _converges(c, "nrmgs", {}) for c in moderate_cases}
    for name, opts in STABILIZERS.items():
        ok = {c.name: _converges(c, "nrmgs", opts) for c in moderate_cases}
        fixed = sorted(n for n in ok if ok[n] and not plain[n])
        broke = sorted(n for n in ok if plain[n] and not ok[n])
        assert (fixed, broke) == tuple(sorted(x) for x in README_STABILIZER_TABLE[name]), name
        # "No setting converges on p-not-hplus-random-6 ... or on not-P-no-solution"
        assert not ok["p-not-hplus-random-6"] and not ok["not-P-no-solution"], name


def test_readme_scaling_fixes_nrm_on_the_badly_scaled_cases(moderate_cases):
    for case in moderate_cases:
        if case.name.startswith("badly-scaled"):
            assert not _converges(case, "nrm", {}) and _converges(case, "nrm", {"scale": "both"}), case.name


# ---------------------------------------------------------------------------------------------
# certificate verdicts


def certificate_table(cases=None, methods=("nrmgs", "nrm")):
    rows = []
    for case in cases or CASES:
        verdicts = []
        for method in methods:
            try:
                cert = nrmicp.convergence_bound(case.A, method=method, lipschitz=case.lipschitz,
                                                **({"omega2": case.setup["omega2"]} if "omega2" in case.setup else {}))
                verdicts.append(f"{'certified' if cert.certified else 'not certified'} (rho={cert.rho:.3g})")
            except ValueError as exc:  # the certificate refuses some matrices (a non-positive diagonal, a singular left matrix)
                assert "omega2" in str(exc) or "left matrix" in str(exc), str(exc)
                verdicts.append(f"n/a ({type(exc).__name__})")
        rows.append((case.name, *verdicts))
    return rows


#: The (case, method) pairs the certificate refuses, with a ValueError naming why.
CERTIFICATE_NA = {("not-P-three-solutions", "nrm"), ("not-P-negative-diag", "nrmgs"), ("not-P-negative-diag", "nrm")}


def test_certificate_runs_on_every_case():
    rows = certificate_table()
    assert len(rows) == len(CASES)
    na = {(row[0], method) for row in rows for method, v in zip(("nrmgs", "nrm"), row[1:]) if v.startswith("n/a")}
    assert na == CERTIFICATE_NA
    # a certified case must converge with that method
    for case, row in zip(CASES, rows):
        for method, verdict in zip(("nrmgs", "nrm"), row[1:]):
            if verdict.startswith("certified"):
                res = run(case, method)
                assert res.success, f"{case.name}/{method} certified but {res.message}"


if __name__ == "__main__":  # print the certificate table and a status matrix
    print("| case | nrmgs | nrm |")
    print("|---|---|---|")
    for row in certificate_table():
        print("| " + " | ".join(row) + " |")
    print()
    print("| case | " + " | ".join(CONFIGS) + " |")
    print("|---|" + "---|" * len(CONFIGS))
    for case in CASES:
        cells = []
        for config in CONFIGS:
            try:
                r = run(case, config)
                cells.append(f"{r.status.name}({r.iterations})")
            except Exception as exc:
                cells.append(type(exc).__name__)
        print(f"| {case.name} | " + " | ".join(cells) + " |")
