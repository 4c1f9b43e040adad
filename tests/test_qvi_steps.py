"""method='newton' on QVIs with ζ's Jacobian: Newton steps on the whole ICP that do not grow with n
(issue 37), on impulse control (its selection Jacobian) and on ζ = ψ + 0.2 sin z (ζ′ = diag(0.2 cos z),
sparse or a LinearOperator). Checked against numpy: the scene's policy iteration (impulse control) and
min(Az + q, z − ζ(z)) computed here."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import nrmicp
from nrmicp import scenes
from test_newton import impulse_jacobian as newton_impulse_jacobian


def impulse_jacobian(problem):
    """The scene's selection Jacobian (nrmicp.scenes.impulse), counting its calls."""
    jac = newton_impulse_jacobian(problem)

    def jacobian(z):
        jacobian.calls += 1
        return jac(z)

    jacobian.calls = 0
    return jacobian


def sin_problem(m):
    """The 2D obstacle scene with ζ = ψ + 0.2 sin z, its geometric hierarchy, and ζ′ in both forms."""
    p = scenes.obstacle_2d(m, exact=False)
    psi = np.asarray(p.zeta, dtype=float)

    def zeta(z):
        return psi + 0.2 * np.sin(z)

    def sparse_jacobian(z):
        return sp.diags(0.2 * np.cos(z), format="csr")

    def operator_jacobian(z):
        d = 0.2 * np.cos(z)
        return spla.LinearOperator((p.n, p.n), matvec=lambda v: d * v.ravel(), dtype=float)

    return p, zeta, {"sparse": sparse_jacobian, "operator": operator_jacobian}


def test_impulse_control_with_its_jacobian_takes_as_many_newton_steps_at_every_n():
    calls = []
    for n in (101, 401, 1601):
        p = scenes.impulse_control(n)
        jacobian = impulse_jacobian(p)
        r = nrmicp.solve(p.A, p.q, p.zeta, method="newton", tol=1e-8, zeta_jacobian=jacobian)
        assert r.success, r.message
        assert np.max(np.abs(r.z - p.z_exact)) < 1e-7 * np.max(np.abs(p.z_exact))
        calls.append(jacobian.calls)
    assert max(calls) <= 6 and max(calls) - min(calls) <= 1, calls  # the cold policy iteration: 8 / 13 / 33


def test_impulse_control_steps_with_a_hierarchy_are_those_without():
    # From n = 1,000 inner 'auto' solves with the hierarchy; a step's system took BiCGSTAB with a V-cycle of A,
    # which does not precondition its rows z_i − z_j*(i) (j* far off): 20 Newton steps at n = 1,601, not 6
    p = scenes.impulse_control(1601)
    steps = []
    for hierarchy in (None, "amg"):
        jacobian = impulse_jacobian(p)
        r = nrmicp.solve(p.A, p.q, p.zeta, method="newton", tol=1e-8, hierarchy=hierarchy, zeta_jacobian=jacobian)
        assert r.success, r.message
        assert np.max(np.abs(r.z - p.z_exact)) < 1e-7 * np.max(np.abs(p.z_exact))
        steps.append(jacobian.calls)
    assert steps[1] <= steps[0] + 1, steps


@pytest.mark.parametrize("form", ["sparse", "operator"])
def test_sin_zeta_takes_as_many_newton_steps_at_every_n(form):
    steps = []
    for m in (31, 63, 127):
        p, zeta, jacobians = sin_problem(m)
        calls = []
        r = nrmicp.solve(p.A, p.q, zeta, method="newton", tol=1e-8, hierarchy=p.prolongations(),
                         zeta_jacobian=lambda z: calls.append(1) or jacobians[form](z))
        assert r.success, r.message
        assert np.max(np.abs(np.minimum(p.A @ r.z + p.q, r.z - zeta(r.z)))) < 1e-8
        steps.append(len(calls))
    assert max(steps) <= 3 and max(steps) - min(steps) <= 1, steps


def test_diagonal_sparse_jacobian_steps_solve_the_obstacle_system_and_agree_with_the_operator_form():
    # A diagonal ζ′ fixes the active rows of a step alone: the step is the obstacle problem's, on its
    # symmetric system (CG on the hierarchy). On the union pattern's nonsymmetric system its BiCGSTAB
    # took 1,026 iterations at n = 16,129 (2 Newton steps), its V-cycle rebuilt every step.
    p, zeta, jacobians = sin_problem(127)
    runs = {form: nrmicp.solve(p.A, p.q, zeta, method="newton", tol=1e-10, hierarchy=p.prolongations(),
                               zeta_jacobian=jacobians[form]) for form in jacobians}
    for r in runs.values():
        assert r.success, r.message
    r = runs["sparse"]
    assert r.inner_iterations <= 5 * r.linear_solves, (r.inner_iterations, r.linear_solves)
    assert np.max(np.abs(r.z - runs["operator"].z)) < 1e-10


def test_diagonal_jacobian_with_unit_entries_keeps_the_union_pattern_step():
    # d_i = 1 makes an active row of the step 0 = c_i: no bound to move, the general system's case
    p, zeta, _ = sin_problem(31)
    calls = []

    def jacobian(z):
        calls.append(1)
        d = 0.2 * np.cos(z)
        d[0] = 1.0
        return sp.diags(d, format="csr")

    r = nrmicp.solve(p.A, p.q, zeta, method="newton", tol=1e-8, hierarchy=p.prolongations(), zeta_jacobian=jacobian)
    assert np.isfinite(r.z).all()
    assert r.success == (np.linalg.norm(np.minimum(p.A @ r.z + p.q, r.z - zeta(r.z))) < 1e-8)
