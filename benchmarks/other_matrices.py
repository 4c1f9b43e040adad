"""Matrices no scene of nrmicp was built or tuned on (issue 17: "other meshes, elements, clients"),
as obstacle problems for benchmarks/finite_elements.py:

    OPENBLAS_NUM_THREADS=1 python benchmarks/finite_elements.py --cases Q1 Q2 tetP1 tetP2 materials \\
        aniso rotated graph plate --peers newton-amg nrmgs+aa --budget 30

Each builder returns an nrmicp.scenes.Problem (A, q, the obstacle ψ as ζ); n grows with `size`.

    Q1, Q2      scikit-fem bilinear / biquadratic quadrilaterals on a tensor mesh of [-1, 1]² (Q1: a
                9-point M-matrix; Q2: positive off-diagonals), f = −1, ψ = 0.1 − |x − (0.3, 0.2)|²
    tetP1/P2    scikit-fem tetrahedra on a tensor mesh of [-1, 1]³ (no M-matrices), f = −1,
                ψ = −0.1 − |x − (0.3, 0.2, 0)|²: contact on a small ball
    materials   P1 on the disk-like polygon, stiffness 1000× larger for x > 0.1, ψ = 0.02 − |x − c|²
                (also tests/test_finite_elements.py's coarse-settle test)
    aniso       5-point ε ∂xx + ∂yy, ε = 10⁻³ (strong couplings along y only)
    rotated     9-point rotated anisotropy (pyamg's diffusion_stencil_2d, ε = 0.01, θ = 30°, FE)
    graph       Laplacian of a random geometric graph on the unit square (+10⁻³ I): no mesh at all
    plate       Kirchhoff plate (the 5-point Laplacian squared, h⁴-scaled; fourth order, no
                M-matrix), q = 200 h⁴ (a uniform load pressing it onto the obstacle)
    dirrows     P1 on the disk-like polygon with every degree of freedom kept and the boundary
                rows replaced by identity rows, their columns kept (as FEniCS' DirichletBC.apply
                and PETSc's MatZeroRows leave them: A nonsymmetric), q = 0 and ψ ≤ 0 there
The grid and graph cases take ψ = 0.1 − |x − (0.55, 0.45)|².
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from nrmicp.scenes import Problem
from nrmicp.scenes._operators import as_csr, grid_2d, tridiag

SIZES = {"Q1": [4, 5, 6], "Q2": [3, 4, 5], "tetP1": [2, 3, 4], "tetP2": [1, 2, 3], "materials": [4, 5, 6],
         "aniso": [127, 255, 511], "rotated": [127, 255, 511], "graph": [10_000, 40_000, 160_000],
         "plate": [63, 127, 255], "dirrows": [4, 5, 6]}
QUICK = {"dirrows": [4], "Q1": [4], "Q2": [3], "tetP1": [2], "tetP2": [1], "materials": [4], "aniso": [127], "rotated": [127],
         "graph": [10_000], "plate": [63]}


def _fe(case, r):
    import skfem
    from skfem.helpers import dot, grad

    if case in ("Q1", "Q2"):
        mesh = skfem.MeshQuad.init_tensor(*(np.linspace(-1, 1, 9),) * 2).refined(r)
        elem = skfem.ElementQuad1() if case == "Q1" else skfem.ElementQuad2()
    elif case in ("tetP1", "tetP2"):
        mesh = skfem.MeshTet.init_tensor(*(np.linspace(-1, 1, 5),) * 3).refined(r)
        elem = skfem.ElementTetP1() if case == "tetP1" else skfem.ElementTetP2()
    else:
        mesh, elem = skfem.MeshTri.init_circle(3).refined(r), skfem.ElementTriP1()
    basis = skfem.Basis(mesh, elem)
    contrast = 999.0 if case == "materials" else 0.0

    @skfem.BilinearForm
    def stiffness(u, v, w):
        return (1.0 + contrast * (w.x[0] > 0.1)) * dot(grad(u), grad(v))

    K = as_csr(skfem.asm(stiffness, basis))
    q = np.asarray(skfem.asm(skfem.LinearForm(lambda v, w: 1.0 * v), basis))
    boundary = basis.get_dofs().all()
    kept = np.ones(K.shape[0], dtype=bool)
    kept[boundary] = False
    if case == "dirrows":   # identity rows on the boundary, columns kept
        A = as_csr(sp.diags_array(kept.astype(float)) @ K + sp.diags_array((~kept).astype(float)))
        q[boundary] = 0.0
        inner = np.arange(K.shape[0])
    else:
        inner = np.flatnonzero(kept)
        A = as_csr(K[inner][:, inner])
    x = basis.doflocs[:, inner]
    d2 = (x[0] - 0.3) ** 2 + (x[1] - 0.2) ** 2 + (x[2] ** 2 if x.shape[0] == 3 else 0.0)
    psi = {"materials": 0.02, "tetP1": -0.1, "tetP2": -0.1}.get(case, 0.1) - d2
    if case == "dirrows":
        psi[boundary] = np.minimum(psi[boundary], 0.0)
    return A, q[inner], psi


def _algebraic(case, size):
    if case == "graph":
        from scipy.spatial import cKDTree
        rng = np.random.default_rng(0)
        pts = rng.random((size, 2))
        pairs = cKDTree(pts).query_pairs(1.6 / np.sqrt(size), output_type="ndarray")
        W = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(size, size))
        W = (W + W.T).tocsr()
        A = sp.csr_matrix(sp.diags_array(np.asarray(W.sum(axis=1)).ravel() + 1e-3) - W)
        X, Y = pts[:, 0], pts[:, 1]
        q = np.full(size, 80.0 / size)
    else:
        m = size
        (X, Y), h = grid_2d(m), 1.0 / (m + 1)
        eye, t = sp.identity(m), tridiag(m, -1.0, 2.0, -1.0)   # t: h² × the 1D −Δ_h
        if case == "aniso":
            A = sp.csr_matrix(1e-3 * sp.kron(eye, t) + sp.kron(t, eye))
            q = np.full(m * m, 8.0 * h * h)
        elif case == "rotated":
            import pyamg
            stencil = pyamg.gallery.diffusion_stencil_2d(epsilon=0.01, theta=np.pi / 6, type="FE")
            A = sp.csr_matrix(pyamg.gallery.stencil_grid(stencil, (m, m)))
            q = np.full(m * m, 8.0 * h * h)
        else:   # plate
            L = sp.kron(eye, t) + sp.kron(t, eye)
            A = sp.csr_matrix(L @ L)
            q = np.full(m * m, 200.0 * h ** 4)
    return as_csr(A), q, 0.1 - (X - 0.55) ** 2 - (Y - 0.45) ** 2


def build(case: str, size: int) -> Problem:
    """The obstacle problem `case` at `size` (SIZES)."""
    A, q, psi = (_fe if case in ("Q1", "Q2", "tetP1", "tetP2", "materials", "dirrows") else _algebraic)(case, size)
    return Problem(name=f"{case}({size})", A=A, q=q, zeta=psi, z_exact=None,
                   description=f"obstacle problem on the {case} matrix (benchmarks/other_matrices.py)")
