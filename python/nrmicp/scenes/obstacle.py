"""Elastic membrane over a rigid obstacle (the classical obstacle problem).

Model (dimensionless: unit tension, unit domain): find the deflection u with

    −Δu ≥ f,   u ≥ ψ,   (−Δu − f)(u − ψ) = 0   in Ω = (0, 1)^d,   u = 0 on ∂Ω.

Discretization: finite differences on the interior nodes, h = 1/(n + 1), 3-point (1D),
5-point (2D) or 7-point (3D) Laplacian. As ICP(q, A, ζ) in z = u:

    A = −Δ_h (entries 2/h² and −1/h² in 1D, 4/h² and −1/h² in 2D: the PDE as written,
        so w = A z + q is the contact pressure density in units of f),
    q = −f (sampled at the nodes),   ζ = ψ (sampled) — a constant vector, i.e. a shifted LCP.

Accuracy note: Res(z) ≈ ‖A‖ δz with ‖A‖∞ = 4/h² (1D) or 8/h² (2D), so an absolute tol on Res
asks for δz ≈ tol·h²/4. At h = 1/540, Res < 1e-7 already means δz ~ 1e-14 and tol = 1e-8 sits
at the double-precision floor; conversely ‖δz‖ ≲ Res/λ_min(A) ≈ Res/π².

Left out: membrane nonlinearity (large deflections), friction, adhesion, dynamics, a
deformable obstacle.
"""
from __future__ import annotations

import numpy as np

from . import Problem
from ._exact import solve_exact_obstacle
from ._operators import grid_1d, grid_2d, grid_3d, neg_laplacian_1d, neg_laplacian_2d, neg_laplacian_3d

_MODELS = ("linear elastic membrane (small deflections)", "rigid obstacle, unilateral contact")
_OMITS = ("large-deflection nonlinearity", "friction and adhesion", "dynamics",
          "deformable or temperature-dependent obstacle")


def obstacle_1d_exact(x: np.ndarray, a: float = 0.1) -> np.ndarray:
    """Closed-form solution for f = 0, ψ(x) = a − (x − ½)², 0 < a < ¼.

    The string is straight from (0, 0) to the tangent point x₀, follows ψ on the contact
    set [x₀, 1 − x₀], and is straight again. Tangency (u = ψ, u' = ψ' at x₀ with u linear
    through the origin) gives y = x₀ − ½ as the root of y² + y + a = 0 in (−½, 0):
    x₀ = ½ + (−1 + √(1 − 4a))/2, slope ψ(x₀)/x₀.
    """
    if not 0.0 < a < 0.25:
        raise ValueError(f"need 0 < a < 1/4 so the obstacle is below the boundary data, got a={a}")
    x0 = 0.5 + 0.5 * (-1.0 + np.sqrt(1.0 - 4.0 * a))
    slope = (a - (x0 - 0.5) ** 2) / x0
    xs = np.minimum(x, 1.0 - x)  # symmetric about ½
    return np.where(xs < x0, slope * xs, a - (x - 0.5) ** 2)


def obstacle_1d(n: int, a: float = 0.1, exact: bool = True) -> Problem:
    """1D membrane (string) over the concave obstacle ψ(x) = a − (x − ½)², no load (f = 0).

    n interior nodes, h = 1/(n + 1). ``reference["u_exact"]`` is the closed-form solution
    (:func:`obstacle_1d_exact`) at the nodes and ``reference["contact"]`` the contact
    interval [x₀, 1 − x₀]. ``z_exact`` is the exact discrete solution (policy iteration,
    cheap in 1D) unless ``exact=False``.

    Discretization error (measured, see tests/test_scenes.py): max-norm error O(h²),
    observed order ≈ 2 — the solution is C^{1,1} (u'' jumps at the free boundary), and in 1D
    the discrete string between two contact nodes is exactly linear, so the free-boundary
    mislocation of O(h) costs only O(h²) in u (the tangency makes the error quadratic).
    """
    A = neg_laplacian_1d(n)
    x = grid_1d(n)
    psi = a - (x - 0.5) ** 2
    q = np.zeros(n)  # −f, f = 0
    x0 = 0.5 + 0.5 * (-1.0 + np.sqrt(1.0 - 4.0 * a))
    return Problem(
        name=f"obstacle_1d(n={n})", A=A, q=q, zeta=psi,
        z_exact=solve_exact_obstacle(A, q, psi) if exact else None,
        reference={"x": x, "h": 1.0 / (n + 1), "u_exact": obstacle_1d_exact(x, a),
                   "contact": (x0, 1.0 - x0)},
        description=f"string over the obstacle {a} - (x-1/2)^2, f = 0, FD h = 1/{n + 1} (shifted LCP)",
        models=_MODELS, omits=_OMITS, lipschitz=0.0, grid=(n,))


def obstacle_2d(m: int, a: float = 0.1, load: float = 0.0, exact=None) -> Problem:
    """2D membrane on (0, 1)² over the paraboloid ψ = a − (x − ½)² − (y − ½)², load f ≡ ``load``.

    m × m interior nodes (n = m²), h = 1/(m + 1), lexicographic ordering (x fastest).
    No closed form on the square; ``z_exact`` is the exact discrete solution by policy
    iteration when ``exact`` is True (default: when n ≤ 40 000), else None.
    """
    A = neg_laplacian_2d(m)
    X, Y = grid_2d(m)
    psi = a - (X - 0.5) ** 2 - (Y - 0.5) ** 2
    q = np.full(m * m, -float(load))
    if exact is None:
        exact = m * m <= 40_000
    return Problem(
        name=f"obstacle_2d(m={m})", A=A, q=q, zeta=psi,
        z_exact=solve_exact_obstacle(A, q, psi) if exact else None,
        reference={"x": X, "y": Y, "h": 1.0 / (m + 1)},
        description=f"membrane over a paraboloid obstacle, f = {load}, 5-point FD on {m}x{m} (shifted LCP)",
        models=_MODELS, omits=_OMITS, lipschitz=0.0, grid=(m, m))


def obstacle_3d(m: int, a: float = 0.1, load: float = 0.0, exact=None) -> Problem:
    """3D obstacle problem on (0, 1)³ over ψ = a − |x − ½|², load f ≡ ``load``, μ = 0.

    Not a membrane any more but the same variational inequality (e.g. a confined elastic
    body or a potential bounded below); it is here because 3D is where factorizations get
    expensive (fill grows like n^{4/3}). m³ interior nodes (n = m³), h = 1/(m + 1), 7-point
    Laplacian, lexicographic ordering (x fastest). ``z_exact`` by policy iteration when
    ``exact`` is True (default: when n ≤ 20 000), else None.
    """
    A = neg_laplacian_3d(m)
    X, Y, Z = grid_3d(m)
    psi = a - (X - 0.5) ** 2 - (Y - 0.5) ** 2 - (Z - 0.5) ** 2
    q = np.full(m**3, -float(load))
    if exact is None:
        exact = m**3 <= 20_000
    return Problem(
        name=f"obstacle_3d(m={m})", A=A, q=q, zeta=psi,
        z_exact=solve_exact_obstacle(A, q, psi) if exact else None,
        reference={"x": X, "y": Y, "z": Z, "h": 1.0 / (m + 1)},
        description=f"3D obstacle problem over a paraboloid, f = {load}, 7-point FD on {m}^3 (shifted LCP)",
        models=("Laplace operator in 3D (mu = 0)", "rigid obstacle, unilateral constraint"),
        omits=("any specific 3D physics beyond the Laplacian",) + _OMITS[1:],
        lipschitz=0.0, grid=(m, m, m))
