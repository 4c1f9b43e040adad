"""A requested hierarchy is never dropped silently (issues 35, 36): when the amg set-up, the
coupled rows' part or the core gives levels up, a HierarchyWarning at set-up, the reason in the
message of a solve that does not converge, and the result field ``hierarchy``."""
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from nrmicp import scenes
from reference_impl import residual as reference_residual


def laplacian_2d(m):
    t = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m))
    eye = sp.identity(m)
    return sp.csr_matrix(sp.kron(eye, t) + sp.kron(t, eye)) * (m + 1) ** 2


def two_sided_membrane(m):
    """0 <= u <= 0.05 under a load of both signs, as an LCP of size 2n: [[A, I], [-I, 0]] (z = [u; λ],
    λ the upper bound's multiplier), q = [-f; upper]. Its last n rows have a zero diagonal."""
    n = m * m
    x = np.arange(1, m + 1) / (m + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    f = (40.0 * np.sin(2 * np.pi * X) * np.sin(np.pi * Y) + 10.0).ravel()
    I = sp.identity(n, format="csr")
    M = sp.csr_matrix(sp.bmat([[laplacian_2d(m), I], [-I, None]]))
    return M, np.concatenate([-f, np.full(n, 0.05)])


def bilinear_2d(m):
    """Bilinear interpolation from the (m − 1)/2 square grid to the m one."""
    mc = (m - 1) // 2
    p = sp.lil_matrix((m, mc))
    for j in range(mc):
        p[2 * j, j], p[2 * j + 1, j], p[2 * j + 2, j] = 0.5, 1.0, 0.5
    p = sp.csr_matrix(p)
    return sp.csr_matrix(sp.kron(p, p))


def membrane_prolongations(m):
    """Geometric prolongations of the 2n problem, u and λ alike: (2m², 2mc²) block diagonal."""
    Ps = []
    while m >= 7:
        P = bilinear_2d(m)
        Ps.append(sp.csr_matrix(sp.block_diag([P, P])))
        m = (m - 1) // 2
    return Ps


def first_nonpositive(d):
    return int(np.flatnonzero(d <= 0)[0])


def test_amg_given_up_on_the_two_sided_membrane_warns_and_reports_why():
    m = 15
    n = m * m
    M, q = two_sided_membrane(m)
    with pytest.warns(nrmicp.HierarchyWarning, match=r"hierarchy='amg': 2 levels requested, 1 used") as caught:
        s = nrmicp.Solver(M, method="newton", hierarchy="amg")
    assert len([w for w in caught if issubclass(w.category, nrmicp.HierarchyWarning)]) == 1
    # the first λ row: no off-diagonal > 0 to lump, a_ii = 0 (the u rows' diagonals are > 0)
    assert M.diagonal()[:n].min() > 0 and M.diagonal()[n] == 0
    res = s.solve(q)
    assert res.success and s.levels == 1 and len(res.level_steps) == 1
    assert res.hierarchy["requested"] == 2 and res.hierarchy["used"] == 1
    assert f"a_ii = 0 <= 0 at row {n}" in res.hierarchy["reason"]
    assert "auxiliary M-matrix" in res.hierarchy["reason"]
    z, w = res.z, M @ res.z + q
    assert np.linalg.norm(np.minimum(z, w)) < 1e-8


def test_a_users_list_cut_by_the_core_warns_and_reports_the_level_and_row():
    m = 15
    M, q = two_sided_membrane(m)
    Ps = membrane_prolongations(m)
    A1 = (Ps[0].T @ M @ Ps[0]).toarray()   # the Galerkin operator the core forms, in numpy
    row = first_nonpositive(np.diag(A1))
    with pytest.warns(nrmicp.HierarchyWarning, match=rf"{len(Ps)} prolongations\]: {len(Ps) + 1} levels requested, 1 used"):
        s = nrmicp.Solver(M, method="newton", hierarchy=Ps)
    res = s.solve(q)
    assert res.hierarchy == {"requested": len(Ps) + 1, "used": 1, "reason": res.hierarchy["reason"]}
    assert f"level 1 (prolongations[0]) has a_ii = 0 <= 0 at row {row}" in res.hierarchy["reason"]
    assert s.levels == 1 and res.success
    z, w = res.z, M @ res.z + q
    assert np.linalg.norm(np.minimum(z, w)) < 1e-8


def test_the_warning_comes_once_per_set_up_and_the_reason_in_a_failed_solves_message():
    M, q = two_sided_membrane(15)
    Ps = membrane_prolongations(15)
    with pytest.warns(nrmicp.HierarchyWarning):
        s = nrmicp.Solver(M, method="newton", hierarchy=Ps)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        short = s.solve(q, maxiter=1)
        done = s.solve(q)
    assert not short.success
    assert f"the hierarchy: {len(Ps) + 1} levels requested, 1 used, a cold start" in short.message
    assert "row" in short.message
    assert done.success and "hierarchy" not in done.message


def test_a_level_cut_below_the_first_keeps_the_levels_above():
    p = scenes.obstacle_2d(31, exact=False)
    Ps = p.prolongations()                       # 961 -> 225 -> 49 -> 9 -> 1
    P1 = Ps[1].tolil()
    P1[:, 5] = 0.0                               # coarse unknown 5 of level 2 interpolates nothing
    Ps[1] = sp.csr_matrix(P1)
    A2 = (Ps[1].T @ (Ps[0].T @ p.A @ Ps[0]) @ Ps[1]).toarray()
    assert first_nonpositive(np.diag(A2)) == 5
    with pytest.warns(nrmicp.HierarchyWarning, match=f"{len(Ps) + 1} levels requested, 2 used, nested iteration over 2"):
        s = nrmicp.Solver(p.A, method="newton", hierarchy=Ps)
    res = s.solve(p.q, zeta=p.zeta)
    assert s.levels == 2 and len(res.level_steps) == 2
    assert "level 2 (prolongations[1]) has a_ii = 0 <= 0 at row 5" in res.hierarchy["reason"]
    assert res.success and reference_residual(p.A, p.q, res.z, p.zeta) < 1e-8


def test_a_list_merged_on_the_coupled_rows_is_reported():
    # one decoupled row (a lone diagonal): on the 49 coupled rows P_0 (50 x 49) is no coarser, and
    # is merged into P_1
    m = 7
    A = sp.csr_matrix(sp.block_diag([laplacian_2d(m), sp.identity(1)]))
    P0 = sp.csr_matrix(np.vstack([np.eye(m * m), np.zeros((1, m * m))]))
    Ps = [P0, bilinear_2d(m), bilinear_2d(3)]
    q = -np.ones(m * m + 1)
    with pytest.warns(nrmicp.HierarchyWarning, match=r"4 levels requested, 3 used.*hierarchy\[0\] is no coarser") as caught:
        s = nrmicp.Solver(A, method="newton", hierarchy=Ps)
    assert [w.category for w in caught] == [nrmicp.HierarchyWarning]   # no conversion of the merged level
    res = s.solve(q)
    assert s.levels == 3 and res.hierarchy["requested"] == 4 and res.hierarchy["used"] == 3
    assert res.success and reference_residual(A, q, res.z) < 1e-8


def test_a_hierarchy_kept_raises_no_warning_and_says_so():
    p = scenes.obstacle_2d(63, exact=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = nrmicp.Solver(p.A, method="newton", hierarchy="amg")
        res = s.solve(p.q, zeta=p.zeta)
    assert s.levels > 2 and res.success
    assert res.hierarchy == {"requested": s.levels, "used": s.levels, "reason": None}
    assert len(res.level_steps) == s.levels


def test_no_hierarchy_requested_reports_one_level():
    M, q = two_sided_membrane(7)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = nrmicp.solve(M, q, method="newton", hierarchy=None)
    assert res.hierarchy == {"requested": 1, "used": 1, "reason": None}
