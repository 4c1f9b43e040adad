"""Finite-element matrices users bring (issue 17): the scikit-fem P1/P2/P3 obstacle scenes, the
numpy-only unstructured P1 scene, and the algebraic hierarchy on them. Properties, not timings:
finest-level Newton steps flat under refinement with hierarchy="amg", agreement with the
independent policy-iteration solution, complementarity. Small sizes (n <= 32,513)."""
import os
import sys

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp
import pyamg  # noqa: F401  (required: a missing one fails, not skips)
from nrmicp._hierarchy import amg_prolongations, auxiliary_m_matrix  # noqa: E402
from nrmicp.scenes.unstructured import contact_disk_p1  # noqa: E402

sys.path.append(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks"))
import other_matrices  # noqa: E402  (the matrices no scene was tuned on; scikit-fem is a test dependency)

TOL = 1e-9


def fe(element, r, exact=None):
    import skfem  # noqa: F401  (a test dependency: make deps installs it; missing fails, not skips)
    from nrmicp.scenes.finite_elements import fe_obstacle
    return fe_obstacle(element, r, exact=exact)


def assert_complementary(problem, z, tol=1e-8):
    w, g = problem.parts(z)
    scale = np.abs(problem.q).max() + np.abs(problem.A @ z).max()
    assert w.min() >= -tol * scale and g.min() >= -tol
    assert np.abs(np.minimum(w, g)).max() <= tol * scale


# ---------------------------------------------------------------- finest steps flat (amg)

# Exact inner solves: the finest steps then count the active sets the nesting left to find (the
# default CG solves a step on a new set loosely and the set that repeats once more, exactly).
EXACT = {"method": "newton", "hierarchy": "amg", "tol": TOL, "inner": "cholmod"}


@pytest.mark.parametrize("element, sizes", [("P1", (2, 3)), ("P2", (1, 2))])
def test_amg_finest_steps_stay_flat_under_refinement_on_finite_elements(element, sizes):
    # before the auxiliary-matrix hierarchy: P2 took 36 finest steps at r = 2 (n = 8,065)
    steps = [fe(element, r, exact=False).solve(**EXACT).level_steps[0] for r in sizes]
    assert max(steps) <= 5 and steps[1] <= steps[0] + 1, steps


def test_p3_steps_are_not_spent_peeling_an_overshoot():
    # P3 (no M-matrix): from the nested start's too small contact set the full step sank below the
    # obstacle far beyond the true contact set, and the next steps peeled the excess: 13 and 22
    # finest steps at r = 1, 2 (41 at r = 3) before such a step was damped (Globalized::overshoots)
    steps = [fe("P3", r, exact=False).solve(**EXACT).level_steps[0] for r in (1, 2)]
    assert max(steps) <= 8, steps


def test_amg_finest_steps_stay_flat_on_the_unstructured_disk():
    steps = [contact_disk_p1(n, exact=False).solve(**EXACT).level_steps[0] for n in (2_000, 8_000)]
    assert max(steps) <= 5 and steps[1] <= steps[0] + 1, steps


@pytest.mark.parametrize("build", [lambda: fe("P2", 2, exact=False), lambda: contact_disk_p1(8_000, exact=False)],
                         ids=["P2", "disk"])
def test_loose_steps_with_cg_reach_tol_and_the_exact_answer(build):
    # the loose steps on guessed sets cost steps, not accuracy (P2 n = 8,065: 8 against 4 exact)
    problem = build()
    exact = problem.solve(**EXACT)
    loose = problem.solve(**{**EXACT, "inner": "cg"})
    assert exact.success and loose.success and loose.residual < TOL
    assert loose.level_steps[0] <= 2 * exact.level_steps[0] + 2, (loose.level_steps, exact.level_steps)
    assert np.abs(loose.z - exact.z).max() <= 1e-8 * max(1.0, np.abs(exact.z).max())


def test_a_coarse_level_does_not_settle_on_a_set_its_loose_step_could_not_show():
    # The start's Res is the coefficient jump's, not the contact's: a coarse step solved to 0.1 Res
    # left z above the obstacle, its empty contact set "repeated", every coarse level settled with no
    # contact, and the finest level found the contact alone: 9 finest steps at n = 32,513 (13 at
    # 130,561, 20 at 523,265) with the default inner CG (NewtonTuning::coarse_repeat_trust).
    p = other_matrices.build("materials", 4)   # benchmarks/other_matrices.py's two materials, n = 32,513
    A, q, psi = p.A, p.q, p.zeta
    res = nrmicp.solve(A, q, zeta=psi, method="newton", hierarchy="amg", tol=TOL)
    assert res.success and res.residual < TOL
    assert res.inner == "cg" and res.level_steps[0] <= 5, res.level_steps
    assert max(res.level_steps[1:3]) >= 2, res.level_steps   # the contact is found on the coarse levels
    w = A @ res.z + q
    assert (res.z - psi).min() >= 0 and w.min() >= -1e-9 and np.abs(np.minimum(w, res.z - psi)).max() <= 1e-9
    assert 0 < np.count_nonzero(res.z - psi <= 1e-12) < 0.01 * A.shape[0]


# ---------------------------------------------------------------- agreement with the reference

@pytest.mark.parametrize("element, r", [("P1", 2), ("P2", 1), ("P3", 1)])
@pytest.mark.parametrize("hierarchy", ["amg", "fe"])
def test_newton_agrees_with_policy_iteration_on_finite_elements(element, r, hierarchy):
    problem = fe(element, r, exact=True)
    h = problem.prolongations() if hierarchy == "fe" else "amg"
    res = problem.solve(method="newton", hierarchy=h, tol=1e-11)
    assert res.success
    assert np.abs(res.z - problem.z_exact).max() <= 1e-10 * max(1.0, np.abs(problem.z_exact).max())
    assert_complementary(problem, res.z)


def test_newton_agrees_with_policy_iteration_on_the_unstructured_disk():
    problem = contact_disk_p1(3_000)
    res = problem.solve(method="newton", hierarchy="amg", tol=1e-11)
    assert res.success
    assert np.abs(res.z - problem.z_exact).max() <= 1e-10
    assert_complementary(problem, res.z)


def test_p2_obstacle_has_contact_and_a_free_region():
    problem = fe("P2", 1, exact=True)
    contact = np.isclose(problem.z_exact, problem.zeta, atol=1e-12)
    assert 0.02 * problem.n < contact.sum() < 0.5 * problem.n


# ---------------------------------------------------------------- the scenes' matrices

def test_p2_stiffness_is_spd_but_no_m_matrix():
    A = fe("P2", 0, exact=False).A
    off = A - sp.diags(A.diagonal())
    assert (off.data > 1e-12).sum() > 0                    # positive off-diagonals
    assert abs(A - A.T).max() <= 1e-12 * abs(A).max()
    assert np.linalg.eigvalsh(A.toarray()).min() > 0


def test_fe_interpolation_is_the_coarse_p2_function_at_the_fine_nodes():
    import skfem  # noqa: F401  (a test dependency: make deps installs it; missing fails, not skips)
    from nrmicp.scenes import finite_elements as fem
    P = fem.fe_interpolation("P2", 1)[0]
    fine, coarse = fem._basis("P2", 1), fem._basis("P2", 0)
    xf = fine.doflocs[:, fem._interior(fine)]
    f = lambda xy: 1.0 - xy[0] ** 2 - 0.5 * xy[1] ** 2 + 0.3 * xy[0] * xy[1]  # noqa: E731
    # with the coarse boundary values, a quadratic is reproduced exactly (P2 spaces are nested) ...
    full = coarse.probes(xf).tocsr()
    assert np.allclose(full @ f(coarse.doflocs), f(xf), atol=1e-12)
    # ... and the hierarchy's P is that interpolation on the interior (Dirichlet) unknowns
    assert abs(P - full[:, fem._interior(coarse)]).max() <= 1e-12
    assert P.data.min() < 0                                 # P2's own interpolation has −1/8 weights


def test_unstructured_scene_is_symmetric_with_zero_row_sums_inside():
    problem = contact_disk_p1(1_000, exact=False)
    A = problem.A
    assert abs(A - A.T).max() <= 1e-12 * abs(A).max()
    assert problem.grid is None and problem.prolongations() is None


def test_fe_scene_names_scikit_fem_when_it_is_missing(monkeypatch):
    from nrmicp.scenes import finite_elements as fem
    monkeypatch.setitem(sys.modules, "skfem", None)
    with pytest.raises(ImportError, match="scikit-fem"):
        fem.fe_obstacle("P1", 0)


@pytest.mark.parametrize("bad", [dict(element="P4"), dict(refinements=-1), dict(refinements=2.0)])
def test_fe_scene_rejects_bad_arguments_by_name(bad):
    from nrmicp.scenes import finite_elements as fem
    args = {"element": "P1", "refinements": 0, **bad}
    with pytest.raises(ValueError, match=next(iter(bad))):
        fem.fe_obstacle(**args)


# ---------------------------------------------------------------- the hierarchy on P2

def test_auxiliary_matrix_lumps_positive_couplings_and_keeps_row_sums():
    A = fe("P2", 0, exact=False).A
    B = auxiliary_m_matrix(A)
    off = B - sp.diags(B.diagonal())
    assert off.data.max() <= 0
    assert np.allclose(np.asarray(B.sum(axis=1)).ravel(), np.asarray(A.sum(axis=1)).ravel())
    assert (A != A.copy()).nnz == 0


def test_amg_prolongations_of_p2_are_nonnegative_and_exact_for_constants_inside():
    A = fe("P2", 1, exact=False).A
    Ps = amg_prolongations(A)
    assert all(P.data.min() >= 0 for P in Ps)
    # rows more than 5 couplings away from a boundary row (nonzero row sum) interpolate constants
    # exactly (direct interpolation: 1 coupling, 3 sweeps, 1 to spare)
    near = (np.abs(np.asarray(A.sum(axis=1)).ravel()) > 1e-10).astype(float)
    graph = (abs(A) > 0).astype(float)
    for _ in range(5):
        near = graph @ near
    inside = near == 0
    assert inside.sum() > 0.2 * A.shape[0]
    sums = np.asarray(Ps[0].sum(axis=1)).ravel()
    assert np.allclose(sums[inside], 1.0)


def test_scikit_fem_example_runs_and_both_hierarchies_agree():
    # the README points scikit-fem users to this example: it must run as shipped
    import os
    import re
    import subprocess
    path = os.path.join(os.path.dirname(__file__), "..", "examples", "scikit_fem_hierarchy.py")
    out = subprocess.run([sys.executable, path], capture_output=True, text=True, timeout=600,
                         env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    assert out.returncode == 0, out.stderr
    solves = re.findall(r"(mesh hierarchy|algebraic \(amg\)) +n = (\d+): (.*?); finest-level steps (\d+),.* Res (\S+)", out.stdout)
    contacts = [int(c) for c in re.findall(r"contact at (\d+) nodes", out.stdout)]
    assert [s[0] for s in solves] == ["mesh hierarchy", "algebraic (amg)"], out.stdout
    for name, n, message, steps, res in solves:
        assert message.startswith("converged") and float(res) < 1e-9, (name, message, res)
        assert int(steps) <= 6, (name, steps)
    assert len(contacts) == 2 and contacts[0] == contacts[1] > 0, out.stdout


# ---------------------------------------------------------------- Dirichlet rows kept as identity rows

def p1_with_identity_rows(r, diagonal=1.0):
    """benchmarks/other_matrices.py's "dirrows": the P1 membrane with every degree of freedom kept
    and the boundary rows replaced by `diagonal` e_i, their columns kept (A nonsymmetric), as
    FEniCS' DirichletBC.apply / PETSc's MatZeroRows leave them; q = 0 there."""
    p = other_matrices.build("dirrows", r)
    lone = np.diff(p.A.indptr) == 1
    scale = np.where(lone, diagonal, 1.0)
    A = p.A.copy()
    A.data *= np.repeat(scale, np.diff(A.indptr))   # rows scaled in place: A stays canonical
    return A, scale * p.q, p.zeta


def test_identity_dirichlet_rows_keep_the_finest_steps_flat_and_cg():
    # On the whole nonsymmetric A the algebraic hierarchy mixed the fixed unknowns into the coarse
    # problems: 8 and 12 finest steps at n = 8,321 / 33,025 (17 at 131,585), BiCGSTAB; the rows
    # are now solved in closed form and Newton runs on the symmetric A_FF (nrmicp/_decoupled.py).
    runs = [nrmicp.solve(*p1_with_identity_rows(r), method="newton", tol=TOL) for r in (3, 4)]
    steps = [res.level_steps[0] for res in runs]
    assert all(res.success and res.inner == "cg" for res in runs)
    assert max(steps) <= 5 and steps[1] <= steps[0] + 1, steps


@pytest.mark.parametrize("diagonal", [1.0, 37.5])
def test_identity_dirichlet_rows_agree_with_policy_iteration_on_the_whole_matrix(diagonal):
    from nrmicp.scenes._exact import solve_exact_obstacle
    A, q, psi = p1_with_identity_rows(3, diagonal)
    q = q.copy()
    q[np.flatnonzero(np.diff(A.indptr) == 1)[::2]] = -0.05 * diagonal  # z_i = 0.05 there: a Dirichlet value
    seen = []
    res = nrmicp.solve(A, q, zeta=psi, method="newton", tol=1e-11, x0=np.zeros(A.shape[0]),
                       callback=lambda zk: seen.append(zk.size))
    z_exact = solve_exact_obstacle(A, q, psi)
    assert res.success and res.residual < 1e-11
    assert np.abs(res.z - z_exact).max() <= 1e-10 * max(1.0, np.abs(z_exact).max())
    w = A @ res.z + q
    assert np.allclose(res.w, w, atol=1e-12) and (res.z - psi).min() >= 0 and w.min() >= -1e-11
    assert seen and set(seen) == {A.shape[0]}   # the callback sees the whole iterate


def test_decoupled_rows_with_a_coupling_zeta_solve_the_whole_problem():
    # an affine ζ couples a lone-diagonal row to the others: no closed form, the whole A is solved
    A, q, psi = p1_with_identity_rows(2)
    B = sp.csr_matrix(0.1 * sp.eye(A.shape[0], k=1))
    zeta = nrmicp.Affine(B, psi)
    res = nrmicp.solve(A, q, zeta=zeta, method="newton", tol=1e-10)
    ref = nrmicp.solve(A, q, zeta=zeta, method="nrmgs", accelerate="anderson", tol=1e-12, maxiter=100_000)
    assert res.success and ref.success
    assert np.abs(res.z - ref.z).max() <= 1e-8 * max(1.0, np.abs(ref.z).max())
    w, g = A @ res.z + q, res.z - zeta(res.z)
    assert np.linalg.norm(np.minimum(w, g)) < 1e-10


def test_a_hierarchy_over_every_node_is_restricted_to_the_coupled_rows():
    # 5-point grid with its boundary nodes kept as identity rows and bilinear prolongations over
    # all nodes (boundary included): P_0 loses the boundary rows, the coarse levels stay
    def bilinear_1d(N):   # N = 2^k + 1 nodes -> (N + 1) / 2
        Nc = (N + 1) // 2
        rows = np.r_[2 * np.arange(Nc), 2 * np.arange(Nc - 1) + 1, 2 * np.arange(Nc - 1) + 1]
        cols = np.r_[np.arange(Nc), np.arange(Nc - 1), np.arange(1, Nc)]
        vals = np.r_[np.ones(Nc), np.full(2 * (Nc - 1), 0.5)]
        return sp.csr_matrix((vals, (rows, cols)), shape=(N, Nc))
    N = 65
    T = sp.diags_array([-1.0, 2.0, -1.0], offsets=[-1, 0, 1], shape=(N, N))
    K = sp.csr_matrix(sp.kron(T, sp.identity(N)) + sp.kron(sp.identity(N), T))
    X, Y = (g.ravel() for g in np.meshgrid(np.linspace(0, 1, N), np.linspace(0, 1, N), indexing="ij"))
    boundary = (X == 0) | (X == 1) | (Y == 0) | (Y == 1)
    A = sp.csr_matrix(sp.diags_array((~boundary).astype(float)) @ K + sp.diags_array(boundary.astype(float)))
    A.eliminate_zeros()
    A.sort_indices()
    q = np.where(boundary, 0.0, 8.0 / (N - 1) ** 2)
    psi = np.where(boundary, -1.0, 0.1 - (X - 0.55) ** 2 - (Y - 0.45) ** 2)
    Ps, n = [], N
    while n > 5:
        P = bilinear_1d(n)
        Ps.append(sp.csr_matrix(sp.kron(P, P)))
        n = (n + 1) // 2
    from nrmicp.scenes._exact import solve_exact_obstacle
    res = nrmicp.solve(A, q, zeta=psi, method="newton", hierarchy=Ps, tol=1e-11)
    assert res.success and res.inner == "cg" and res.level_steps[0] <= 4, res.level_steps
    assert len(res.level_steps) == len(Ps) + 1
    assert np.abs(res.z - solve_exact_obstacle(A, q, psi)).max() <= 1e-10
    w = A @ res.z + q
    assert (res.z - psi).min() >= 0 and w.min() >= -1e-11 and np.abs(np.minimum(w, res.z - psi)).max() <= 1e-11


def _chain_with_identity_rows(n, lone):
    A = sp.lil_matrix(sp.diags_array([-1.0, 2.0, -1.0], offsets=[-1, 0, 1], shape=(n, n)))
    for i in lone:
        A.rows[i], A.data[i] = [i], [1.0]
    return sp.csr_matrix(A)


@pytest.mark.filterwarnings("ignore::nrmicp.HierarchyWarning")   # n = 8: its last level, 1 x 1 on the coupled rows, goes
def test_every_level_of_a_hierarchy_list_keeps_only_what_interpolates_coupled_rows():
    # aggregation prolongations whose coarse unknowns at several levels only interpolate identity
    # rows: each level is restricted (a level no coarser than the one above merged into the next),
    # none is rejected with the reduced shapes, none cut off by a zero Galerkin diagonal
    def aggregate(nf, nc):
        return sp.csr_matrix((np.ones(nf), (np.arange(nf), np.arange(nf) * nc // nf)), shape=(nf, nc))
    from nrmicp.scenes._exact import solve_exact_obstacle
    for n, lone, sizes in ((8, range(6), (4, 2)), (16, range(6), (8, 4, 2)), (64, range(0, 64, 3), (32, 16, 8, 4))):
        A, q = _chain_with_identity_rows(n, lone), -np.ones(n)
        Ps = [aggregate(nf, nc) for nf, nc in zip((n,) + sizes, sizes)]
        s = nrmicp.Solver(A, method="newton", hierarchy=Ps)
        res = s.solve(q, np.full(n, -0.5))
        assert res.success and len(res.level_steps) == s.levels >= 2, (n, res.level_steps, s.levels)
        assert res.hierarchy["requested"] == len(Ps) + 1 and res.hierarchy["used"] == s.levels
        assert (res.hierarchy["reason"] is None) == (s.levels == len(Ps) + 1)
        assert np.abs(res.z - solve_exact_obstacle(A, q, np.full(n, -0.5))).max() <= 1e-10


def test_the_status_is_decided_on_the_whole_problems_res():
    # large data on the identity rows: the coupled rows' Res and the whole problem's differ by
    # rounding, and the status follows the returned Res (rule 4 of docs/SPEC.md)
    m, n = 10, 100
    T = sp.diags_array([-1.0, 2.0, -1.0], offsets=[-1, 0, 1], shape=(m, m))
    K = sp.csr_matrix(sp.kron(T, sp.identity(m)) + sp.kron(sp.identity(m), T))
    rng = np.random.default_rng(0)
    lone = rng.uniform(size=n) < 0.3
    A = sp.csr_matrix(sp.diags_array((~lone).astype(float)) @ K + sp.diags_array(3.0 * lone))
    A.eliminate_zeros()
    A.sort_indices()
    q = rng.uniform(-1, 1, n) * 1e7
    q[lone] = -1e8 * rng.uniform(0.5, 1, lone.sum())
    psi = rng.uniform(-0.3, 0.3, n) * 1e7
    for tol in (1e-9, 5.62e-8, 1e-6):
        res = nrmicp.solve(A, q, psi, method="newton", tol=tol)
        w = A @ res.z + q
        assert res.residual == pytest.approx(np.linalg.norm(np.minimum(w, res.z - psi)), rel=1e-12)
        assert res.success == (res.residual < tol) and (res.status == nrmicp.Status.CONVERGED) == res.success


def test_a_damped_step_whose_set_repeats_is_solved_again_not_settled():
    # P2 under an obstacle 10 higher (contact at 1,760 of 130,561 nodes), the FE interpolation as
    # hierarchy: the first finest step overshot and was damped (Globalized::overshoots), the damped
    # z's active set repeated, and the repeat was trusted as a solution: STAGNATED at Res 4.2 ("its
    # rounding floor", 8e-13). A damped z is no set's exact solve; its repeat is solved again.
    problem = fe("P2", 4, exact=False)
    psi = problem.zeta + 10.0
    res = nrmicp.solve(problem.A, problem.q, zeta=psi, method="newton", hierarchy=problem.prolongations(), tol=TOL)
    assert res.success and res.residual < TOL, (res.status, res.residual, res.level_steps)
    w = problem.A @ res.z + problem.q
    g = res.z - psi   # z = ψ + y: rounding of ψ ≈ 10 is 2e-15
    assert g.min() >= -1e-13 and w.min() >= -1e-9 and np.abs(np.minimum(w, g)).max() <= 1e-9
    assert 0 < np.count_nonzero(g <= 1e-12) < 0.05 * problem.n


@pytest.mark.parametrize("element, r", [("P1", 3), ("P2", 2)])
def test_rows_scaled_apart_keep_the_amg_hierarchy(element, r):
    # D·S with d_i in [0.1, 10]: the Galerkin operators PᵀDSP lost their positive diagonal, the core
    # ended the hierarchy there and started cold (P1 n = 130,561: 51 steps, direct solves, 27 s);
    # rows are now equilibrated first (scale='rows') and the hierarchy stays. The LCP's solution
    # does not depend on a positive row scaling: policy iteration on S is the reference.
    from nrmicp.scenes._exact import solve_exact_obstacle
    from nrmicp._newton import amg_levels_or_rows
    problem = fe(element, r, exact=False)
    d = 10.0 ** np.random.default_rng(0).uniform(-1, 1, problem.n)
    A = problem.A.copy()
    A.data *= np.repeat(d, np.diff(A.indptr))
    q = d * problem.q
    assert amg_levels_or_rows(A) is None    # the unscaled hierarchy would lose a diagonal
    s = nrmicp.Solver(A, method="newton")
    res = s.solve(q, problem.zeta, tol=1e-9 * d.min())
    assert s.levels > 2 and res.scaling["kind"] == "rows" and res.success
    z_exact = solve_exact_obstacle(problem.A, problem.q, problem.zeta)
    assert np.abs(res.z - z_exact).max() <= 1e-8 * max(1.0, np.abs(z_exact).max())
