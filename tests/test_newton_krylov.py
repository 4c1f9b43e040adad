"""method="newton", inner="cg" on a nonsymmetric reduced system K (a nonsymmetric A, or an
affine ζ whose active rows are I − B): BiCGSTAB preconditioned by the multigrid V-cycle.
Checked against the scene's exact discrete solution (policy iteration), a plain scipy
active-set loop written here, and the direct inner solve."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import nrmicp
from nrmicp import scenes


def active_set_reference(A, q, B, c, maxit=100):
    """min(Az + q, z − Bz − c) = 0 by a plain semismooth Newton loop with scipy's spsolve."""
    A = sp.csr_matrix(A)
    n = A.shape[0]
    G = sp.identity(n, format="csr") - B
    z = np.asarray(c, dtype=float).copy()
    last = None
    for _ in range(maxit):
        w, g = A @ z + q, G @ z - c
        inactive = g > w  # the w-row is the smaller one: w = 0 there
        if last is not None and np.array_equal(inactive, last):
            return z
        last = inactive
        D = sp.diags(inactive.astype(float))
        K = (D @ A + (sp.identity(n) - D) @ G).tocsc()
        z = spla.spsolve(K, np.where(inactive, -q, c))
    raise AssertionError("the reference active-set loop did not settle")


def check_complementarity(A, q, z, g, tol):
    w = A @ z + q
    assert w.min() > -tol and g.min() > -tol
    assert np.abs(np.minimum(w, g)).max() < tol


@pytest.mark.parametrize("m", [31, 47])
def test_bicgstab_inner_solve_on_the_convection_scene_agrees_with_the_exact_and_direct_solutions(m):
    pb = scenes.convection_diffusion_obstacle(m, exact=True)
    rk = nrmicp.solve(pb.A, pb.q, zeta=pb.zeta, method="newton", inner="cg", hierarchy="amg", tol=1e-10)
    rd = nrmicp.solve(pb.A, pb.q, zeta=pb.zeta, method="newton", inner="umfpack", hierarchy="amg", tol=1e-10)
    assert rk.inner == "bicgstab" and rd.inner == "umfpack"
    assert rk.success and rk.residual < 1e-10
    assert rk.inner_iterations > 0 and rd.inner_iterations == 0
    np.testing.assert_allclose(rk.z, pb.z_exact, rtol=0, atol=1e-9)
    np.testing.assert_allclose(rk.z, rd.z, rtol=0, atol=1e-9)
    check_complementarity(pb.A, pb.q, rk.z, rk.z - pb.zeta, 1e-9)


def test_bicgstab_inner_solve_for_an_affine_zeta_agrees_with_a_scipy_active_set_loop():
    pb = scenes.convection_diffusion_obstacle(31, exact=False)
    n = pb.A.shape[0]
    B = sp.csr_matrix(0.2 * sp.diags(np.ones(n - 1), 1) + 0.1 * sp.diags(np.ones(n - 31), -31))
    c = np.asarray(pb.zeta)
    z_ref = active_set_reference(pb.A, pb.q, B, c)
    zeta = nrmicp.Affine(B, c)
    rk = nrmicp.solve(pb.A, pb.q, zeta=zeta, method="newton", inner="cg", hierarchy="amg", tol=1e-10)
    rd = nrmicp.solve(pb.A, pb.q, zeta=zeta, method="newton", inner="umfpack", hierarchy="amg", tol=1e-10)
    assert rk.success and rk.residual < 1e-10
    assert rk.inner_iterations > 0
    np.testing.assert_allclose(rk.z, z_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(rk.z, rd.z, rtol=0, atol=1e-9)
    check_complementarity(pb.A, pb.q, rk.z, rk.z - (B @ rk.z + c), 1e-9)


def test_auto_takes_bicgstab_for_the_nonsymmetric_scene_from_the_threshold_on():
    small = scenes.convection_diffusion_obstacle(31, exact=False)
    large = scenes.convection_diffusion_obstacle(101, exact=False)  # n = 10,201
    rs = nrmicp.solve(small.A, small.q, zeta=small.zeta, method="newton", hierarchy="amg", tol=1e-8)
    rl = nrmicp.solve(large.A, large.q, zeta=large.zeta, method="newton", hierarchy="amg", tol=1e-8)
    assert rs.inner == "umfpack" or rs.inner == "eigen_lu"
    assert rl.inner == "bicgstab" and rl.success
