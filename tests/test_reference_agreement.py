"""nrmicp's C++ core against the plain numpy reference (tests/reference_impl.py).

(a) the first iterates (maxiter = 1, 2, 3) agree to 1e-10 (relative): z and the Res history;
(b) the iteration counts to tol = 1e-8 are equal;
(c) at m = 64 the returned z satisfies the complementarity conditions, checked here in numpy;
(d) at m = 64 the returned z is within 1e-6 of the known solution z*.

Every parameter (omega1, omega2, phi, alpha, beta, theta, gamma) and the initial guess are
passed explicitly to both sides, so neither relies on the other's per-method defaults.  Methods
whose table entry fixes Omega1 = I and phi = 0 (mms, two_sweep) get neither argument.  A few
tests at the end check the defaults SPEC.md fixes (z_update='auto', the method table, x0 = 0).

Problems (problems.py): Bai's symmetric and nonsymmetric matrices, as an LCP and as ICPs whose
zeta is a Python callable, an nrmicp.Affine map (evaluated in C++) or a constant obstacle.
"""

import functools
import itertools

import numpy as np
import pytest

import nrmicp
from problems import AffineZeta, ConstantZeta, make_problem
from reference_impl import METHODS, reference_solve

TOL = 1e-8
GAMMA = 2.0               # not the default 1: exercises gamma in the x0 mapping and the z-updates
Z_UPDATES = ("explicit", "solve")
# (kind, symmetric): a Python-callable zeta ('icp'), zeta = Bz + c evaluated in C++ ('affine'),
# a constant obstacle solved as a shifted LCP ('obstacle'); see problems.py.
PROBLEMS = [("lcp", True), ("lcp", False), ("icp", True), ("icp", False),
            ("affine", False), ("obstacle", False)]
M_SMALL = 10              # n = 100: agreement with the reference
M_LARGE = 64              # n = 4096: convergence to z*, core only


def method_parameters(method, A):
    """Explicit parameters per method, as keyword arguments valid for both implementations.

    They are chosen away from the defaults (vector Omega1, phi > 0, alpha != beta, theta < 1,
    nrmm's alpha != mean(diag A)) so that a parameter the core ignores shows up as a mismatch.
    """
    n = A.shape[0]
    d = A.diagonal()
    w1 = 1.0 + 0.1 * np.cos(np.arange(n))          # a non-constant positive Omega1
    table = {
        "nrm": dict(omega1=1.0, omega2=1.0, phi=0.5),
        "nrmm": dict(omega1=1.0, alpha=7.0, phi=0.25),
        "nrmaor": dict(omega1=w1, omega2=d * w1, phi=0.3, alpha=1.1, beta=0.9),
        "nrmsor": dict(omega1=1.0, omega2=d, phi=0.0, alpha=1.2),
        "nrmgs": dict(omega1=1.0, omega2=1.2 * d, phi=0.2),
        "nrmj": dict(omega1=w1, omega2=d * w1, phi=0.0),
        "mms": dict(omega2=d, alpha=1.1, beta=1.0),
        "two_sweep": dict(omega2=d, alpha=1.0, beta=1.0, theta=0.9),
    }
    return table[method]


@functools.lru_cache(maxsize=None)
def problem(kind, m, symmetric):
    return make_problem(kind, m, symmetric)


def core_zeta(zeta):
    """zeta as nrmicp takes it: None, a callable, nrmicp.Affine(B, c), or a constant vector."""
    if isinstance(zeta, AffineZeta):
        return nrmicp.Affine(zeta.B, zeta.c)
    if isinstance(zeta, ConstantZeta):
        return zeta.c
    return zeta


# The initial guess of z is passed explicitly too (zeros unless a test says otherwise);
# test_default_initial_guess_is_zero checks the default separately.

def core_solve(P, method, z_update, z0=None, **kwargs):
    z0 = np.zeros(P.q.size) if z0 is None else z0
    return nrmicp.solve(P.A, P.q, core_zeta(P.zeta), method=method, gamma=GAMMA, z_update=z_update,
                        x0=z0, **method_parameters(method, P.A), **kwargs)


def ref_solve(P, method, z_update, z0=None, **kwargs):
    z0 = np.zeros(P.q.size) if z0 is None else z0
    return reference_solve(P.A, P.q, P.zeta, method=method, gamma=GAMMA, z_update=z_update,
                           z0=z0, **method_parameters(method, P.A), **kwargs)


def case_id(method, z_update, kind, symmetric):
    return f"{method}-{z_update}-{kind}-{'sym' if symmetric else 'nonsym'}"


CASES = [pytest.param(method, z_update, kind, sym, id=case_id(method, z_update, kind, sym))
         for method, z_update, (kind, sym) in itertools.product(METHODS, Z_UPDATES, PROBLEMS)]

FIRST_ITERATE_CASES = [
    pytest.param(method, z_update, kind, sym, k, id=f"{case_id(method, z_update, kind, sym)}-k{k}")
    for method, z_update, (kind, sym), k in itertools.product(METHODS, Z_UPDATES, PROBLEMS, (1, 2, 3))]


def relative_error(actual, expected):
    return np.linalg.norm(actual - expected) / max(np.linalg.norm(expected), 1e-300)


# ---- (a) the first iterates agree ---------------------------------------------------------

@pytest.mark.parametrize("method, z_update, kind, symmetric, k", FIRST_ITERATE_CASES)
def test_first_iterates_z_agree(method, z_update, kind, symmetric, k):
    P = problem(kind, M_SMALL, symmetric)
    ref = ref_solve(P, method, z_update, tol=TOL, maxiter=k)
    res = core_solve(P, method, z_update, tol=TOL, maxiter=k, record_history=True)
    assert not ref.converged
    assert relative_error(res.z, ref.z) < 1e-10, (
        f"core z = {res.z[:4]}..., reference z = {ref.z[:4]}...")


@pytest.mark.parametrize("method, z_update, kind, symmetric, k", FIRST_ITERATE_CASES)
def test_first_iterates_residual_history_agrees(method, z_update, kind, symmetric, k):
    P = problem(kind, M_SMALL, symmetric)
    ref = ref_solve(P, method, z_update, tol=TOL, maxiter=k)
    res = core_solve(P, method, z_update, tol=TOL, maxiter=k, record_history=True)
    np.testing.assert_allclose(res.history["residual"], ref.residuals, rtol=1e-10, atol=0)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("z_update", Z_UPDATES)
def test_first_iterates_agree_from_initial_guess(method, z_update):
    """A nonzero x0 (initial guess of z) goes through the x0 mapping identically."""
    P = problem("icp", M_SMALL, False)
    z0 = P.z_star + np.random.default_rng(7).uniform(-0.5, 0.5, P.z_star.size)
    ref = ref_solve(P, method, z_update, tol=TOL, maxiter=2, z0=z0)
    res = core_solve(P, method, z_update, tol=TOL, maxiter=2, z0=z0, record_history=True)
    np.testing.assert_allclose(res.history["residual"], ref.residuals, rtol=1e-10, atol=0)
    assert relative_error(res.z, ref.z) < 1e-10


# ---- (b) the iteration counts agree ------------------------------------------------------

@pytest.mark.parametrize("method, z_update, kind, symmetric", CASES)
def test_iteration_counts_agree(method, z_update, kind, symmetric):
    P = problem(kind, M_SMALL, symmetric)
    ref = ref_solve(P, method, z_update, tol=TOL, maxiter=5000)
    res = core_solve(P, method, z_update, tol=TOL, maxiter=5000)
    assert ref.converged and res.success
    assert res.nit == ref.nit


@pytest.mark.parametrize("method, z_update, kind, symmetric", CASES)
def test_reference_converges_to_known_solution(method, z_update, kind, symmetric):
    """The reference on its own: it solves the small problems (a check of the reference)."""
    P = problem(kind, M_SMALL, symmetric)
    ref = ref_solve(P, method, z_update, tol=TOL, maxiter=5000)
    assert ref.converged
    assert np.max(np.abs(ref.z - P.z_star)) < 1e-6


# ---- (c), (d) the core solves the m = 64 problems --------------------------------------------

@functools.lru_cache(maxsize=None)
def large_solution(method, z_update, kind, symmetric):
    P = problem(kind, M_LARGE, symmetric)
    return P, core_solve(P, method, z_update, tol=TOL, maxiter=5000)


@pytest.mark.parametrize("method, z_update, kind, symmetric", CASES)
def test_large_problem_converges(method, z_update, kind, symmetric):
    P, res = large_solution(method, z_update, kind, symmetric)
    assert res.success
    assert res.status == nrmicp.Status.CONVERGED
    assert res.residual < TOL


@pytest.mark.parametrize("method, z_update, kind, symmetric", CASES)
def test_large_problem_solution_is_complementary(method, z_update, kind, symmetric):
    """The returned z, checked here from scratch: w >= 0, g >= 0, g^T w = 0, Res < tol."""
    P, res = large_solution(method, z_update, kind, symmetric)
    z = res.z
    w = P.A @ z + P.q
    g = z if P.zeta is None else z - P.zeta(z)
    assert np.linalg.norm(np.minimum(w, g)) < TOL          # Res recomputed here
    assert w.min() >= -TOL
    assert g.min() >= -TOL
    # |g^T w| = |sum min_i max_i| <= ||min(w, g)|| ||max(w, g)||  (Cauchy-Schwarz)
    assert abs(g @ w) < TOL * np.linalg.norm(np.maximum(w, g))


@pytest.mark.parametrize("method, z_update, kind, symmetric", CASES)
def test_large_problem_reports_its_residual_and_w(method, z_update, kind, symmetric):
    P, res = large_solution(method, z_update, kind, symmetric)
    w = P.A @ res.z + P.q
    g = res.z if P.zeta is None else res.z - P.zeta(res.z)
    np.testing.assert_allclose(res.w, w, rtol=0, atol=1e-12 * np.abs(w).max())
    assert res.residual == pytest.approx(np.linalg.norm(np.minimum(w, g)), rel=1e-6, abs=1e-12)


@pytest.mark.parametrize("method, z_update, kind, symmetric", CASES)
def test_large_problem_finds_known_solution(method, z_update, kind, symmetric):
    P, res = large_solution(method, z_update, kind, symmetric)
    assert np.max(np.abs(res.z - P.z_star)) < 1e-6


# ---- defaults the contract fixes -------------------------------------------------------------

# 'auto' is the explicit update: measured faster (no solve with A) and more robust than the
# paper's 'solve' on the hard-case suite (README, "Options": z_update); the baseline mms keeps
# its defining 'solve' update on an ICP (a constant obstacle is an LCP: explicit).
@pytest.mark.parametrize("method, kind, expected_update", [
    ("nrmgs", "lcp", "explicit"), ("nrmgs", "icp", "explicit"), ("nrmgs", "affine", "explicit"),
    ("nrmgs", "obstacle", "explicit"), ("mms", "lcp", "explicit"), ("mms", "icp", "solve"),
    ("mms", "affine", "solve"), ("mms", "obstacle", "explicit")])
def test_auto_z_update(method, kind, expected_update):
    P = problem(kind, M_SMALL, False)
    ref = ref_solve(P, method, expected_update, tol=TOL, maxiter=3)
    res = core_solve(P, method, "auto", tol=TOL, maxiter=3, record_history=True)
    np.testing.assert_allclose(res.history["residual"], ref.residuals, rtol=1e-10, atol=0)


SPEC_DEFAULTS = {   # SPEC.md's method table, for the methods whose every default it fixes
    "nrm": lambda A: dict(omega1=1.0, omega2=1.0, phi=0.0),
    "nrmm": lambda A: dict(omega1=1.0, alpha=A.diagonal().mean(), phi=0.0),
    "nrmgs": lambda A: dict(omega1=1.0, omega2=A.diagonal(), phi=0.0),
    "nrmj": lambda A: dict(omega1=1.0, omega2=A.diagonal(), phi=0.0),
    # the table's Ω1 = I, Ω2 = D, φ = 0, with solve()'s documented α = 1, β = α (and θ = 1)
    "nrmaor": lambda A: dict(omega1=1.0, omega2=A.diagonal(), phi=0.0, alpha=1.0, beta=1.0),
    "nrmsor": lambda A: dict(omega1=1.0, omega2=A.diagonal(), phi=0.0, alpha=1.0),
    "mms": lambda A: dict(omega2=A.diagonal(), alpha=1.0, beta=1.0),
    "two_sweep": lambda A: dict(omega2=A.diagonal(), alpha=1.0, beta=1.0, theta=1.0),
}


@pytest.mark.parametrize("method", sorted(SPEC_DEFAULTS))
def test_default_parameters_follow_spec_table(method):
    """nrmicp.solve with only `method` given iterates like the reference with SPEC's defaults."""
    P = problem("icp", M_SMALL, False)
    # SPEC: 'auto' is explicit, except 'solve' on an ICP for nrm with its default Omega2 = I and for mms.
    expected_update = "solve" if method in ("nrm", "mms") else "explicit"
    ref = reference_solve(P.A, P.q, P.zeta, method=method, z_update=expected_update, gamma=1.0,
                          tol=TOL, maxiter=3, **SPEC_DEFAULTS[method](P.A))
    res = nrmicp.solve(P.A, P.q, P.zeta, method=method, tol=TOL, maxiter=3, record_history=True)
    np.testing.assert_allclose(res.history["residual"], ref.residuals, rtol=1e-10, atol=0)


@pytest.mark.parametrize("kind", ["lcp", "icp", "affine", "obstacle"])
def test_default_initial_guess_is_zero(kind):
    """SPEC: x0 (the initial guess of z) defaults to zeros, whatever the kind of zeta."""
    P = problem(kind, M_SMALL, False)
    params = method_parameters("nrmgs", P.A)
    ref = reference_solve(P.A, P.q, P.zeta, method="nrmgs", z_update="explicit", gamma=GAMMA,
                          tol=TOL, maxiter=2, z0=np.zeros(P.q.size), **params)
    res = nrmicp.solve(P.A, P.q, core_zeta(P.zeta), method="nrmgs", z_update="explicit",
                       gamma=GAMMA, tol=TOL, maxiter=2, record_history=True, **params)
    np.testing.assert_allclose(res.history["residual"], ref.residuals, rtol=1e-10, atol=0)
