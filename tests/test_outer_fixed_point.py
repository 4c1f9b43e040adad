"""method='newton' on a callable ζ without zeta_jacobian: the outer fixed point z ↦ S(ζ(z)),
Anderson-accelerated with inexact inner solves (detail::OuterFixedPoint; docs/SPEC.md, the Newton
member). Checked against numpy: the exact discrete QVI solution of the scene (a plain fixed point
of exact obstacle solves, scenes/_exact.py) and min(Az + q, z − ζ(z)) computed here."""
import numpy as np
import pytest

import nrmicp
from nrmicp import scenes


def complementarity(A, q, zeta, z):
    """‖min(Az + q, z − ζ(z))‖∞, in numpy."""
    return float(np.max(np.abs(np.minimum(A @ z + q, z - zeta(z)))))


def test_outer_steps_do_not_grow_with_the_mesh_on_thermoforming_1d():
    steps = []
    for n in (63, 255):
        p = scenes.thermoforming_1d(n, exact=False)
        r = nrmicp.solve(p.A, p.q, p.zeta, method="newton", tol=1e-8)
        assert r.success, r.message
        steps.append(r.outer_iterations)
    assert steps[1] <= steps[0] + 1, steps
    assert max(steps) <= 10, steps


@pytest.mark.parametrize("n", [63, 127])
def test_accelerated_answer_is_the_plain_fixed_points_and_complementary(n):
    p = scenes.thermoforming_1d(n)  # z_exact: the plain fixed point of exact obstacle solves, in numpy
    r = nrmicp.solve(p.A, p.q, p.zeta, method="newton", tol=1e-10)
    assert r.success, r.message
    assert np.max(np.abs(r.z - p.z_exact)) < 1e-8
    assert complementarity(p.A, p.q, p.zeta, r.z) < 1e-9


def test_strong_coupling_needs_few_outer_steps_and_is_complementary():
    # κ = 2, δ = 1: the plain outer fixed point took 16-17 outer steps here (docs/MEASUREMENTS.md)
    p = scenes.thermoforming_2d(31, kappa=2.0, delta=1.0, exact=False)
    r = nrmicp.solve(p.A, p.q, p.zeta, method="newton", tol=1e-8, hierarchy=p.prolongations())
    assert r.success, r.message
    assert r.outer_iterations <= 10
    assert complementarity(p.A, p.q, p.zeta, r.z) < 1e-8


def test_unsolvable_zeta_is_not_reported_as_a_success():
    # z >= z + 1 has no solution: |min(w_i, -1)| >= 1 for every z
    p = scenes.thermoforming_1d(31, exact=False)
    r = nrmicp.solve(p.A, p.q, lambda z: z + 1.0, method="newton", tol=1e-8, maxiter=200)
    assert not r.success
    assert r.status != nrmicp.Status.CONVERGED and r.residual >= 1.0
    assert np.isfinite(r.z).all()


def test_expanding_zeta_ends_honestly():
    # ζ(z) = Φ₀ + 3 sin(z): not a contraction; whatever the verdict, it must be the truth
    p = scenes.thermoforming_1d(63, exact=False)
    phi0 = p.reference["phi0"]
    zeta = lambda z: phi0 + 3.0 * np.sin(z)  # noqa: E731
    r = nrmicp.solve(p.A, p.q, zeta, method="newton", tol=1e-8, maxiter=300)
    err = float(np.linalg.norm(np.minimum(p.A @ r.z + p.q, r.z - zeta(r.z))))
    assert err == pytest.approx(r.residual, rel=1e-6, abs=1e-12)
    assert r.success == (err < 1e-8)


@pytest.mark.parametrize("n", [255, 511])
def test_a_change_of_units_of_a_and_q_changes_no_decision_under_the_default_rule(n):
    # A, q multiplied by s leave z and the outer map z -> S(zeta(z)) unchanged. Before, the outer
    # steps were judged by Res, which weighs w (A's units) against z - zeta(z): at n = 511 every good
    # outer step on sigma*A looked worse than z = 0 and the solve ended MAX_ITERATIONS 6e-3 off
    p = scenes.thermoforming_1d(n, exact=False)
    runs = [nrmicp.solve(s * p.A, s * p.q, p.zeta, method="newton") for s in (1e-4, 1.0, 1e4)]
    ref = runs[1].z
    for r in runs:
        assert r.status == nrmicp.Status.CONVERGED, r.message
        assert r.fallback_sweeps == 0  # the outer steps contract: no sweeps of the fallback member
        assert np.max(np.abs(r.z - ref)) <= 1e-8 * np.max(np.abs(ref))
        assert abs(r.outer_iterations - runs[1].outer_iterations) <= 1, [x.outer_iterations for x in runs]


def test_default_rule_solves_thermoforming_511_to_the_plain_fixed_point_of_exact_obstacle_solves():
    p = scenes.thermoforming_1d(511)  # z_exact: numpy's fixed point of exact obstacle solves (scenes/_exact.py)
    r = nrmicp.solve(p.A, p.q, p.zeta)
    assert r.success and r.method == "newton", r.message
    assert np.max(np.abs(r.z - p.z_exact)) <= 1e-10 * np.max(np.abs(p.z_exact))
    assert complementarity(p.A, p.q, p.zeta, r.z) < 1e-6  # (A ~ 1/h²: w's rounding alone is ~1e-9)
    assert r.outer_iterations <= 10
