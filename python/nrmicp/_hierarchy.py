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
    ml = pyamg.ruge_stuben_solver(A, **kw)
    out = []
    for level in ml.levels[:-1]:
        P = sp.csr_matrix(level.P, dtype=np.float64)
        P.eliminate_zeros()
        P.sort_indices()
        out.append(P)
    return out


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
