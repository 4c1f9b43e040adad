"""The hierarchy= option's Python side: AMG prolongations from pyamg and checked
user-supplied (geometric) prolongations. Fast: matrices of at most a few thousand rows."""
import sys

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
from nrmicp._hierarchy import amg_prolongations, resolve_hierarchy  # noqa: E402
from reference_impl import residual as reference_residual


def laplacian_2d(m):
    t = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m))
    eye = sp.identity(m)
    return sp.csr_matrix(sp.kron(eye, t) + sp.kron(t, eye))


def upwind_convection_diffusion(m, eps=0.01, b=(1.0, 0.5)):
    """−εΔu + b·∇u, first-order upwind (b > 0): a nonsymmetric M-matrix."""
    h = 1.0 / (m + 1)
    e = np.ones(m)
    d2 = sp.diags([-e[1:], 2 * e, -e[1:]], [-1, 0, 1]) / h**2
    d1 = sp.diags([-e[1:], e], [-1, 0]) / h
    eye = sp.identity(m)
    return sp.csr_matrix(eps * (sp.kron(eye, d2) + sp.kron(d2, eye))
                         + b[0] * sp.kron(eye, d1) + b[1] * sp.kron(d1, eye))


def assert_chain(Ps, n):
    rows = n
    for P in Ps:
        assert isinstance(P, sp.csr_matrix) and P.dtype == np.float64
        assert P.has_sorted_indices
        assert P.shape[0] == rows and P.shape[1] < rows
        assert np.all(np.isfinite(P.data))
        rows = P.shape[1]
    return rows


@pytest.mark.parametrize("build", [lambda: laplacian_2d(32), lambda: upwind_convection_diffusion(32)],
                         ids=["laplacian", "upwind_convection_diffusion"])
def test_amg_prolongations_form_a_shape_chain_down_to_a_small_coarsest_level(build):
    A = build()
    Ps = amg_prolongations(A)
    assert len(Ps) >= 2
    coarsest = assert_chain(Ps, A.shape[0])
    assert coarsest <= 10


def test_amg_prolongations_of_an_m_matrix_are_nonnegative_on_the_first_levels():
    Ps = amg_prolongations(laplacian_2d(32))
    assert Ps[0].data.min() >= 0 and Ps[1].data.min() >= 0


def test_amg_galerkin_coarse_operator_of_spd_matrix_is_spd():
    A = laplacian_2d(16)
    P = amg_prolongations(A)[0]
    Ac = (P.T @ A @ P).toarray()
    assert np.allclose(Ac, Ac.T)
    assert np.linalg.eigvalsh(Ac).min() > 0


def test_amg_prolongations_interpolate_constants_in_the_interior():
    # classical interpolation reproduces constants at points whose strong neighbours all
    # lie inside the domain: rows of P sum to 1 away from the boundary
    m = 32
    A = laplacian_2d(m)
    P = amg_prolongations(A)[0]
    sums = np.asarray(P.sum(axis=1)).ravel()
    i, j = np.divmod(np.arange(m * m), m)
    interior = (i > 1) & (i < m - 2) & (j > 1) & (j < m - 2)
    assert np.allclose(sums[interior], 1.0)


def test_amg_prolongations_of_a_tiny_matrix_are_empty():
    assert amg_prolongations(laplacian_2d(3)) == []   # n = 9 <= max_coarse


def test_amg_prolongations_pass_options_to_pyamg():
    A = laplacian_2d(32)
    assert len(amg_prolongations(A, max_levels=2)) == 1


def test_amg_prolongations_reject_an_unknown_option_by_name():
    with pytest.raises(TypeError, match="strenght"):
        amg_prolongations(laplacian_2d(8), strenght=0.5)


@pytest.mark.parametrize("size", [1e16, 1e-16, 3.0, 2.0 ** 60])
def test_the_amg_set_up_does_not_depend_on_the_size_of_As_entries(size, capfd):
    """Found by review: on 1e16 · A pyamg's kernels printed "Inner denominator was zero." 7,472 times (m = 45)
    into the user's output. The set-up runs on σA (σ a power of two: exact), so A's size changes no level."""
    A = laplacian_2d(45)
    capfd.readouterr()
    base, scaled = nrmicp.Hierarchy.amg(A), nrmicp.Hierarchy.amg(size * A)
    assert capfd.readouterr().out == ""
    assert len(base.prolongations) == len(scaled.prolongations) > 1
    for P, Q in zip(base.prolongations, scaled.prolongations):   # (bit for bit where size is a power of two)
        assert P.shape == Q.shape and np.array_equal(P.indptr, Q.indptr) and np.array_equal(P.indices, Q.indices)
        np.testing.assert_allclose(Q.data, P.data, rtol=0 if size == 2.0 ** 60 else 1e-13)
    for Ac, Sc in zip(base.operators[1:], scaled.operators[1:]):
        np.testing.assert_allclose(Sc.toarray(), size * Ac.toarray(), rtol=1e-12)


def test_amg_prolongations_do_not_mutate_A():
    A = laplacian_2d(16)
    before = A.copy()
    amg_prolongations(A)
    assert (A != before).nnz == 0


@pytest.mark.parametrize("before", [True, False])
def test_amg_set_up_leaves_numpys_hugepage_setting_as_it_found_it(before, monkeypatch):
    # the set-up switches numpy's madvise(MADV_HUGEPAGE) off for its temporaries: a process-wide
    # setting of the user's, which must come back also when the set-up raises
    try:
        from numpy._core.multiarray import _set_madvise_hugepage
    except ImportError:
        from numpy.core.multiarray import _set_madvise_hugepage
    from nrmicp import _hierarchy

    def flag():
        current = _set_madvise_hugepage(False)
        _set_madvise_hugepage(current)
        return current

    original = _set_madvise_hugepage(before)
    try:
        seen = []
        real = _hierarchy._auxiliary_level
        monkeypatch.setattr(_hierarchy, "_auxiliary_level", lambda *a: seen.append(flag()) or real(*a))
        assert amg_prolongations(laplacian_2d(16))
        assert seen == [False] and flag() is before
        monkeypatch.setattr(_hierarchy, "_auxiliary_level", lambda *a: 1 / 0)
        with pytest.raises(ZeroDivisionError):
            amg_prolongations(laplacian_2d(16))
        assert flag() is before
    finally:
        _set_madvise_hugepage(original)


def test_resolve_none_is_none_and_amg_builds_the_chain():
    A = laplacian_2d(16)
    assert resolve_hierarchy(None, A) is None
    assert_chain(resolve_hierarchy("amg", A), A.shape[0])


def test_resolve_accepts_a_tuple_of_matrices_and_converts_them_to_csr():
    A = laplacian_2d(7)  # n = 49
    P0 = sp.random(49, 9, density=0.3, format="coo", random_state=0)
    P1 = np.ones((9, 1))
    with pytest.warns(sp.SparseEfficiencyWarning):
        out = resolve_hierarchy((P0, P1), A)
    assert_chain(out, 49)
    assert np.allclose(out[0].toarray(), P0.toarray())


def test_resolve_empty_list_means_no_coarse_level():
    assert resolve_hierarchy([], laplacian_2d(4)) == []


@pytest.mark.parametrize("empty_at, count", [(0, 1), (1, 2), (1, 3), (2, 3)])
def test_resolve_drops_levels_from_the_first_empty_one_on_naming_it(empty_at, count):
    """A coarsest level without unknowns (shape (5, 0), as an L-shaped mesh's coarsening left
    it) was refused; it and every level after it are dropped, with a warning naming it."""
    A = laplacian_2d(4)   # n = 16
    sizes = [16, 6, 3][:empty_at + 1] + [0] * (count - empty_at)
    levels = [sp.csr_matrix(np.ones((sizes[l], sizes[l + 1]))) for l in range(count)]
    with pytest.warns(nrmicp.ConversionWarning,
                      match=rf"hierarchy\[{empty_at}\] has shape \({sizes[empty_at]}, 0\).*without unknowns"):
        out = resolve_hierarchy(levels, A)
    assert [P.shape for P in out] == [P.shape for P in levels[:empty_at]]


def test_a_newton_solve_with_an_empty_coarsest_level_uses_the_others():
    from nrmicp import scenes
    p = scenes.obstacle_2d(15, exact=False)   # n = 225, its geometric prolongations 225 -> 49 -> 9 -> 1
    given = p.prolongations()
    Ps = given + [sp.csr_matrix((given[-1].shape[1], 0))]
    with pytest.warns(nrmicp.ConversionWarning, match=rf"hierarchy\[{len(Ps) - 1}\]"):
        solver = nrmicp.Solver(p.A, method="newton", hierarchy=Ps)
    assert solver.levels == len(given) + 1 == 4   # the finest level and the non-empty prolongations
    res = solver.solve(p.q, zeta=p.zeta)
    ref = nrmicp.solve(p.A, p.q, p.zeta, method="newton", hierarchy=given)
    assert res.success and res.nit == ref.nit
    np.testing.assert_array_equal(res.z, ref.z)
    assert reference_residual(p.A, p.q, res.z, p.zeta) < 1e-8


@pytest.mark.parametrize("bad, match", [
    ("geometric", "hierarchy must be 'auto', 'amg'"),
])
def test_resolve_rejects_unknown_strings(bad, match):
    with pytest.raises(ValueError, match=match):
        resolve_hierarchy(bad, laplacian_2d(4))


def test_resolve_rejects_a_bare_matrix_naming_hierarchy():
    with pytest.raises(TypeError, match="hierarchy"):
        resolve_hierarchy(sp.identity(16, format="csr"), laplacian_2d(4))


def test_resolve_rejects_a_first_level_with_the_wrong_row_count():
    with pytest.raises(ValueError, match=r"hierarchy\[0\].*A's size \(16\)"):
        resolve_hierarchy([sp.csr_matrix(np.ones((15, 4)))], laplacian_2d(4))


def test_resolve_rejects_a_broken_shape_chain_naming_the_level():
    P0 = sp.csr_matrix(np.ones((16, 4)))
    P1 = sp.csr_matrix(np.ones((5, 2)))
    with pytest.raises(ValueError, match=r"hierarchy\[1\].*columns of hierarchy\[0\] \(4\)"):
        resolve_hierarchy([P0, P1], laplacian_2d(4))


def test_resolve_rejects_a_transposed_prolongation():
    with pytest.raises(ValueError, match=r"hierarchy\[0\] has shape \(16, 16\).*strictly coarser"):
        resolve_hierarchy([sp.identity(16, format="csr")], laplacian_2d(4))


def test_resolve_rejects_non_finite_entries_naming_the_level():
    P = np.ones((16, 4))
    P[3, 2] = np.nan
    with pytest.raises(ValueError, match=r"hierarchy\[0\] has a non-finite entry"):
        resolve_hierarchy([sp.csr_matrix(P)], laplacian_2d(4))


def test_resolve_rejects_non_matrix_levels_naming_the_level():
    with pytest.raises(TypeError, match=r"hierarchy\[0\]"):
        resolve_hierarchy(["not a matrix"], laplacian_2d(4))


def test_resolve_does_not_mutate_the_callers_matrices():
    P = sp.csr_matrix(np.ones((16, 4)))
    P.data[0] = 2.0
    before = P.copy()
    resolve_hierarchy([P], laplacian_2d(4))
    assert (P != before).nnz == 0


def test_amg_without_pyamg_says_what_to_do(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyamg", None)   # import pyamg now raises ImportError
    with pytest.raises(ImportError, match=r"hierarchy='amg' needs pyamg.*hierarchy=None"):
        resolve_hierarchy("amg", laplacian_2d(8))


def dense_relaxation(B, P, is_c, sweeps, truncate):
    """The Jacobi sweeps of _relax_interpolation on dense arrays: P_F <- -D_F^-1((B_FF - D_FF) P_F + B_FC),
    each row's entries below truncate x its largest dropped and the rest scaled to the row's sum."""
    Bd, P = B.toarray(), P.toarray()
    d = np.diag(Bd)
    off = Bd - np.diag(d)
    f = ~is_c
    for _ in range(sweeps):
        new = -(off[f] @ P) / d[f, None]
        keep = np.abs(new) >= truncate * np.abs(new).max(axis=1, keepdims=True)
        kept = np.where(keep, new, 0.0)
        s = kept.sum(axis=1, keepdims=True)
        P[f] = kept * np.divide(new.sum(axis=1, keepdims=True), s, out=np.ones_like(s), where=s != 0)
    return P


@pytest.mark.parametrize("truncate", [0.0, 0.2, 0.5])
def test_relaxation_matches_a_dense_reference_with_fine_fine_couplings(truncate):
    # an irregular M-matrix (random graph Laplacian plus a diagonal shift): its RS split leaves F-F couplings
    from nrmicp._hierarchy import _relax_interpolation, _rs_interpolation, _rs_split, _strength
    rng = np.random.default_rng(5)
    n = 60
    W = sp.random(n, n, density=0.08, random_state=rng, data_rvs=lambda k: rng.uniform(0.1, 1.0, k))
    W = sp.triu(W + W.T, 1)
    W = W + W.T
    B = sp.csr_matrix(sp.diags(np.asarray(W.sum(axis=1)).ravel() + 0.1) - W)
    B.sort_indices()
    S = _strength(B, 0.25, "min")
    is_c = _rs_split(S)
    assert B[~is_c][:, ~is_c].count_nonzero() > (~is_c).sum()    # the premise: F-F couplings
    P = _rs_interpolation(B, S, is_c, "direct")
    got = _relax_interpolation(B, P, is_c, sweeps=3, truncate=truncate)
    np.testing.assert_allclose(got.toarray(), dense_relaxation(B, P, is_c, 3, truncate), rtol=1e-13, atol=1e-15)
    assert got.has_canonical_format and (got.data != 0).all()
    np.testing.assert_array_equal(got[is_c].toarray(), P[is_c].toarray())   # C rows: the identity, kept


def test_relaxation_with_no_fine_fine_coupling_is_its_first_sweep():
    # a 7-point 3D Laplacian's RS split leaves no F–F coupling: one sweep is the ideal interpolation
    from nrmicp._hierarchy import _relax_interpolation
    from pyamg.classical import split
    from pyamg.classical.interpolate import direct_interpolation
    from pyamg.strength import classical_strength_of_connection
    t = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(9, 9))
    eye = sp.identity(9)
    B = sp.csr_matrix(sp.kron(sp.kron(eye, eye), t) + sp.kron(sp.kron(eye, t), eye) + sp.kron(sp.kron(t, eye), eye))
    C = classical_strength_of_connection(B, theta=0.25, norm="min")
    is_c = split.RS(C).astype(bool)
    assert B[~is_c][:, ~is_c].count_nonzero() == (~is_c).sum()      # the premise: B_FF diagonal
    P = sp.csr_matrix(direct_interpolation(B, C, is_c.astype(np.int32)))
    ideal = np.zeros(P.shape)
    ideal[is_c] = P.toarray()[is_c]
    Bd = B.toarray()
    ideal[~is_c] = -(Bd[~is_c][:, is_c] @ P.toarray()[is_c]) / np.diag(Bd)[~is_c, None]
    got = _relax_interpolation(B, P, is_c, sweeps=3, truncate=0.0).toarray()
    np.testing.assert_allclose(got, ideal, rtol=1e-14, atol=1e-15)


def test_relaxation_refuses_c_flags_that_do_not_match_the_columns_of_p():
    # a C point writes P's column in C order: one flag too many once wrote past the row's accumulator (heap corruption)
    from nrmicp import _core
    B = sp.csr_matrix(sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(4, 4)))
    P = sp.csr_matrix(np.array([[1.0, 0], [0.5, 0.5], [0, 1], [0, 1.0]]))
    def raw(*b):   # a bool array from raw bytes: a byte 2 is a C flag too (it was counted as none)
        return np.frombuffer(bytes(b), dtype=bool)
    for flags in (np.array([1, 0, 1, 1], bool), np.array([1, 0, 0, 0], bool), raw(1, 0, 2, 1)):
        with pytest.raises(ValueError, match="n_coarse"):
            _core.relax_interpolation(B.indptr, B.indices, B.data, flags, P.indptr, P.indices, P.data, 2, 3, 0.2)
    args = (P.indptr, P.indices, P.data, 2, 3, 0.2)
    same = [_core.relax_interpolation(B.indptr, B.indices, B.data, f, *args) for f in (raw(1, 0, 2, 0), raw(1, 0, 1, 0))]
    for a, b in zip(*same):
        np.testing.assert_array_equal(a, b)


def laplacian_3d(m):
    t = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m))
    eye = sp.identity(m)
    return sp.csr_matrix(sp.kron(sp.kron(eye, eye), t) + sp.kron(sp.kron(eye, t), eye) + sp.kron(sp.kron(t, eye), eye))


@pytest.mark.parametrize("build", [lambda: laplacian_2d(40), lambda: upwind_convection_diffusion(40),
                                   lambda: laplacian_3d(16)], ids=["laplacian_2d", "convection", "laplacian_3d"])
def test_amg_levels_coarse_operators_are_the_galerkin_products_of_their_prolongations(build):
    # the core takes these instead of forming P^T A P again: they must be those products (3D: the
    # folded first level, whose operator is pyamg's second)
    from nrmicp._hierarchy import amg_levels
    A = build()
    levels = amg_levels(A)
    assert len(levels) >= 2
    Al = A
    for P, Ac in levels:
        galerkin = (P.T @ Al @ P).toarray()
        np.testing.assert_allclose(Ac.toarray(), galerkin, rtol=0, atol=1e-12 * np.abs(galerkin).max())
        Al = Ac
    assert [P.shape for P in amg_prolongations(A)] == [P.shape for P, _ in levels]


def test_newton_with_pyamgs_coarse_operators_agrees_with_the_core_forming_them():
    import nrmicp
    from nrmicp import scenes
    p = scenes.obstacle_2d(63, exact=False)
    given = nrmicp.solve(p.A, p.q, p.zeta, method="newton", hierarchy="amg", tol=1e-10)
    formed = nrmicp.solve(p.A, p.q, p.zeta, method="newton", hierarchy=amg_prolongations(p.A), tol=1e-10)
    assert given.success and formed.success
    assert given.level_steps == formed.level_steps
    np.testing.assert_allclose(given.z, formed.z, rtol=0, atol=1e-10)


def p2_stiffness():
    from nrmicp.scenes.finite_elements import fe_obstacle
    return sp.csr_matrix(fe_obstacle("P2", 2, exact=False).A)


@pytest.mark.parametrize("interpolation", ["classical", "direct"])
@pytest.mark.parametrize("build", [lambda: laplacian_2d(40), lambda: upwind_convection_diffusion(40),
                                   lambda: laplacian_3d(12), p2_stiffness],
                         ids=["laplacian_2d", "convection", "laplacian_3d", "P2"])
def test_ruge_stuben_levels_from_pyamgs_kernels_are_pyamgs_ruge_stuben_solver(build, interpolation):
    # _rs_levels calls pyamg's compiled kernels without its Python-level copies: the same
    # splittings, prolongations and coarse operators as pyamg's own solver (up to rounding)
    import pyamg
    from nrmicp._hierarchy import _rs_levels
    A = build()
    ml = pyamg.ruge_stuben_solver(A, strength=("classical", {"theta": 0.25}), max_coarse=10, max_levels=30,
                                  interpolation=interpolation)
    ours = _rs_levels(A, 0.25, 10, 30, interpolation)
    assert len(ours) == len(ml.levels) - 1
    for (P, Ac), level, coarse in zip(ours, ml.levels, ml.levels[1:]):
        assert P.shape == level.P.shape and Ac.shape == coarse.A.shape
        np.testing.assert_allclose(P.toarray(), level.P.toarray(), rtol=0, atol=1e-13)
        np.testing.assert_allclose(Ac.toarray(), coarse.A.toarray(), rtol=0, atol=1e-13 * abs(coarse.A).max())
