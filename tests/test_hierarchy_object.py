"""nrmicp.Hierarchy: the levels of nested iteration built once (validated, the Galerkin operators
formed, printable) and passed as hierarchy= to any solve on the same A."""
import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from nrmicp import _hierarchy
from nrmicp.scenes import obstacle


@pytest.fixture(scope="module")
def problem():
    pb = obstacle.obstacle_2d(63, exact=False)
    return sp.csr_matrix(pb.A), pb.q, np.asarray(pb.zeta, dtype=float), pb.prolongations()


def test_its_operators_are_the_galerkin_products_of_its_prolongations(problem):
    A, _, _, Ps = problem
    for h in (nrmicp.Hierarchy(A, Ps), nrmicp.Hierarchy.amg(A)):
        assert len(h) == len(h.prolongations) + 1 == len(h.operators) and h.operators[0] is A
        for P, R, fine, coarse in zip(h.prolongations, h.restrictions, h.operators, h.operators[1:]):
            assert abs(R - P.T).max() == 0
            expected = (P.T @ fine @ P).toarray()     # scipy's own product, dense
            assert np.allclose(coarse.toarray(), expected, rtol=1e-14, atol=1e-14 * abs(expected).max())
        assert h.complexity == pytest.approx(sum(M.nnz for M in h.operators[1:]) / A.nnz)
    assert [P.shape for P in nrmicp.Hierarchy.amg(A).prolongations] == \
        [P.shape for P in _hierarchy.amg_prolongations(A)]


def test_it_prints_each_levels_rows_and_nonzeros(problem):
    A, _, _, Ps = problem
    h = nrmicp.Hierarchy(A, Ps)
    text = str(h)
    assert repr(h) in text and f"{len(h)} levels" in repr(h)
    for M in h.operators:
        assert f"{M.shape[0]:,}" in text and f"{M.nnz:,}" in text


@pytest.mark.parametrize("kind", ["geometric", "amg"])
def test_a_solve_given_it_takes_the_decisions_of_the_same_levels_and_builds_nothing(problem, kind, monkeypatch):
    A, q, psi, Ps = problem
    h = nrmicp.Hierarchy(A, Ps) if kind == "geometric" else nrmicp.Hierarchy.amg(A)
    same = nrmicp.solve(A, q, psi, method="newton", hierarchy=list(h.prolongations) if kind == "geometric" else "amg",
                        tol=1e-9)

    def no_setup(*args, **kwargs):
        raise AssertionError("the amg set-up ran although a Hierarchy was given")
    monkeypatch.setattr(_hierarchy, "_levels", no_setup)
    for method in ("newton", "auto"):   # ('auto' takes newton for a Hierarchy, as for a list)
        r = nrmicp.solve(A, q, psi, method=method, hierarchy=h, tol=1e-9)
        assert r.method == "newton" and r.status == same.status and r.level_steps == same.level_steps
        assert np.max(np.abs(r.z - same.z)) <= 1e-12 * np.max(np.abs(same.z))
        assert r.hierarchy["used"] == r.hierarchy["requested"] == len(h)
    # the complementarity conditions themselves, in numpy
    w = A @ r.z + q
    assert np.max(np.abs(np.minimum(w, r.z - psi))) < 1e-8


def test_it_serves_every_default_rule_and_an_a_with_decoupled_rows(problem):
    A, q, psi, Ps = problem
    h = nrmicp.Hierarchy(A, Ps)
    r = nrmicp.solve(A, q, psi, hierarchy=h)   # the default (units) rule
    assert r.success and r.level_steps == nrmicp.solve(A, q, psi, hierarchy=list(Ps)).level_steps
    # one row a lone diagonal: the coupled rows' part of its prolongations (as for a list)
    B = sp.lil_matrix(A)
    B[0, :] = 0.0
    B[:, 0] = 0.0
    B[0, 0] = 4.0
    B = sp.csr_matrix(B)
    hb = nrmicp.Hierarchy(B, Ps)
    got = nrmicp.solve(B, q, psi, method="newton", hierarchy=hb, tol=1e-9)
    ref = nrmicp.solve(B, q, psi, method="newton", hierarchy=list(Ps), tol=1e-9)
    assert got.status == ref.status and np.array_equal(got.z, ref.z)


def test_nothing_the_user_passed_is_mutated(problem):
    A, q, psi, Ps = problem
    before = [M.copy() for M in [A, *Ps]]
    h = nrmicp.Hierarchy(A, Ps)
    nrmicp.solve(A, q, psi, hierarchy=h, method="newton")
    for M, M0 in zip([A, *Ps], before):
        assert (M != M0).nnz == 0


def test_bad_input_names_the_argument(problem):
    A, q, psi, Ps = problem
    h = nrmicp.Hierarchy(A, Ps)
    with pytest.raises(ValueError, match="hierarchy was built on another matrix"):
        nrmicp.solve(2.0 * A, q, psi, hierarchy=h)
    with pytest.raises(ValueError, match="hierarchy is the nested iteration of method 'newton'"):
        nrmicp.solve(A, q, psi, hierarchy=h, method="nrmgs")
    with pytest.raises(ValueError, match=r"hierarchy\[0\]"):
        nrmicp.Hierarchy(A, [sp.eye(A.shape[0] + 1, 3, format="csr")])
    with pytest.raises(TypeError, match="prolongations must be a list"):
        nrmicp.Hierarchy(A, Ps[0])
    with pytest.raises(TypeError, match=r"Hierarchy\.amg\(A\) builds"):   # (the option's string is not a list)
        nrmicp.Hierarchy(A, "amg")
    with pytest.raises(ValueError, match="A must be square"):
        nrmicp.Hierarchy(sp.csr_matrix(np.ones((3, 2))), [])


def test_an_a_changed_in_place_is_refused_and_another_index_dtype_is_not(problem):
    A, q, psi, Ps = problem
    B = A.copy()
    h = nrmicp.Hierarchy(B, Ps)
    wide = sp.csr_matrix((B.data, B.indices.astype(np.int64), B.indptr.astype(np.int64)), shape=B.shape)
    r = nrmicp.solve(wide, q, psi, hierarchy=h, method="newton", tol=1e-9)   # the same matrix, int64 indices
    assert r.hierarchy["used"] == len(h)
    B.data *= 3.0   # its coarse operators are now stale
    with pytest.raises(ValueError, match="or on A before it changed"):
        nrmicp.solve(B, q, psi, hierarchy=h)


def test_a_coarse_operator_the_nest_cannot_use_is_said_when_it_is_built():
    # P1 elements with their rows scaled apart (D A): the amg levels' PᵀAP loses its positive diagonal
    # ('amg' equilibrates the rows first; a Hierarchy is built on A as given, so it warns at once)
    from nrmicp.scenes.finite_elements import fe_obstacle
    pb = fe_obstacle("P1", 3, exact=False)
    d = 10.0 ** np.random.default_rng(0).uniform(-1, 1, pb.A.shape[0])
    A = sp.csr_matrix(sp.diags(d) @ pb.A)
    A.sort_indices()
    with pytest.warns(nrmicp.HierarchyWarning, match=r"coarse operator 1 has a_ii = .* <= 0 .* will end at level 0"):
        h = nrmicp.Hierarchy.amg(A)
    with pytest.warns(nrmicp.HierarchyWarning, match="1 used, a cold start"):   # and the solve says it again
        r = nrmicp.solve(A, d * pb.q, pb.zeta, method="newton", hierarchy=h)
    assert r.success and r.hierarchy["used"] == 1
    assert repr(nrmicp.Hierarchy(A, [])).startswith("Hierarchy(1 level,")
