"""Elastic membrane between two rigid plates (the two-sided obstacle problem): a box problem.

Model (dimensionless, as the obstacle scenes): find the deflection u with

    ψ_l ≤ u ≤ ψ_u,   −Δu − f ≥ 0 where u = ψ_l,   ≤ 0 where u = ψ_u,   = 0 between,

in Ω = (0, 1)^d, u = 0 on ∂Ω. A load that pushes one part of the membrane up and another down
presses it onto both plates.

Discretization: finite differences on the interior nodes (3- or 5-point Laplacian, h = 1/(m + 1)),
as the obstacle scenes. As a mixed complementarity problem in z = u (``nrmicp.solve(A, q,
zeta=ψ_l, upper=ψ_u)``, PATH's convention):

    A = −Δ_h,   q = −f at the nodes,   ζ = ψ_l (lower bound),   upper = ψ_u,

so w = A z + q is the contact pressure density: ≥ 0 where the membrane rests on the lower plate,
≤ 0 where the upper plate holds it down, 0 where it is free.

Left out: large deflections, friction, adhesion, dynamics, deformable plates.
"""
from __future__ import annotations

import numpy as np

from . import Problem
from ._exact import exact_fixed_point, solve_exact_box
from ._operators import grid_1d, grid_2d, heat_solve, neg_laplacian_1d, neg_laplacian_2d

__all__ = ["two_sided_membrane_1d", "two_sided_membrane_1d_exact", "two_sided_membrane_2d",
           "two_sided_membrane_heated_2d"]

_MODELS = ("linear elastic membrane (small deflections)", "two rigid plates, unilateral contact on both sides")
_OMITS = ("large-deflection nonlinearity", "friction and adhesion", "dynamics", "deformable plates")


def two_sided_membrane_1d_exact(x: np.ndarray, load: float = 16.0, gap: float = 0.125) -> np.ndarray:
    """Closed form for f = load on (0, ½), −load on (½, 1), plates at ∓gap, 0 < gap < load/32.

    By antisymmetry (u(1 − x) = −u(x)) it is enough to solve on (0, ½), where u(½) = 0. The string
    rises as u = load·x(2α − x)/2 until it meets the upper plate tangentially at α = √(2 gap/load)
    (u(α) = gap, u'(α) = 0), rests on it on [α, β], β = ½ − α, and leaves it tangentially again:
    u = gap − load(x − β)²/2, which is 0 at ½ since load·α²/2 = gap. The contact sets are
    [α, β] (upper plate, w = −load < 0) and [1 − β, 1 − α] (lower plate, w = load > 0); u is C¹
    and piecewise quadratic, and the 3-point Laplacian is exact on quadratics, so the discrete
    error comes from the free boundaries alone.
    """
    alpha = np.sqrt(2.0 * gap / load)
    if not (load > 0 and 0 < gap and 2.0 * alpha < 0.5):
        raise ValueError(f"need load > 0 and 0 < gap < load/32 so both plates are touched, got load={load}, "
                         f"gap={gap}")
    beta = 0.5 - alpha
    x = np.asarray(x, dtype=float)
    s = np.where(x <= 0.5, x, 1.0 - x)       # the mirror point on (0, ½]
    u = np.where(s < alpha, load * s * (2.0 * alpha - s) / 2.0,
                 np.where(s <= beta, gap, gap - load * (s - beta) ** 2 / 2.0))
    return np.where(x <= 0.5, u, -u)


def two_sided_membrane_1d(n: int, load: float = 16.0, gap: float = 0.125, exact: bool = True) -> Problem:
    """String between plates at ∓``gap`` under the load ±``load`` (up on the left half, down on the
    right), n interior nodes, h = 1/(n + 1); f = 0 at a node at x = ½ (the load's mean there).

    ``reference["u_exact"]`` is the closed form (:func:`two_sided_membrane_1d_exact`) at the nodes,
    ``reference["contact_upper"]``/``["contact_lower"]`` the contact intervals. The defaults put
    the free boundaries at x = 1/8, 3/8, 5/8, 7/8. ``z_exact``: the exact discrete solution (policy
    iteration) unless ``exact=False``. Observed max-norm error O(h²) (tests/test_scenes_bounds.py).
    """
    x = grid_1d(n)
    u_exact = two_sided_membrane_1d_exact(x, load, gap)    # checks load and gap
    A = neg_laplacian_1d(n)
    q = -load * np.sign(0.5 - x)                            # q = −f
    lower, upper = np.full(n, -gap), np.full(n, gap)
    alpha = np.sqrt(2.0 * gap / load)
    return Problem(
        name=f"two_sided_membrane_1d(n={n})", A=A, q=q, zeta=lower, upper=upper,
        z_exact=solve_exact_box(A, q, lower, upper) if exact else None,
        reference={"x": x, "h": 1.0 / (n + 1), "u_exact": u_exact,
                   "contact_upper": (alpha, 0.5 - alpha), "contact_lower": (0.5 + alpha, 1.0 - alpha)},
        description=f"string between plates at -/+{gap}, load +/-{load}, FD h = 1/{n + 1} (box problem)",
        models=_MODELS, omits=_OMITS, lipschitz=0.0, grid=(n,))


def two_sided_membrane_2d(m: int, load: float = 50.0, lower: float = -0.3, upper: float = 0.25,
                          exact=None) -> Problem:
    """Membrane on (0, 1)² between plates at z = ``lower`` and z = ``upper`` under the load
    f = ``load``·sin(2πx)·sin(πy) (up on the left half, down on the right): it rests on the upper
    plate in a region of the left half and on the lower plate in one of the right half (the
    plates are unequally far, so no symmetry maps one contact region onto the other).

    m × m interior nodes (n = m²), h = 1/(m + 1), lexicographic ordering (x fastest); m = 2^k − 1
    gives the grid's geometric hierarchy (``Problem.prolongations``). ``z_exact`` by policy
    iteration when ``exact`` is True (default: n ≤ 40,000), else None.
    """
    if not lower < 0.0 < upper:
        raise ValueError(f"need lower < 0 < upper (the membrane's boundary lies between the plates), got "
                         f"lower={lower}, upper={upper}")
    A = neg_laplacian_2d(m)
    X, Y = grid_2d(m)
    q = -load * np.sin(2.0 * np.pi * X) * np.sin(np.pi * Y)
    lo, up = np.full(m * m, float(lower)), np.full(m * m, float(upper))
    if exact is None:
        exact = m * m <= 40_000
    return Problem(
        name=f"two_sided_membrane_2d(m={m})", A=A, q=q, zeta=lo, upper=up,
        z_exact=solve_exact_box(A, q, lo, up) if exact else None,
        reference={"x": X, "y": Y, "h": 1.0 / (m + 1)},
        description=f"membrane between plates at {lower} and {upper}, f = {load} sin(2 pi x) sin(pi y), 5-point FD "
                    f"on {m}x{m} (box problem)",
        models=_MODELS, omits=_OMITS, lipschitz=0.0, grid=(m, m))


def _sagging_ceiling(L, ceiling: float, kappa: float, delta: float, ell: float):
    """u(z) = ceiling − κ (I − δL)⁻¹ s(ceiling − z), s(d) = 1/(1 + (d/ℓ)²): the upper plate sags toward
    the membrane where the membrane, close below it, heats it (thermoforming's mould law, from above).
    (I − δL) is factorized once; each call returns a fresh array."""
    solve = heat_solve(L, delta)

    def upper(z):
        gap = (ceiling - np.asarray(z, dtype=float)) / ell
        return ceiling - kappa * solve(1.0 / (1.0 + gap * gap))

    return upper


def two_sided_membrane_heated_2d(m: int, load: float = 50.0, lower: float = -0.3, ceiling: float = 0.25,
                                 kappa: float = 0.05, delta: float = 0.01, ell: float = 0.2, exact=None) -> Problem:
    """:func:`two_sided_membrane_2d` under a ceiling that moves with the solution ("thermoforming from
    above"): the upper plate sags by κ (I − δΔ_h)⁻¹ s(ceiling − u), s(d) = 1/(1 + (d/ℓ)²), toward the
    membrane where the membrane comes close to it (the thermoforming scene's mould law, mirrored). An
    implicit upper bound: ``upper`` is the callable u(z) (``nrmicp.solve(..., upper=problem.upper)``,
    method 'newton''s outer fixed point). Lipschitz constant of u (∞-norm): κ·3√3/(8ℓ) (0.162 with the
    defaults), a contraction, so the problem has one solution; ``z_exact`` is that fixed point of exact
    box solves (policy iteration) when ``exact`` is True (default: n ≤ 5,000).
    """
    if not lower < 0.0 < ceiling:
        raise ValueError(f"need lower < 0 < ceiling, got lower={lower}, ceiling={ceiling}")
    if not (kappa >= 0 and delta >= 0 and ell > 0 and kappa * 3.0 * np.sqrt(3.0) / (8.0 * ell) < 1.0):
        raise ValueError(f"need kappa >= 0, delta >= 0, ell > 0 and kappa 3 sqrt(3) / (8 ell) < 1 (a contraction); "
                         f"got {kappa}, {delta}, {ell}")
    A = neg_laplacian_2d(m)
    X, Y = grid_2d(m)
    q = -load * np.sin(2.0 * np.pi * X) * np.sin(np.pi * Y)
    lo = np.full(m * m, float(lower))
    upper = _sagging_ceiling(A, ceiling, kappa, delta, ell)
    if exact is None:
        exact = m * m <= 5_000
    lip = kappa * 3.0 * np.sqrt(3.0) / (8.0 * ell)
    z_exact = _exact_fixed_point(A, q, lo, upper, lip) if exact else None
    return Problem(
        name=f"two_sided_membrane_heated_2d(m={m})", A=A, q=q, zeta=lo, upper=upper, z_exact=z_exact,
        reference={"x": X, "y": Y, "h": 1.0 / (m + 1), "ceiling": ceiling, "kappa": kappa, "delta": delta,
                   "ell": ell, "upper_lipschitz": float(lip)},
        description=f"membrane between a plate at {lower} and a ceiling at {ceiling} that sags toward it where "
                    f"heated, f = {load} sin(2 pi x) sin(pi y), 5-point FD on {m}x{m} (implicit upper bound)",
        models=_MODELS + ("the ceiling sags where the membrane heats it (nonlocal, implicit upper bound)",),
        omits=_OMITS + ("transient heating (steady state only)",), lipschitz=0.0, grid=(m, m))


def _exact_fixed_point(A, q, lower, upper_fn, lipschitz, tol=1e-14, maxiter=200):
    """The fixed point z = S(u(z)) of exact box solves (solve_exact_box), u a contraction with constant
    `lipschitz` (exact_fixed_point)."""
    z = solve_exact_box(A, q, lower, upper_fn(np.zeros(A.shape[0])))
    return exact_fixed_point(lambda v: solve_exact_box(A, q, lower, upper_fn(v), z0=v), z, lipschitz, tol, maxiter,
                             "the heated membrane's exact outer fixed point")
