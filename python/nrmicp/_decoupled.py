"""Decoupled rows of the Newton member (``method="newton"``, ζ none or constant).

A row whose only nonzero is its positive diagonal is a one-unknown LCP: w_i = a_ii z_i + q_i,
z_i ≥ ψ_i, complementary, so z_i = max(ψ_i, −q_i / a_ii) whatever the other unknowns are. Its
column then moves to the right-hand side of the others: q_F + A_FD z_D. Finite-element codes
leave such rows where they impose Dirichlet values by replacing rows with identity rows and
keep the columns (FEniCS' ``DirichletBC.apply``, PETSc's ``MatZeroRows``): A is then
nonsymmetric although A_FF is symmetric, and the algebraic hierarchy built on the full A makes
coarse problems that mix the fixed unknowns into the free ones (docs/finite_elements.md, "Dirichlet
rows kept as identity rows"). So the Newton member solves on A_FF and puts z_D back; an affine or callable ζ
couples z_i to other unknowns, and is solved on the whole A (a second Solver, built when first needed).
Here, not in the C++ core, because the algebraic hierarchy is built here (pyamg) and must be built on
A_FF; a C++ caller of nrmicp::Newton with such rows passes A_FF itself.
"""
from __future__ import annotations

from typing import Any, Callable, Optional

import numpy as np
import scipy.sparse as sp

from ._result import Result, wants_result


def decoupled_rows(A: sp.csr_matrix) -> Optional[np.ndarray]:
    """The rows of A whose only nonzero is a positive diagonal entry (stored zeros ignored), or
    None when there are none, all rows are, or some row has no positive diagonal (the whole A is
    then solved, so that the core's errors name the user's rows)."""
    n = A.shape[0]
    if not (np.diff(A.indptr) == 1).any() and A.data.all():   # no one-entry row, no stored zero: none (the common case)
        return None
    if not (A.diagonal() > 0).all():
        return None
    rows = np.repeat(np.arange(n), np.diff(A.indptr))
    off = (A.data != 0) & (A.indices != rows)
    D = np.flatnonzero(np.bincount(rows[off], minlength=n) == 0)
    return D if 0 < D.size < n else None


def _diagonal_part(value, F):
    """A diagonal option (omega1, omega2, phi) on the coupled rows: a vector (any shape as_diagonal
    takes) restricted, a scalar kept."""
    v = None if value is None else np.asarray(value, dtype=np.float64)
    return value if v is None or v.size == 1 else v.ravel()[F]


def _hierarchy_part(hierarchy, A, F):
    """(A list of prolongations on the coupled rows: each P_l's rows of the unknowns kept on its
    fine level (F on the first), without the coarse columns that interpolate none of them (their
    Galerkin row would be zero, and the core would end the hierarchy there); a level left no
    coarser than the one above is merged into the next, or dropped when it is the last; the
    `asked` of _newton.levels: (levels requested, why fewer are left, or None)). Strings and None
    kept (asked None)."""
    if hierarchy is None or isinstance(hierarchy, str):
        return hierarchy, None
    from ._hierarchy import resolve_hierarchy
    Ps = resolve_hierarchy(hierarchy, A)   # checked on the whole A: errors name the user's shapes
    out, kept, waiting, why = [], F, None, []   # waiting: a level not coarser than the one above, merged into the next
    for level, P in enumerate(Ps):
        P = sp.csr_matrix(P[kept])
        if waiting is not None:
            P = sp.csr_matrix(waiting @ P)
        P.eliminate_zeros()
        kept = np.unique(P.indices)
        if kept.size == 0:
            why.append(f"hierarchy[{level}] interpolates none of the coupled rows (those not a lone diagonal): "
                       "dropped with the levels after it")
            break
        P = sp.csr_matrix(P[:, kept])
        waiting = None if P.shape[1] < P.shape[0] else P
        if waiting is None:
            P.sort_indices()   # canonical: the inner Solver would warn of a conversion the user never asked for
            out.append(P)
        else:
            why.append(f"hierarchy[{level}] is no coarser than its fine level on the coupled rows ({P.shape[1]} "
                       f"columns for {P.shape[0]} rows): {'merged into the next' if level + 1 < len(Ps) else 'dropped'}")
    return out, (len(Ps) + 1, "; ".join(why) or None)


class Reduced:
    """The Newton member on the coupled rows F of A, the decoupled rows D solved in closed form.
    `settings`: the Solver's constructor arguments (checked on the whole A already)."""

    def __init__(self, solver_cls, A: sp.csr_matrix, D: np.ndarray, settings: dict, units_factor: float):
        n = A.shape[0]
        self.D = D
        coupled = np.ones(n, dtype=bool)
        coupled[D] = False
        self.F = np.flatnonzero(coupled)
        self.a = A.diagonal()[D]
        rows = A[self.F]
        self.A_FD = sp.csr_matrix(rows[:, D])
        A_FF = sp.csr_matrix(rows[:, self.F])
        A_FF.sort_indices()
        hierarchy, asked = _hierarchy_part(settings["hierarchy"], A, self.F)
        labels = settings["components"]   # checked: one per row of A, or None
        part = dict(settings, hierarchy=hierarchy, components=None if labels is None else labels[self.F],
                    **{k: _diagonal_part(settings[k], self.F) for k in ("omega1", "omega2", "phi")})
        self.inner = solver_cls(A_FF, _decouple=False, _units_factor=units_factor, _hierarchy_asked=asked, **part)
        self.n = n

    def z_decoupled(self, q: np.ndarray, c: Optional[np.ndarray]) -> Optional[np.ndarray]:
        """z_D = max(ψ_D, −q_D / a_DD) (ψ = 0 for the LCP), or None when it overflows (a tiny a_ii)."""
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            zD = np.maximum(-q[self.D] / self.a, 0.0 if c is None else c[self.D])
        return zD if np.isfinite(zD).all() else None

    def expand(self, zF: np.ndarray, zD: np.ndarray) -> np.ndarray:
        z = np.empty(self.n)
        z[self.F] = zF
        z[self.D] = zD
        return z

    def solve(self, q: np.ndarray, c: Optional[np.ndarray], zD: np.ndarray, x0: Optional[np.ndarray],
              callback: Optional[Callable[..., Any]], options: dict, measure):
        """The inner Solver's result for q (full length), the constant obstacle c (or None), the
        decoupled rows' zD and the start x0 under the iteration `options` (an absolute tol), with
        z, w and Res (`measure(z)` -> (w, Res) on the whole A) in the whole problem's variables; its
        status is the caller's to re-decide. The history, the callback's residual and the messages
        are the coupled rows' Res (the decoupled rows' part of it is rounding)."""
        qF = q[self.F] + self.A_FD @ zD
        cb = None if callback is None else _expanding(callback, lambda zF: self.expand(zF, zD))
        r = self.inner._solve(qF, None if c is None else c[self.F], x0=None if x0 is None else x0[self.F],
                              callback=cb, **options)
        z = self.expand(r.z, zD)
        w, res = measure(z)
        r.update(z=z, w=w, residual=res)
        return r


def _expanding(callback: Callable[..., Any], expand: Callable[[np.ndarray], np.ndarray]) -> Callable[..., Any]:
    """The user's callback, called with the whole iterate (its calling form kept: scipy's
    ``intermediate_result`` or the plain ``callback(xk)``)."""
    if wants_result(callback):
        def hook(intermediate_result):
            ir = intermediate_result
            return callback(intermediate_result=Result(z=expand(ir.z), nit=ir.nit, residual=ir.residual))
        return hook
    return lambda xk: callback(expand(xk))
