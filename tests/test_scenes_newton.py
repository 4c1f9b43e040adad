"""Scenes for the Newton member and nested iteration: geometric prolongations, the 3D
obstacle, the upwind convection–diffusion obstacle (nonsymmetric M-matrix) and the P-matrix
on which plain active-set Newton cycles. Everything is checked against an independent
computation (numpy/scipy interpolation, closed-form stencils, enumeration, a plain numpy
active-set iteration), on small sizes."""
import itertools

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.interpolate import RegularGridInterpolator

import nrmicp.scenes as scenes
from nrmicp.scenes._operators import grid_prolongations, prolongation_1d  # noqa: E402


def fine_and_coarse_nodes(m):
    h = 1.0 / (m + 1)
    mc = (m - 1) // 2
    return np.arange(1, m + 1) * h, np.arange(1, mc + 1) * 2 * h


# ------------------------------------------------------------------ geometric prolongations

def test_prolongation_1d_is_piecewise_linear_interpolation_with_zero_ends():
    m = 15
    xf, xc = fine_and_coarse_nodes(m)
    uc = np.random.default_rng(0).normal(size=xc.size)
    expected = np.interp(xf, np.r_[0.0, xc, 1.0], np.r_[0.0, uc, 0.0])
    assert np.allclose(prolongation_1d(m) @ uc, expected, atol=1e-14)


@pytest.mark.parametrize("dim", [2, 3])
def test_grid_prolongation_is_multilinear_interpolation_in_lexicographic_order(dim):
    m = 7
    xf, xc = fine_and_coarse_nodes(m)
    mc = xc.size
    uc = np.random.default_rng(dim).normal(size=mc**dim)
    # independent: scipy's multilinear interpolation on the coarse grid padded with the
    # Dirichlet zeros; unknowns are raveled with x fastest, i.e. C order over (.., y, x)
    padded = np.pad(uc.reshape((mc,) * dim), 1)
    axis = np.r_[0.0, xc, 1.0]
    interp = RegularGridInterpolator((axis,) * dim, padded)
    mesh = np.meshgrid(*((xf,) * dim), indexing="ij")
    expected = interp(np.stack([g.ravel() for g in mesh], axis=-1))
    P0 = grid_prolongations((m,) * dim)[0]
    assert P0.shape == (m**dim, mc**dim)
    assert np.allclose(P0 @ uc, expected, atol=1e-14)


def test_grid_prolongations_halve_every_axis_down_to_one_node():
    Ps = grid_prolongations((15, 15))
    assert [P.shape for P in Ps] == [(225, 49), (49, 9), (9, 1)]
    assert all(isinstance(P, sp.csr_matrix) and P.has_sorted_indices for P in Ps)


def test_grid_prolongations_stop_at_an_even_axis():
    assert [P.shape for P in grid_prolongations((11,))] == [(11, 5), (5, 2)]   # 2 is even
    assert grid_prolongations((16, 16)) == []


def test_galerkin_coarse_operators_of_the_2d_laplacian_stay_m_matrices():
    problem = scenes.obstacle_2d(15, exact=False)
    A = problem.A
    for P in problem.prolongations():
        A = (P.T @ A @ P).tocsr()
        dense = A.toarray()
        off = dense - np.diag(np.diag(dense))
        assert off.max() <= 1e-12 * np.abs(dense).max()
        assert np.allclose(dense, dense.T) and np.linalg.eigvalsh(dense).min() > 0


@pytest.mark.parametrize("build, levels", [
    (lambda: scenes.obstacle_1d(63), 5),
    (lambda: scenes.obstacle_2d(31, exact=False), 4),
    (lambda: scenes.obstacle_3d(7, exact=False), 2),
    (lambda: scenes.thermoforming_1d(31, exact=False), 4),
    (lambda: scenes.thermoforming_2d(15, exact=False), 3),
    (lambda: scenes.convection_diffusion_obstacle(15, exact=False), 3),
    (lambda: scenes.american_put(n_space=64, exact=False), 5),
], ids=["obstacle_1d", "obstacle_2d", "obstacle_3d", "thermoforming_1d", "thermoforming_2d",
        "convection_diffusion", "american_put"])
def test_grid_scenes_offer_a_hierarchy_that_fits_their_matrix(build, levels):
    problem = build()
    Ps = problem.prolongations()
    assert len(Ps) == levels and Ps[0].shape[0] == problem.n
    for fine, coarse in zip(Ps, Ps[1:]):
        assert fine.shape[1] == coarse.shape[0]


@pytest.mark.parametrize("build", [lambda: scenes.obstacle_2d(16, exact=False),
                                   lambda: scenes.impulse_control(33, exact=False),
                                   lambda: scenes.bai(8), lambda: scenes.p_matrix_cycling(2)],
                         ids=["even_grid", "impulse_control", "bai", "p_matrix"])
def test_scenes_without_a_geometric_hierarchy_return_none(build):
    assert build().prolongations() is None


# ------------------------------------------------------------------ obstacle_3d

def test_obstacle_3d_matrix_is_the_7_point_laplacian():
    # the 7-point stencil differentiates a product of quadratics exactly
    m = 6
    problem = scenes.obstacle_3d(m, exact=False)
    X, Y, Z = problem.reference["x"], problem.reference["y"], problem.reference["z"]
    f = lambda t: t * (1 - t)  # noqa: E731
    u = f(X) * f(Y) * f(Z)
    minus_laplacian = 2 * (f(Y) * f(Z) + f(X) * f(Z) + f(X) * f(Y))
    assert np.allclose(problem.A @ u, minus_laplacian, rtol=1e-10, atol=1e-10)
    assert problem.A.shape == (m**3, m**3) and problem.A.nnz == 7 * m**3 - 6 * m**2
    assert problem.grid == (m, m, m)


def test_obstacle_3d_exact_solution_touches_the_obstacle_and_is_complementary():
    problem = scenes.obstacle_3d(9)
    z = problem.z_exact
    w, g = problem.parts(z)
    scale = np.abs(problem.A).max() * np.abs(z).max()
    assert w.min() >= -1e-12 * scale and g.min() >= -1e-12 * scale
    assert np.abs(np.minimum(w, g)).max() <= 1e-12 * scale
    contact = g <= 1e-12
    assert 0 < contact.sum() < problem.n
    centre = np.argmin(np.abs(problem.reference["x"] - 0.5) + np.abs(problem.reference["y"] - 0.5)
                       + np.abs(problem.reference["z"] - 0.5))
    assert contact[centre]


# ------------------------------------------------------------------ convection–diffusion

def test_convection_diffusion_matrix_is_a_nonsymmetric_m_matrix():
    problem = scenes.convection_diffusion_obstacle(8, eps=0.01, exact=False)
    A = problem.A.toarray()
    off = A - np.diag(np.diag(A))
    assert off.max() <= 0.0
    assert np.abs(A - A.T).max() > 0.1 * np.abs(A).max()
    assert A.sum(axis=1).min() >= -1e-9 * np.abs(A).max()           # row sums >= 0
    assert np.linalg.inv(A).min() >= -1e-14                           # inverse-nonnegative


def test_convection_diffusion_upwind_operator_is_first_order_consistent():
    # ‖A u − (−εΔu + b·∇u)‖∞ on u = x(1−x)y(1−y): the upwind term is O(h)
    eps, b = 0.1, (1.0, -0.5)

    def error(m):
        p = scenes.convection_diffusion_obstacle(m, eps=eps, b=b, exact=False)
        X, Y = p.reference["x"], p.reference["y"]
        fx, fy = X * (1 - X), Y * (1 - Y)
        exact = eps * 2 * (fx + fy) + b[0] * (1 - 2 * X) * fy + b[1] * (1 - 2 * Y) * fx
        return np.abs(p.A @ (fx * fy) - exact).max()

    e1, e2 = error(15), error(31)
    assert 1.7 < e1 / e2 < 2.3


def test_convection_diffusion_exact_solution_is_complementary_and_differs_from_diffusion():
    problem = scenes.convection_diffusion_obstacle(20, eps=0.01)
    z = problem.z_exact
    w, g = problem.parts(z)
    scale = np.abs(problem.A).max() * np.abs(z).max()
    assert np.abs(np.minimum(w, g)).max() <= 1e-12 * scale
    assert w.min() >= -1e-12 * scale and g.min() >= -1e-12 * scale
    # the flow moves the solution: not the symmetric (pure-diffusion) one
    sym = scenes.obstacle_2d(20)
    assert np.abs(z - sym.z_exact).max() > 1e-3


# ------------------------------------------------------------------ the cycling P-matrix

def plain_active_set(M, q, active, maxiter=30):
    """Newton-min / primal–dual active set on LCP(q, M), plain numpy. Returns the list of
    active sets visited and whether it reached a solution."""
    seen = []
    for _ in range(maxiter):
        seen.append(tuple(active))
        z = np.zeros(len(q))
        inactive = ~active
        if inactive.any():
            z[inactive] = np.linalg.solve(M[np.ix_(inactive, inactive)], -q[inactive])
        w = M @ z + q
        if np.abs(np.minimum(w, z)).max() <= 1e-12:
            return seen, True
        active = z < w
        if tuple(active) in seen:
            return seen, False
    return seen, False


def test_p_matrix_block_is_p_but_neither_m_nor_h_plus():
    M = scenes.p_matrix_cycling(1).A.toarray()
    for r in range(1, 5):
        for S in itertools.combinations(range(4), r):
            assert np.linalg.det(M[np.ix_(S, S)]) > 0
    assert (M - np.diag(np.diag(M))).max() > 0                  # positive off-diagonals
    comparison = -np.abs(M) + 2 * np.diag(np.abs(np.diag(M)))
    assert np.linalg.inv(comparison).min() < 0                  # not an H+-matrix


def test_p_matrix_scene_exact_solution_is_the_unique_complementary_point():
    problem = scenes.p_matrix_cycling(3)
    M, n = problem.A.toarray(), problem.n
    solutions = []
    for b in range(3):   # enumerate all 16 complementary pieces of each 4 × 4 block
        blk = slice(4 * b, 4 * b + 4)
        Mb, qb = M[blk, blk], problem.q[blk]
        for pattern in itertools.product([False, True], repeat=4):
            free = ~np.array(pattern)
            z = np.zeros(4)
            z[free] = np.linalg.solve(Mb[np.ix_(free, free)], -qb[free])
            if z.min() >= -1e-12 and (Mb @ z + qb).min() >= -1e-12:
                solutions.append((b, z))
    assert [b for b, _ in solutions] == [0, 1, 2]
    assert np.allclose(np.concatenate([z for _, z in solutions]), problem.z_exact)
    assert problem.z_exact.shape == (n,)


def test_plain_active_set_newton_cycles_on_the_p_matrix_from_a_cold_start():
    problem = scenes.p_matrix_cycling(2)
    M, q = problem.A.toarray(), problem.q
    seen, solved = plain_active_set(M, q, active=(0.0 < q))       # z = 0: w = q
    assert not solved and len(seen) >= 3
    seen, solved = plain_active_set(M, q, active=np.ones(problem.n, dtype=bool))
    assert not solved


def test_stationary_nrm_member_solves_the_cycling_p_matrix():
    import nrmicp
    problem = scenes.p_matrix_cycling(4)
    result = nrmicp.solve(problem.A, problem.q, method="nrmgs", tol=1e-12)
    assert result.success
    assert np.allclose(result.z, problem.z_exact, atol=1e-10)


# ------------------------------------------------------------------ method="newton" on these scenes

def newton(problem, **kw):
    import nrmicp
    if "newton" not in nrmicp.METHODS:
        pytest.skip("this build has no method='newton'")
    return nrmicp.solve(problem.A, problem.q, problem.zeta, method="newton", tol=1e-10, **kw)


def test_newton_gets_the_exact_solution_of_the_cycling_p_matrix():
    # the plain iteration cycles (above); Newton's projected sweeps after each step break the
    # cycle, and its fallback (tests/test_newton.py) is there if they do not
    problem = scenes.p_matrix_cycling(8)
    result = newton(problem, hierarchy=None)
    assert result.success
    assert np.abs(result.z - problem.z_exact).max() <= 1e-10


@pytest.mark.parametrize("build", [lambda: scenes.convection_diffusion_obstacle(31),
                                   lambda: scenes.obstacle_3d(11)],
                         ids=["convection_diffusion", "obstacle_3d"])
@pytest.mark.parametrize("hierarchy", [None, "amg", "geometric"])
def test_newton_reproduces_the_policy_iteration_solution(build, hierarchy):
    problem = build()
    h = problem.prolongations() if hierarchy == "geometric" else hierarchy
    result = newton(problem, hierarchy=h)
    assert result.success
    assert np.abs(result.z - problem.z_exact).max() <= 1e-10 * max(1.0, np.abs(problem.z_exact).max())


def test_nested_newton_on_the_nonsymmetric_m_matrix_needs_few_finest_steps():
    # measured: cold 23 steps at m = 63, nested (RS-AMG) 3
    problem = scenes.convection_diffusion_obstacle(63, exact=False)
    nested, cold = newton(problem, hierarchy="amg"), newton(problem, hierarchy=None)
    assert nested.success and cold.success
    assert nested.nit <= 5 < cold.nit
