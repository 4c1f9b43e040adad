"""hierarchy="amg" on stencils whose first Ruge–Stüben coarse operator is denser than A (the 3D
7-point Laplacian): that level is folded into the next, P_0 P_1 (nonnegative), so the first
coarse level is both smaller and sparser than A; 2D 5-point grids keep every level. Nested
Newton on either stays flat and agrees with the geometric path."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from nrmicp import scenes
from nrmicp._hierarchy import amg_prolongations

import pyamg  # noqa: F401  (required: a missing one fails, not skips)


def rs_first_level(A):
    """pyamg's own first Ruge–Stüben level (θ = 0.25): P_0 and P_0ᵀ A P_0."""
    ml = pyamg.ruge_stuben_solver(sp.csr_matrix(A), max_levels=2, max_coarse=10)
    P0 = ml.levels[0].P
    return P0, P0.T @ A @ P0


@pytest.mark.parametrize("m", [15, 31])
def test_a_denser_first_level_is_folded_into_the_next(m):
    A = scenes.obstacle_3d(m, exact=False).A
    P0, A1 = rs_first_level(A)
    assert A1.nnz > A.nnz                         # the premise: RS's first level is denser than A
    P = amg_prolongations(A)[0]
    assert P.shape[0] == A.shape[0] and P.shape[1] < P0.shape[1]   # coarser than RS's first level
    assert P.data.min() >= 0                      # a product of nonnegative prolongations
    assert (P.T @ A @ P).nnz < A.nnz              # the first coarse level is now sparser than A


def test_a_2d_five_point_hierarchy_keeps_its_first_level():
    A = scenes.obstacle_2d(63, exact=False).A
    P0, A1 = rs_first_level(A)
    assert A1.nnz <= A.nnz
    assert amg_prolongations(A)[0].shape == P0.shape


@pytest.mark.parametrize("m", [15, 31])
def test_folded_amg_nests_in_few_steps_and_agrees_with_the_geometric_path(m):
    P = scenes.obstacle_3d(m, exact=False)
    amg = nrmicp.solve(P.A, P.q, P.zeta, method="newton", hierarchy="amg", tol=1e-10)
    geo = nrmicp.solve(P.A, P.q, P.zeta, method="newton", hierarchy=P.prolongations(), tol=1e-10)
    assert amg.success and geo.success
    assert np.abs(amg.z - geo.z).max() < 1e-10
    # exact inner solves: the finest steps count the sets the nesting left to find
    exact = nrmicp.solve(P.A, P.q, P.zeta, method="newton", hierarchy="amg", tol=1e-10, inner="cholmod")
    assert exact.level_steps[0] <= 4
