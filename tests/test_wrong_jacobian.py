"""A zeta_jacobian that does not deliver is given up (issue 37; docs/SPEC.md, the Newton member:
detail::JacobianCheck): method 'newton' goes on with the outer fixed point, says so in the message
and in ``path`` ('newton+outer'), and its answer is checked here in numpy, independently of nrmicp;
the right Jacobian is never flagged. The problems are also benchmarks/wrong_jacobian.py's."""
import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from nrmicp import scenes

FLAG = "zeta_jacobian looks wrong"


def averaging(m: int) -> sp.csr_matrix:
    """The 5-point averaging matrix on the m × m grid, rows normalized to sum 1 (‖S‖∞ = 1)."""
    t = sp.diags([np.ones(m - 1), np.ones(m), np.ones(m - 1)], [-1, 0, 1])
    eye = sp.identity(m)
    S = (sp.kron(eye, t) + sp.kron(t, eye)).tocsr()
    S.setdiag(1.0)
    return sp.csr_matrix(sp.diags(1.0 / np.asarray(S.sum(axis=1)).ravel()) @ S)


def averaging_problem(m: int, c: float = 0.3, k: int = 3):
    """(A, q, ζ, {name: zeta_jacobian or None}): the 2D obstacle scene with the nonlocal obstacle
    ζ(z) = ψ + c·S^k z (a contraction with factor c), its exact Jacobian c·S^k (sparse), the local
    part of it (its diagonal), zero, negated, ten times too large, or none."""
    pb = scenes.obstacle_2d(m, exact=False)
    J = sp.identity(m * m, format="csr")
    for _ in range(k):
        J = sp.csr_matrix(averaging(m) @ J)
    J = sp.csr_matrix(c * J)
    psi = np.asarray(pb.zeta, dtype=float)
    local = sp.diags(J.diagonal(), format="csr")
    jacs = {"exact": lambda z: J, "local": lambda z: local, "zero": lambda z: sp.csr_matrix(J.shape),
            "negated": lambda z: -J, "10x": lambda z: 10 * J, "none": None}
    return pb.A, pb.q, (lambda z: psi + J @ z), jacs


def thermoforming_problem(m: int, kappa: float = 2.0, delta: float = 1.0):
    """(A, q, ζ, {name: zeta_jacobian or None}): scenes.thermoforming_2d with a strong, wide heat
    coupling, ζ(z) = Φ₀ + κ (I − δΔ_h)⁻¹ s(z). Its derivative κ (I − δΔ_h)⁻¹ diag(s'(z)) is dense, so
    there is no 'exact'; 'local' is κ diag(s'(z)) (the inverse taken as I: a user's approximation)."""
    pb = scenes.thermoforming_2d(m, kappa=kappa, delta=delta, exact=False)
    phi0, ell = pb.reference["phi0"], pb.reference["ell"]

    def local(z):
        u = (z - phi0) / ell
        return sp.diags(kappa * -2 * u / ell / (1 + u * u) ** 2, format="csr")

    jacs = {"local": local, "zero": lambda z: sp.csr_matrix((m * m, m * m)), "negated": lambda z: -local(z),
            "10x": lambda z: 10 * local(z), "none": None}
    return pb.A, pb.q, pb.zeta, jacs


def complementarity(A, q, zeta, z) -> float:
    """‖min(Az + q, z − ζ(z))‖₂ relative to ‖min(q, −ζ(0))‖₂ (Res at z = 0), in numpy."""
    z0 = np.zeros_like(z)
    return float(np.linalg.norm(np.minimum(A @ z + q, z - zeta(z))) / np.linalg.norm(np.minimum(q, z0 - zeta(z0))))


def solve(problem, which, **kw):
    A, q, zeta, jacs = problem
    jac = {} if jacs[which] is None else {"zeta_jacobian": jacs[which]}
    return nrmicp.solve(A, q, zeta, method="newton", **jac, **kw)


@pytest.mark.parametrize("which", ["10x", "negated"])
def test_a_wrong_jacobian_is_given_up_for_the_outer_fixed_point_which_solves_the_problem(which):
    problem = thermoforming_problem(31)
    res = solve(problem, which, hierarchy=None)
    assert res.path == "newton+outer"
    assert FLAG in res.message and "outer fixed point" in res.message
    assert res.success and res.message.startswith("converged")
    assert res.outer_iterations > 0
    assert complementarity(*problem[:3], res.z) < 1e-6


def test_a_jacobian_ten_times_too_large_on_a_nonlocal_zeta_is_given_up():
    problem = averaging_problem(31)
    res = solve(problem, "10x", hierarchy=None)
    assert res.path == "newton+outer" and FLAG in res.message
    assert res.success
    assert complementarity(*problem[:3], res.z) < 1e-6


def test_a_local_jacobian_that_contracts_slowly_is_given_up_in_few_steps():
    # the case: an approximate (diagonal) Jacobian of a nonlocal ζ; 165 Newton steps before the check
    problem = thermoforming_problem(31)
    res = solve(problem, "local", hierarchy=None)
    assert res.path == "newton+outer" and "reduced Res by less than" in res.message
    assert res.success and res.nit < 100
    assert complementarity(*problem[:3], res.z) < 1e-6


def test_a_jacobian_given_up_though_it_matches_along_the_step_says_so_after_converged():
    # impulse control with ζ′ = 0.99 I: along the last step (nearly a shift of z) it misses ζ's difference
    # quotient by 5% only, so the core's note is the 'matches' one; it was lost when Python re-decided 'converged'
    p = scenes.build("impulse_control", "medium")
    res = nrmicp.solve(p.A, p.q, p.zeta, method="newton", zeta_jacobian=lambda z: 0.99 * sp.identity(p.n, format="csr"))
    assert res.path == "newton+outer" and res.success, res.message
    assert res.message.startswith("converged") and "the Newton steps with zeta_jacobian stopped converging" in res.message
    assert np.max(np.abs(res.z - p.z_exact)) < 1e-6 * np.max(np.abs(p.z_exact))


def test_the_outer_fixed_point_after_a_wrong_jacobian_counts_against_maxiter_and_keeps_the_word():
    problem = thermoforming_problem(31)
    full = solve(problem, "10x", hierarchy=None)
    res = solve(problem, "10x", hierarchy=None, maxiter=full.nit - 3)
    assert not res.success and res.nit <= full.nit - 3
    assert res.path == "newton+outer" and FLAG in res.message


@pytest.mark.parametrize("m", [15, 31, 47])
def test_the_exact_jacobian_of_a_nonlocal_zeta_is_not_flagged(m):
    problem = averaging_problem(m)
    res = solve(problem, "exact", hierarchy=None, tol=1e-10)
    assert res.success and res.path == "newton" and FLAG not in res.message
    # a Newton step or two, each followed by one outer step (the outer fixed point alone takes 8-9)
    assert res.outer_iterations <= 3
    assert complementarity(*problem[:3], res.z) < 1e-10


def test_the_exact_jacobian_of_a_nonlinear_zeta_is_not_flagged():
    A, q, psi = scenes.obstacle_2d(31, exact=False).A, scenes.obstacle_2d(31, exact=False).q, scenes.obstacle_2d(31, exact=False).zeta
    zeta = lambda z: psi + 0.2 * np.sin(z)  # noqa: E731
    res = nrmicp.solve(A, q, zeta, method="newton", zeta_jacobian=lambda z: sp.diags(0.2 * np.cos(z), format="csr"),
                       tol=1e-10)
    assert res.success and res.path == "newton" and FLAG not in res.message
    assert complementarity(A, q, zeta, res.z) < 1e-10


@pytest.mark.parametrize("scale", [-3.0, -1.0, 1.0, 2.0])
def test_a_jacobian_whose_every_step_fails_is_given_up_too(scale):
    """Found by review: ζ′ = scale · I for ζ = ψ + 0.2 sin z (true ζ′ = 0.2 cos z) made the first Newton step's Res
    grow (or, at I, left I − ζ′ singular on the active rows) and the fallback gave up: STAGNATED at the start
    with no word on ζ′, as no step was judged. The fallback's end now checks ζ′ against ζ's difference quotient."""
    n = 200
    A = sp.csr_matrix(sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n)) * (n + 1) ** 2)
    x = np.linspace(0, 1, n + 2)[1:-1]
    psi, q = -2 + 2 * (x - 0.5) ** 2, 50 * np.ones(n)

    def zeta(z):
        return psi + 0.2 * np.sin(z)
    res = nrmicp.solve(A, q, zeta, method="newton", zeta_jacobian=lambda z: scale * sp.identity(n, format="csr"))
    assert res.success and res.path == "newton+outer" and FLAG in res.message, res.message
    assert complementarity(A, q, zeta, res.z) < 1e-8
