"""A user's matrix with no grid and no mesh hierarchy behind it: P1 finite elements on a Delaunay
triangulation of scattered points in the unit disk, with a two-bump contact obstacle. numpy and
scipy only.

Model: −Δu ≥ f, u ≥ ψ, (−Δu − f)(u − ψ) = 0 in the unit disk, u = 0 on its boundary, f ≡ −2,
ψ(x) = max(0.05 − |x − c₁|², 0.02 − 2|x − c₂|²) with c₁ = (0.35, 0.1), c₂ = (−0.3, −0.25): two
contact regions, and a kink in ψ where the bumps meet.

Mesh: a sunflower (Vogel) spiral of interior points, quasi-uniform and on no lattice, plus
equally spaced points on the circle, triangulated by ``scipy.spatial.Delaunay``. Each size is a
new point set (not a refinement), as a user's meshes are: the only hierarchy is the algebraic one
(``hierarchy="amg"``). P1 stiffness matrix (an M-matrix only where the triangulation is
Delaunay with no obtuse pair; a few positive off-diagonals may remain), lumped load f·|T|/3.

As ICP(q, A, ζ) in z = the nodal values of u at the interior points: A = stiffness, q = −load,
ζ = ψ at the nodes (a constant vector: a shifted LCP).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from . import Problem

__all__ = ["contact_disk_p1", "p1_stiffness"]

_GOLDEN = np.pi * (3.0 - np.sqrt(5.0))


def p1_stiffness(points: np.ndarray, triangles: np.ndarray) -> tuple:
    """(K, lumped mass) of P1 elements: K_ij = ∫∇φ_i·∇φ_j as CSR, and ∫φ_i = Σ|T|/3."""
    p = points[triangles]                              # (t, 3, 2)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    area = 0.5 * np.abs(det)
    # gradients of the barycentric coordinates: rotate the opposite edge by 90° and divide by 2|T|
    opp = np.stack([p[:, 2] - p[:, 1], p[:, 0] - p[:, 2], p[:, 1] - p[:, 0]], axis=1)
    grad = np.stack([-opp[..., 1], opp[..., 0]], axis=-1) / det[:, None, None]
    local = area[:, None, None] * np.einsum("tak,tbk->tab", grad, grad)
    rows = np.repeat(triangles, 3, axis=1).ravel()
    cols = np.tile(triangles, (1, 3)).ravel()
    n = points.shape[0]
    K = sp.csr_matrix((local.ravel(), (rows, cols)), shape=(n, n))
    K.sum_duplicates()
    mass = np.bincount(triangles.ravel(), np.repeat(area / 3.0, 3), minlength=n)
    return K, mass


def _disk_points(n_interior: int) -> tuple:
    k = np.arange(n_interior) + 0.5
    r = np.sqrt(k / n_interior) * (1.0 - 0.5 / np.sqrt(n_interior))  # keep off the circle
    inner = np.column_stack([r * np.cos(k * _GOLDEN), r * np.sin(k * _GOLDEN)])
    m = int(np.ceil(2.0 * np.sqrt(np.pi * n_interior)))               # boundary spacing ≈ interior spacing
    t = 2.0 * np.pi * np.arange(m) / m
    return np.vstack([inner, np.column_stack([np.cos(t), np.sin(t)])]), n_interior


def contact_disk_p1(n: int = 20_000, exact=None) -> Problem:
    """P1 membrane over a two-bump obstacle on a Delaunay mesh of ``n`` scattered interior points
    of the unit disk (see the module docstring). ``z_exact`` by policy iteration with direct
    solves when ``exact`` is True (default: n ≤ 20,000)."""
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 16:
        raise ValueError(f"n must be an int >= 16, got {n!r}")
    from scipy.spatial import Delaunay

    points, n_in = _disk_points(int(n))
    tri = Delaunay(points).simplices
    K, mass = p1_stiffness(points, tri)
    A = sp.csr_matrix(K[:n_in, :n_in])
    A.eliminate_zeros()
    A.sort_indices()
    x, y = points[:n_in, 0], points[:n_in, 1]
    psi = np.maximum(0.05 - (x - 0.35) ** 2 - (y - 0.1) ** 2, 0.02 - 2.0 * ((x + 0.3) ** 2 + (y + 0.25) ** 2))
    q = 2.0 * mass[:n_in]                              # q = −∫fφ, f = −2
    from ._exact import exact_if_small
    z_exact = exact_if_small(A, q, psi, exact)
    return Problem(
        name=f"contact_disk_p1(n={n_in})", A=A, q=q, zeta=psi, z_exact=z_exact,
        reference={"x": x, "y": y, "triangles": tri},
        description="membrane over a two-bump obstacle, f = -2, P1 elements on a Delaunay mesh of scattered points "
                    "in the unit disk, no grid and no mesh hierarchy (shifted LCP)",
        models=("linear elastic membrane (small deflections)", "rigid obstacle with a kink, unilateral contact",
                "P1 finite elements on an unstructured triangulation"),
        omits=("large-deflection nonlinearity", "friction and adhesion", "dynamics", "curved boundary"),
        lipschitz=0.0)
