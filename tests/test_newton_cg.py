"""method="newton", inner="cg": the reduced systems solved by CG preconditioned with a multigrid
V-cycle on the nesting's prolongations. Checked against the scenes' exact discrete solutions
(policy iteration, independent of the Newton code) and against the direct inner solve."""
from __future__ import annotations

import numpy as np
import pytest

import nrmicp
from nrmicp import scenes


@pytest.mark.parametrize("scene, m, hierarchy", [
    (scenes.obstacle_2d, 31, "geometric"),
    (scenes.obstacle_2d, 40, "amg"),
    (scenes.obstacle_3d, 15, "amg"),
])
def test_cg_inner_solve_agrees_with_the_exact_solution_and_the_direct_solve(scene, m, hierarchy):
    pb = scene(m, exact=True)
    Ps = pb.prolongations() if hierarchy == "geometric" else "amg"
    assert Ps is not None
    rc = nrmicp.solve(pb.A, pb.q, zeta=pb.zeta, method="newton", inner="cg", hierarchy=Ps, tol=1e-10)
    rd = nrmicp.solve(pb.A, pb.q, zeta=pb.zeta, method="newton", inner="eigen_llt", hierarchy=Ps, tol=1e-10)
    assert rc.inner == "cg"
    assert rd.inner != "cg"
    assert rc.success and rc.residual < 1e-10
    assert rc.nit <= 4
    np.testing.assert_allclose(rc.z, pb.z_exact, rtol=0, atol=1e-10)
    np.testing.assert_allclose(rc.z, rd.z, rtol=0, atol=1e-10)
    w = pb.A @ rc.z + pb.q
    g = rc.z - pb.zeta
    assert w.min() > -1e-9 and g.min() > -1e-12


def test_cg_without_a_hierarchy_uses_the_direct_solve():
    pb = scenes.obstacle_2d(15, exact=True)
    r = nrmicp.solve(pb.A, pb.q, zeta=pb.zeta, method="newton", inner="cg", hierarchy=None, tol=1e-10)
    assert r.inner != "cg" and r.success
    np.testing.assert_allclose(r.z, pb.z_exact, rtol=0, atol=1e-10)


def test_cg_is_refused_for_a_stationary_member_naming_the_option():
    pb = scenes.obstacle_2d(7)
    with pytest.raises(ValueError, match="inner = 'cg'"):
        nrmicp.solve(pb.A, pb.q, zeta=pb.zeta, method="nrm", inner="cg")


@pytest.mark.parametrize("hierarchy", ["geometric", "amg"])
def test_a_solver_solves_again_as_a_fresh_one_after_its_coarse_levels_released_their_systems(hierarchy):
    # each coarse level frees its reduced system once prolongated; the next solve of the same
    # Solver rebuilds it and must give what a fresh Solver gives: the same steps, z to rounding
    # (the finest level's multigrid operators are updated from the previous solve's, not anew)
    pb = scenes.obstacle_2d(63, exact=True)
    Ps = pb.prolongations() if hierarchy == "geometric" else "amg"
    solver = nrmicp.Solver(pb.A, method="newton", hierarchy=Ps, inner="cg")
    for scale in (1.0, 1.5, 1.0):
        q = pb.q * scale
        again = solver.solve(q, pb.zeta, tol=1e-10)
        fresh = nrmicp.Solver(pb.A, method="newton", hierarchy=Ps, inner="cg").solve(q, pb.zeta, tol=1e-10)
        assert again.success and again.level_steps == fresh.level_steps
        assert again.linear_solves == fresh.linear_solves
        np.testing.assert_allclose(again.z, fresh.z, rtol=0, atol=1e-14)
    np.testing.assert_allclose(again.z, pb.z_exact, rtol=0, atol=1e-10)
