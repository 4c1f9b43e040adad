"""The ``components=`` option: the 'amg' hierarchy of a vector problem built by component (the
unknown-based classical AMG for systems). Checked against what it promises: the option validated
with errors naming it; 1 (or one label) exactly the scalar hierarchy; each prolongation ≥ 0 and
block-diagonal by component; on elastic contact fewer finest Newton steps and CG iterations than the
scalar 'amg', with an answer that meets the box conditions and agrees with a plain scipy active-set
reference (tests/test_scenes_bounds.py's). Small sizes (n <= 4,160)."""
import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
import nrmicp.scenes as scenes
from nrmicp._hierarchy import amg_levels
from test_scenes_bounds import mcp_violation, reference_box   # tests/: plain numpy/scipy, no nrmicp


@pytest.fixture(scope="module")
def contact_p2():
    return scenes.elastic_contact("P2", 3, exact=False)   # n = 1,056, interleaved (u_x, u_y)


@pytest.mark.parametrize("components, error, words", [
    (0, ValueError, "components=0"), (5, ValueError, "divide n = 1056"), (-2, ValueError, "components=-2"),
    (np.zeros(10, dtype=int), ValueError, "shape (1056,)"), (np.zeros((528, 2), dtype=int), ValueError, "shape (1056,)"),
    (np.zeros(1056), TypeError, "dtype float64"), (True, TypeError, "dtype bool"), ("xy", TypeError, "components must be"),
])
def test_components_are_validated_with_an_error_naming_them(contact_p2, components, error, words):
    for call in (lambda: nrmicp.solve(contact_p2.A, contact_p2.q, zeta=contact_p2.zeta, components=components),
                 lambda: nrmicp.Solver(contact_p2.A, method="nrmgs", components=components)):
        with pytest.raises(error, match="components") as info:
            call()
        assert words in str(info.value)


@pytest.mark.parametrize("scene", ["laplacian", "contact_p2"])
def test_one_component_is_exactly_the_scalar_hierarchy(scene, contact_p2):
    A = scenes.obstacle_2d(31, exact=False).A if scene == "laplacian" else contact_p2.A
    plain = amg_levels(A)
    for components in (1, np.full(A.shape[0], 7)):
        same = amg_levels(A, components)
        assert len(same) == len(plain) > 2
        for (P, Ac), (P1, Ac1) in zip(plain, same):
            for M, M1 in ((P, P1), (Ac, Ac1)):
                assert np.array_equal(M.indptr, M1.indptr) and np.array_equal(M.indices, M1.indices)
                assert np.array_equal(M.data, M1.data)


def test_default_solve_and_components_1_give_identical_answers(contact_p2):
    p = contact_p2
    a = nrmicp.solve(p.A, p.q, zeta=p.zeta, hierarchy="amg")
    b = nrmicp.solve(p.A, p.q, zeta=p.zeta, hierarchy="amg", components=1)
    assert np.array_equal(a.z, b.z) and list(a.level_steps) == list(b.level_steps)
    assert a.inner_iterations == b.inner_iterations


@pytest.mark.parametrize("components", [2, "labels"])
def test_prolongations_by_component_are_nonnegative_and_block_diagonal(contact_p2, components):
    labels = contact_p2.reference["component"]
    levels = amg_levels(contact_p2.A, labels if components == "labels" else components)
    assert len(levels) >= 3
    for P, _ in levels:
        assert P.data.min() >= 0
        C = sp.csc_matrix(P)
        coarse = np.empty(P.shape[1], dtype=int)
        for j in range(P.shape[1]):   # every column interpolates one component only
            rows = labels[C.indices[C.indptr[j]:C.indptr[j + 1]]]
            assert rows.size and np.all(rows == rows[0]), j
            coarse[j] = rows[0]
        assert set(coarse) == {0, 1}   # both components on every coarse level
        labels = coarse


@pytest.mark.parametrize("element, r", [("P2", 3), ("P1", 5)])   # n = 1,056; 4,160
def test_components_take_fewer_steps_on_elastic_contact_and_meet_the_box_conditions(element, r):
    p = scenes.elastic_contact(element, r, exact=False)
    assert p.solver_options == {"components": 2}   # the scene says what its unknowns are
    plain = nrmicp.solve(p.A, p.q, zeta=p.zeta, hierarchy="amg", tol=1e-12)
    ours = p.solve(hierarchy="amg", tol=1e-12)
    assert ours.success and plain.success
    assert ours.level_steps[0] < plain.level_steps[0]
    assert ours.inner_iterations < plain.inner_iterations / 2
    lower = np.asarray(p.zeta, float)
    assert np.all(ours.z >= lower - 1e-14)   # within the bound (-inf on the free rows)
    assert mcp_violation(p, ours.z) < 1e-9     # w >= 0 at the floor, w = 0 on the free and gap rows
    ref = reference_box(p.A, p.q, lower, None)
    assert np.abs(ours.z - ref).max() < 1e-9 * np.abs(ref).max()


def test_identity_rows_keep_their_labels_out_of_the_coupled_rows(contact_p2):
    # Dirichlet rows kept as identity rows (FEniCS' DirichletBC.apply): the coupled rows' hierarchy
    # takes their labels; the identity rows break the interleaving, so the labels are an array
    p = contact_p2
    n, k = p.n, 3
    rng = np.random.default_rng(0)
    B = sp.random(n, k, density=0.01, random_state=rng, format="csr")
    A = sp.csr_matrix(sp.bmat([[p.A, -B], [None, sp.identity(k)]]))
    A.sort_indices()
    zD = np.array([0.01, -0.02, 0.005])
    q = np.concatenate([p.q, -zD])
    lower = np.concatenate([np.asarray(p.zeta, float), np.full(k, -np.inf)])
    labels = np.concatenate([p.reference["component"], [0, 1, 0]])
    res = nrmicp.solve(A, q, zeta=lower, hierarchy="amg", components=labels, tol=1e-12)
    scalar = nrmicp.solve(A, q, zeta=lower, hierarchy="amg", tol=1e-12)
    direct = nrmicp.solve(p.A, p.q - B @ zD, zeta=p.zeta, hierarchy="amg", components=2, tol=1e-12)
    assert res.success and res.hierarchy == direct.hierarchy and res.level_steps[0] == direct.level_steps[0]
    assert res.inner_iterations < scalar.inner_iterations / 2   # the labels reached the coupled rows' hierarchy
    assert np.allclose(res.z[n:], zD, rtol=0, atol=1e-15)
    ref = reference_box(A, q, lower, None)
    assert np.abs(res.z - ref).max() < 1e-9 * np.abs(ref).max()
