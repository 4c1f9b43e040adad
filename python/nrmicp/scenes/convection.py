"""Obstacle problem with convection: a nonsymmetric M-matrix.

Model (dimensionless, unit square): find u with

    −εΔu + b·∇u ≥ f,   u ≥ ψ,   (−εΔu + b·∇u − f)(u − ψ) = 0   in Ω = (0, 1)²,   u = 0 on ∂Ω,

e.g. a concentration or temperature transported by a constant flow b and kept above a
threshold ψ (a pricing problem with drift has the same form). ψ is the paraboloid of
:func:`obstacle_2d`.

Discretization: 5-point −εΔ_h plus first-order *upwind* differences for b·∇ (backward
where b > 0, forward where b < 0), on m × m interior nodes, h = 1/(m + 1), x fastest. Upwinding
keeps every off-diagonal entry ≤ 0 and every row sum ≥ 0 (> 0 next to the boundary), so
A is a nonsymmetric, irreducibly diagonally dominant M-matrix whatever the Péclet number
|b|h/(2ε); central differences would lose that once |b|h/(2ε) > 1. q = −f, ζ = ψ (constant:
a shifted LCP).

Left out: second-order accuracy in the convective term (upwinding is O(h) and smears
boundary layers), variable or divergence-free flow fields, time dependence.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from . import Problem
from ._exact import solve_exact_obstacle
from ._operators import as_csr, grid_2d, neg_laplacian_1d, upwind_derivative_1d


def convection_diffusion_matrix(m: int, eps: float, b: tuple) -> sp.csr_matrix:
    """−εΔ_h + b·∇_h (upwind) on m × m interior nodes, x fastest."""
    eye = sp.identity(m, format="csr")
    lap = neg_laplacian_1d(m)
    return as_csr(eps * (sp.kron(eye, lap) + sp.kron(lap, eye))
                  + sp.kron(eye, upwind_derivative_1d(m, b[0]))
                  + sp.kron(upwind_derivative_1d(m, b[1]), eye))


def convection_diffusion_obstacle(m: int, eps: float = 0.1, b: tuple = (1.0, 0.5),
                                  a: float = 0.1, load: float = 0.0, exact=None) -> Problem:
    """Upwind convection–diffusion obstacle problem on m × m interior nodes (n = m²).

    ``eps`` diffusion, ``b`` = (b_x, b_y) the flow, ψ = a − (x − ½)² − (y − ½)², f ≡ ``load``.
    With the defaults the cell Péclet number |b|h/(2ε) is 0.09 at m = 63 and A is clearly
    nonsymmetric (convective entries b/h are about a sixth of the diffusive ε/h² at m = 63).
    Measured with the active-set prototype (benchmarks/newton_prototype.py, m = 63 → 255):
    a cold start needs 23 → 45 steps; nested from RS-AMG coarse levels, 3 steps on the finest
    level at every m. With stronger convection nesting helps less: ε = 0.03, 6 finest steps
    at every m; ε = 0.01, 7 → 10 (the upwind scheme's O(h) error moves the free boundary
    between levels). ``z_exact`` by policy iteration (exact for an M-matrix) when ``exact``
    is True (default: when n ≤ 40 000).
    """
    if not eps > 0:
        raise ValueError(f"eps must be > 0, got {eps}")
    b = tuple(float(v) for v in b)
    if len(b) != 2:
        raise ValueError(f"b must be a pair (b_x, b_y), got {b}")
    A = convection_diffusion_matrix(m, eps, b)
    X, Y = grid_2d(m)
    psi = a - (X - 0.5) ** 2 - (Y - 0.5) ** 2
    q = np.full(m * m, -float(load))
    if exact is None:
        exact = m * m <= 40_000
    h = 1.0 / (m + 1)
    return Problem(
        name=f"convection_diffusion_obstacle(m={m}, eps={eps}, b={b})", A=A, q=q, zeta=psi,
        z_exact=solve_exact_obstacle(A, q, psi) if exact else None,
        reference={"x": X, "y": Y, "h": h, "eps": eps, "b": b,
                   "peclet": float(np.hypot(*b) * h / (2 * eps))},
        description=f"2D upwind convection-diffusion obstacle, eps={eps}, b={b}, {m}x{m} "
                    f"(nonsymmetric M-matrix, shifted LCP)",
        models=("diffusion and transport by a constant flow", "lower bound (obstacle) on the state"),
        omits=("second-order convection (upwind is first order)", "variable flow fields",
               "time dependence"),
        lipschitz=0.0, grid=(m, m))
