"""The nested start of a QVI's first obstacle solve (detail::NestedStart::refreshed, issue 37): coarse
to fine, each level on the bounds ζ(z_f) at the finest prolongation z_f of the coarser answer, so the
finest solve starts near ζ(z*)'s free boundary, not ζ(0)'s. Checked against numpy: the scene's exact
QVI solution (a plain fixed point of exact obstacle solves, scenes/_exact.py), min(Az + q, z − ζ(z))
computed here, and the count of ζ's calls the rule implies (one a level)."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import nrmicp
from nrmicp import scenes
from reference_impl import reference_box_solve

KAPPA, DELTA = 0.25, 1.0  # a long-range coupling whose ζ is a contraction (Lipschitz 0.81): z_exact exists


def thermoforming(m=31):
    """thermoforming_2d(m) with ζ recording its arguments, ζ' = κ (I + δA)⁻¹ diag(s'(z)) (the scene's
    s(u) = 1 / (1 + ((u − Φ₀)/ℓ)²)), and the scene's geometric hierarchy."""
    p = scenes.thermoforming_2d(m, kappa=KAPPA, delta=DELTA, exact=True)
    phi0, ell = p.reference["phi0"], p.reference["ell"]
    lu = spla.splu(sp.csc_matrix(sp.identity(p.n) + DELTA * p.A))
    seen = []

    def zeta(z):
        seen.append(np.array(z))
        return np.array(p.zeta(z))

    def jacobian(z):
        u = (z - phi0) / ell
        ds = KAPPA * -2.0 * u / ell / (1.0 + u * u) ** 2
        return spla.LinearOperator((p.n, p.n), matvec=lambda v: lu.solve(ds * v.ravel()), dtype=float)

    return p, zeta, jacobian, seen


def complementarity(A, q, zeta, z):
    """‖min(Az + q, z − ζ(z))‖∞, in numpy."""
    return float(np.max(np.abs(np.minimum(A @ z + q, z - zeta(z)))))


def solve(p, zeta, jacobian, hierarchy, seen):
    """The Newton member's solve, and the count of ζ's calls at each of the callback's calls, in order."""
    at = []

    def callback(intermediate_result):
        at.append(len(seen))

    extra = {"zeta_jacobian": jacobian} if jacobian else {}
    r = nrmicp.solve(p.A, p.q, zeta, method="newton", tol=1e-11, hierarchy=hierarchy, callback=callback, **extra)
    return r, at


@pytest.mark.parametrize("with_jacobian", [False, True])
def test_nested_qvi_answer_is_the_exact_one_and_the_cold_solves(with_jacobian):
    p, zeta, jacobian, seen = thermoforming()
    jac = jacobian if with_jacobian else None
    nested, _ = solve(p, zeta, jac, p.prolongations(), seen)
    cold, _ = solve(p, zeta, jac, None, seen)
    assert nested.success and cold.success, (nested.message, cold.message)
    scale = np.max(np.abs(p.z_exact))
    assert np.max(np.abs(nested.z - p.z_exact)) < 1e-10 * scale
    assert np.max(np.abs(nested.z - cold.z)) < 1e-10 * scale
    assert complementarity(p.A, p.q, p.zeta, nested.z) < 1e-8  # (A ~ 1/h²: w's rounding ~1e-12 × 4e3)
    assert np.all(nested.z - p.zeta(nested.z) >= -1e-12)


def test_outer_fixed_point_takes_zeta_once_a_level_before_its_first_outer_step():
    p, zeta, _, seen = thermoforming()
    r, at = solve(p, zeta, None, p.prolongations(), seen)
    levels = len(r.level_steps)
    assert levels >= 3 and r.success, (levels, r.message)
    # iterate 0: ζ(0); iterate 1 = G(z_f): ζ at the finest prolongation of each coarse level's answer
    # (levels − 1 of them, the last z_f), then at G(z_f) itself
    assert at[0] == 1 and at[1] == levels + 1, (at, levels)
    starts = seen[1:levels]
    for a, b in zip(seen[:levels - 1], starts):
        assert np.max(np.abs(a - b)) > 0  # each level's bounds taken at a new z
    # the first outer step's answer S(ζ(z_f)) (ζ's next argument) is far nearer z* than S(ζ(0)), the frozen
    # start's (numpy: 7e-5 against 1e-2)
    frozen = reference_box_solve(p.A, p.q, lower=p.zeta(np.zeros(p.n))).z
    assert np.max(np.abs(seen[levels] - p.z_exact)) < 0.05 * np.max(np.abs(frozen - p.z_exact))


def test_without_a_hierarchy_nothing_is_nested_and_zeta_is_taken_once_a_step():
    p, zeta, _, seen = thermoforming()
    r, at = solve(p, zeta, None, None, seen)
    assert r.success and len(r.level_steps) == 1
    assert at[:2] == [1, 2], at


def test_semismooth_start_takes_zeta_once_a_level():
    p, zeta, jacobian, seen = thermoforming()
    r, at = solve(p, zeta, jacobian, p.prolongations(), seen)
    levels = len(r.level_steps)
    assert r.success and levels >= 3
    # ζ(0), ζ at levels − 1 prolongations, then the Newton loop's own at its start (the outer step's answer)
    assert at[0] == levels + 1, (at, levels)
    seen.clear()
    cold, at_cold = solve(p, zeta, jacobian, None, seen)
    assert at_cold[0] == 2, at_cold  # ζ(0), then the Newton loop's at its start


def test_a_constant_callable_zeta_with_a_hierarchy_solves_as_the_constant_obstacle():
    p = scenes.thermoforming_2d(31, exact=False)
    psi = p.zeta(np.zeros(p.n)).copy()
    calls = []
    r = nrmicp.solve(p.A, p.q, lambda z: calls.append(1) or psi, method="newton", tol=1e-11,
                     hierarchy=p.prolongations())
    c = nrmicp.solve(p.A, p.q, psi, method="newton", tol=1e-11, hierarchy=p.prolongations())
    assert r.success and c.success
    assert np.max(np.abs(r.z - c.z)) < 1e-12 * np.max(np.abs(c.z))
    assert np.all(c.z >= psi) and c.timings["zeta"] == 0.0  # a vector ψ: ζ is never evaluated
    # the finest solve's iterates are the constant obstacle's: the same finest steps and coarse levels
    assert r.level_steps[1:] == c.level_steps[1:], (r.level_steps, c.level_steps)


@pytest.mark.parametrize("with_jacobian", [False, True])
def test_a_given_start_with_a_hierarchy_is_used_not_replaced_by_the_nested_start(with_jacobian):
    # x0 close to z* (a loose solve): the first outer step starts from it, so fewer ζ calls than a cold nested solve
    p, zeta, jacobian, seen = thermoforming()
    extra = {"zeta_jacobian": jacobian} if with_jacobian else {}
    loose = nrmicp.solve(p.A, p.q, p.zeta, method="newton", tol=1e-5, **extra)
    options = dict(method="newton", tol=1e-11, hierarchy=p.prolongations(), **extra)
    seen.clear()
    cold = nrmicp.solve(p.A, p.q, zeta, **options)
    cold_calls = len(seen)
    seen.clear()
    warm = nrmicp.solve(p.A, p.q, zeta, x0=loose.z, **options)
    assert cold.status == warm.status == nrmicp.Status.CONVERGED
    assert complementarity(p.A, p.q, p.zeta, warm.z) < 1e-9
    assert np.array_equal(seen[0], loose.z)   # ζ's first call is at the given start
    assert len(seen) < cold_calls
