"""Prolongations for nested iteration (the ``hierarchy=`` option of ``method="newton"``).

A hierarchy is a list of prolongation matrices [P_0, P_1, …]: P_l maps level l + 1 to level
l, shape (n_l, n_{l+1}), level 0 being the problem itself (n_0 = n). The coarse problems
are the Galerkin ones, A_{l+1} = P_lᵀ A_l P_l and q_{l+1} = P_lᵀ q_l; the C++ solver takes the
list and solves coarse to fine. Building it is this module's job:

- ``"amg"``: classical Ruge–Stüben prolongations from pyamg (no grid needed). For an
  M-matrix they are nonnegative, so a prolongated feasible start stays close to feasible.
- a list of matrices: a geometric hierarchy (the grid scenes offer theirs as
  ``Problem.prolongations``), checked here.
- None: no hierarchy (a cold start).

pyamg is imported only when ``"amg"`` is asked for (its import costs about a second).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ._inputs import as_csr

__all__ = ["amg_prolongations", "resolve_hierarchy"]

# Classical strength of connection on A's rows, θ = 0.25 (pyamg's default): it needs no
# symmetry. On the upwind convection–diffusion obstacle (scenes, ε = 0.01, m = 63 → 191,
# nested active-set Newton of benchmarks/newton_prototype.py) it gave 7 → 10 finest-level
# steps where 'symmetric' strength gave 17 → 53 (cold start: 21 → 57); at ε = 0.1, 3 steps
# flat (m = 63 → 255).
_RS_DEFAULTS = {"strength": ("classical", {"theta": 0.25}), "max_coarse": 10, "max_levels": 30}


def _pyamg():
    try:
        import pyamg
    except ImportError as exc:
        raise ImportError(
            "hierarchy='amg' needs pyamg (pip install pyamg); pass hierarchy=None for a cold "
            "start or a list of prolongation matrices for a geometric hierarchy") from exc
    return pyamg


def amg_prolongations(A, **opts) -> list:
    """Classical (Ruge–Stüben) AMG prolongations of A, finest first.

    ``opts`` go to ``pyamg.ruge_stuben_solver`` (e.g. ``strength``, ``CF``,
    ``interpolation``, ``max_coarse``, ``max_levels``); the defaults are
    classical strength with θ = 0.25, coarsening down to at most 10 unknowns. Works for
    nonsymmetric A (the strength measure reads A's rows). Returns a list of float64
    canonical ``scipy.sparse.csr_matrix``, P_l of shape (n_l, n_{l+1}); ``[]`` when A is
    already small enough to be the coarsest level.
    """
    pyamg = _pyamg()
    A = sp.csr_matrix(A, dtype=np.float64)
    if A.shape[0] != A.shape[1]:
        raise ValueError(f"A must be square, got shape {A.shape}")
    kw = {**_RS_DEFAULTS, **opts}
    if A.shape[0] <= kw["max_coarse"]:
        return []
    # A first coarse operator denser than A (7-point 3D: 546k unknowns, 18.7 nonzeros a row
    # against 6.9) costs more per V-cycle and per Newton step than the finest level: it is then
    # folded into the next (P_0 P_1, nonnegative), whose levels use direct interpolation (a
    # third of classical's set-up there). Measured (obstacle_3d, tol 1e-8, one solve, CPU s):
    # m = 103, 12.0 -> 8.5 s, 2.3 -> 1.46 GB peak, 3 -> 4 finest steps; m = 47, 1.08 -> 0.53 s.
    # Folding the 2D 5-point first level (not denser) took 13 finest steps instead of 3;
    # θ = 0.5 changed nothing on the 7-point stencil (all its connections are equally strong);
    # PMIS with direct interpolation took 18-26 finest steps.
    first = pyamg.ruge_stuben_solver(A, **{**kw, "max_levels": 2})
    if len(first.levels) < 2:
        return []
    P0, A1 = first.levels[0].P, first.levels[1].A
    out = [P0]
    if A1.shape[0] > kw["max_coarse"] and kw["max_levels"] > 2:
        dense = A1.nnz > A.nnz
        kw1 = {**kw, "max_levels": kw["max_levels"] - 1}
        rest = pyamg.ruge_stuben_solver(A1, **({**kw1, "interpolation": "direct"} if dense and "interpolation" not in opts
                                               else kw1))
        out += [level.P for level in rest.levels[:-1]]
        if dense and len(out) > 1:
            out[:2] = [out[0] @ out[1]]
    return [_canonical(P) for P in out]


def _canonical(P):
    P = sp.csr_matrix(P, dtype=np.float64)
    P.eliminate_zeros()
    P.sort_indices()
    return P


def resolve_hierarchy(hierarchy, A) -> list | None:
    """The ``hierarchy=`` option as a checked list of prolongations, or None.

    Accepts ``"amg"`` (→ :func:`amg_prolongations`), a list or tuple of prolongation
    matrices P_0, P_1, … (P_l of shape (n_l, n_{l+1}) with n_0 = A's size and each level
    strictly coarser; finite; converted to canonical float64 CSR), or None. An empty list
    means no coarse level (a cold start). Raises TypeError/ValueError naming ``hierarchy``
    and the offending level.
    """
    if hierarchy is None:
        return None
    if isinstance(hierarchy, str):
        if hierarchy == "amg":
            return amg_prolongations(A)
        raise ValueError(f"hierarchy must be 'amg', a list of prolongation matrices or None, "
                         f"got {hierarchy!r}")
    if not isinstance(hierarchy, (list, tuple)):
        raise TypeError(f"hierarchy must be 'amg', a list of prolongation matrices or None, "
                        f"got {type(hierarchy).__name__}")
    rows = A.shape[0]
    out = []
    for level, P in enumerate(hierarchy):
        name = f"hierarchy[{level}]"
        P = as_csr(P, name, square=False)
        n_fine, n_coarse = P.shape
        if n_fine != rows:
            where = "A's size" if level == 0 else f"the columns of hierarchy[{level - 1}]"
            raise ValueError(f"{name} has shape {P.shape}: its rows must match {where} ({rows})")
        if not 1 <= n_coarse < n_fine:
            raise ValueError(f"{name} has shape {P.shape}: a prolongation maps a strictly "
                             f"coarser level (1 <= columns < rows)")
        out.append(P)
        rows = n_coarse
    return out
