"""Membrane over an off-centre obstacle, Lagrange finite elements (P1, P2, P3) built with
scikit-fem: the matrices a finite-element user brings.

Model: find u with −Δu ≥ f, u ≥ ψ, (−Δu − f)(u − ψ) = 0 in Ω, u = 0 on ∂Ω, where Ω is a
polygon approximating the unit disk (scikit-fem's ``MeshTri.init_circle(3)``, 256
triangles), refined uniformly ``refinements`` times *without* moving the boundary, so the
meshes are nested and the coarse spaces are subspaces of the fine ones.

Discretization: conforming P_k elements on the interior degrees of freedom (Dirichlet rows and
columns removed). As ICP(q, A, ζ) in z = the nodal values:

    A = the stiffness matrix ∫∇φ_i·∇φ_j (SPD; for P2 and P3 *not* an M-matrix: it has
        positive off-diagonal entries),
    q = −∫ f φ_i,   ζ = ψ at the degrees of freedom (a nodal obstacle: a constant vector).

Load f ≡ −1 (the membrane is pressed down onto the obstacle); obstacle
ψ(x) = 0.1 − |x − (0.3, 0.2)|² (off-centre, so no symmetry of the disk helps a solver).

``Problem.prolongations()`` returns the finite-element hierarchy's own nested interpolation
(coarse function evaluated at the fine degrees of freedom, Dirichlet ones dropped), to pass as
``hierarchy=``; ``hierarchy="amg"`` is what a user without it gets.

scikit-fem is a test and benchmark dependency, not one of nrmicp's: it is imported when a scene
is built (``pip install scikit-fem``).

Left out: large deflections, friction, adhesion, dynamics (as the grid obstacle scenes), and a curved boundary.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from . import Problem

__all__ = ["fe_obstacle", "fe_interpolation"]

_CENTRE = (0.3, 0.2)
_ELEMENTS = ("P1", "P2", "P3")


def _skfem():
    try:
        import skfem
    except ImportError as exc:
        raise ImportError("nrmicp.scenes.fe_obstacle needs scikit-fem (pip install scikit-fem), a test and "
                          "benchmark dependency of nrmicp, not a runtime one") from exc
    return skfem


def _basis(element: str, refinements: int):
    skfem = _skfem()
    elem = {"P1": skfem.ElementTriP1, "P2": skfem.ElementTriP2, "P3": skfem.ElementTriP3}[element]()
    # init_circle's own refinement projects the boundary onto the circle; .refined() does not,
    # which keeps the meshes nested (every coarse function lives on the fine mesh).
    mesh = skfem.MeshTri.init_circle(3).refined(refinements) if refinements else skfem.MeshTri.init_circle(3)
    return skfem.Basis(mesh, elem)


def _interior(basis) -> np.ndarray:
    return basis.complement_dofs(basis.get_dofs())


def _check(element, refinements):
    if element not in _ELEMENTS:
        raise ValueError(f"element must be one of {_ELEMENTS}, got {element!r}")
    if not isinstance(refinements, (int, np.integer)) or isinstance(refinements, bool) or not 0 <= refinements <= 8:
        raise ValueError(f"refinements must be an int in 0..8, got {refinements!r}")


def _cells(mesh, x: np.ndarray) -> np.ndarray:
    """The triangle of ``mesh`` holding each point of x (2, N): among the 8 nearest centroids,
    the first whose barycentric coordinates are ≥ −1e-10 (scikit-fem's own finder compares
    every point with the union of all candidates, N × cells memory)."""
    from scipy.spatial import cKDTree

    p, t = mesh.p, mesh.t
    k = min(8, t.shape[1])
    cand = cKDTree(p[:, t].mean(axis=1).T).query(x.T, k)[1].reshape(x.shape[1], k)
    a, b, c = (p[:, t[i, cand]] for i in range(3))           # (2, N, k) corners
    det = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    dx, dy = x[0][:, None] - a[0], x[1][:, None] - a[1]
    l1 = (dx * (c[1] - a[1]) - dy * (c[0] - a[0])) / det
    l2 = ((b[0] - a[0]) * dy - (b[1] - a[1]) * dx) / det
    inside = (l1 >= -1e-10) & (l2 >= -1e-10) & (1.0 - l1 - l2 >= -1e-10)
    if not inside.any(axis=1).all():
        raise ValueError("a fine node lies in none of the nearest coarse triangles: meshes not nested")
    return cand[np.arange(x.shape[1]), inside.argmax(axis=1)]


def _probes(basis, x: np.ndarray) -> sp.csr_matrix:
    """The basis functions of ``basis`` at the points x (2, N), as an (N, basis.N) matrix: what
    ``basis.probes(x)`` computes, with the point location of :func:`_cells`."""
    cells = _cells(basis.mesh, x)
    pts = basis.mapping.invF(x[:, :, None], tind=cells)
    phis = np.array([basis.elem.gbasis(basis.mapping, pts, k, tind=cells)[0] for k in range(basis.Nbfun)])
    rows = np.tile(np.arange(x.shape[1]), basis.Nbfun)
    cols = basis.element_dofs[:, cells].ravel()
    return sp.csr_matrix((phis.ravel(), (rows, cols)), shape=(x.shape[1], basis.N))


def fe_interpolation(element: str, refinements: int) -> list:
    """The nested interpolation of the finite-element hierarchy, finest first: P_l maps the
    interior degrees of freedom after ``refinements − l − 1`` refinements to those after
    ``refinements − l``, shape (n_l, n_{l+1}); down to the unrefined polygon. It has negative
    weights for P2 and P3 (−1/8 at edge midpoints for P2)."""
    _check(element, refinements)
    out = []
    fine = _basis(element, refinements)
    for r in range(refinements - 1, -1, -1):
        coarse = _basis(element, r)
        # the coarse function at the fine interior nodes (boundary ones may round to outside)
        P = _probes(coarse, fine.doflocs[:, _interior(fine)])[:, _interior(coarse)]
        P.data[np.abs(P.data) < 1e-12] = 0.0     # rounding of the barycentric look-up
        P.eliminate_zeros()
        P.sort_indices()
        out.append(sp.csr_matrix(P, dtype=np.float64))
        fine = coarse
    return out


def fe_obstacle(element: str = "P2", refinements: int = 3, exact=None) -> Problem:
    """Membrane over an off-centre obstacle on a disk-like polygon with P1/P2/P3 elements.

    ``refinements`` uniform refinements of a 256-triangle polygon; n (interior degrees of
    freedom): P1 8,065 / 32,513 / 130,561 / 523,265 at r = 3..6, P2 the same at r = 2..5 (P2 at
    r equals P1 at r + 1). ``z_exact`` (policy iteration with direct solves; it settled on
    these problems although P2 is no M-matrix) when ``exact`` is True (default: n ≤ 20,000).
    """
    _check(element, refinements)
    skfem = _skfem()
    from skfem.models.poisson import laplace

    basis = _basis(element, refinements)
    K = skfem.asm(laplace, basis)
    load = skfem.asm(skfem.LinearForm(lambda v, w: -1.0 * v), basis)
    interior = _interior(basis)
    A = sp.csr_matrix(K[interior][:, interior], dtype=np.float64)
    A.eliminate_zeros()
    A.sort_indices()
    x, y = basis.doflocs[:, interior]
    psi = 0.1 - (x - _CENTRE[0]) ** 2 - (y - _CENTRE[1]) ** 2
    q = -np.asarray(load[interior], dtype=np.float64)
    from ._exact import exact_if_small
    z_exact = exact_if_small(A, q, psi, exact)
    return Problem(
        name=f"fe_obstacle({element}, r={refinements})", A=A, q=q, zeta=psi, z_exact=z_exact,
        reference={"x": x, "y": y, "element": element, "refinements": refinements,
                   "prolongations": lambda: fe_interpolation(element, refinements)},
        description=f"membrane over an off-centre obstacle, f = -1, {element} elements on a nested refinement "
                    f"({refinements}x) of a disk-like polygon (shifted LCP)",
        models=("linear elastic membrane (small deflections)", "rigid obstacle, unilateral contact",
                f"conforming {element} finite elements on an unstructured triangulation"),
        omits=("large-deflection nonlinearity", "friction and adhesion", "dynamics", "curved boundary"),
        lipschitz=0.0)
