"""Infeasibility that the data show at a glance, named in the message of a solve that did not
converge (it costs one pass over A, and only then).

Row i of ICP(q, A, ζ) has no solution when w_i = (Az + q)_i can never be >= 0:
  - any ζ: row i of A is zero and q_i < 0 (w_i = q_i for every z);
  - an LCP (ζ = 0, z >= 0): no entry of row i is positive and q_i < 0 (w_i <= q_i);
  - ζ = c (z >= c, z = y + c with y >= 0): no entry of row i is positive and (q + Ac)_i < 0;
  - bounds lo <= z <= u (w_i >= 0 at lo_i, <= 0 at u_i, 0 between): row i of A is zero and q_i > 0 with
    lo_i = -inf, or q_i < 0 with u_i = +inf (w_i = q_i never vanishes, and no bound holds z_i).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def _row_extremes(A: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    """(largest entry, largest |entry|) of each row, 0 for an empty row."""
    nnz = np.diff(A.indptr)
    top, size = np.zeros(A.shape[0]), np.zeros(A.shape[0])
    rows = np.flatnonzero(nnz)
    if rows.size:
        top[rows] = np.maximum.reduceat(A.data, A.indptr[rows])
        size[rows] = np.maximum.reduceat(np.abs(A.data), A.indptr[rows])
    return top, size


def evident_infeasibility(A: sp.csr_matrix, q: np.ndarray, lcp: bool, c=None) -> str:
    """A message part naming the first row i that makes the problem infeasible, or "". `lcp`:
    ζ is 0 or the constant `c`; otherwise only a zero row with q_i < 0 counts."""
    top, size = _row_extremes(A)
    if lcp:
        with np.errstate(over="ignore", invalid="ignore"):
            qs = q if c is None else q + A @ c
        bad = np.flatnonzero((top <= 0) & (qs < 0))
    else:
        qs = q
        bad = np.flatnonzero((size == 0) & (q < 0))
    if bad.size == 0:
        return ""
    i = int(bad[0])
    others = f" (and {bad.size - 1} more such row(s))" if bad.size > 1 else ""
    if size[i] == 0:
        return (f"; row {i} of A is zero and q[{i}] = {q[i]:.3g} < 0: w_{i} = q_{i} can never be >= 0, the problem "
                f"has no solution{others}")
    what, bound = (f"q[{i}]", "z >= 0") if c is None else (f"(q + A c)[{i}]", "z >= c")
    return (f"; row {i} of A has no positive entry and {what} = {qs[i]:.3g} < 0: w_{i} <= {what} < 0 for every "
            f"{bound}, the problem has no solution{others}")


def box_infeasibility(A: sp.csr_matrix, q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> str:
    """evident_infeasibility's rule for the bounds lower <= z <= upper (vectors; ±inf: none)."""
    _, size = _row_extremes(A)
    bad = np.flatnonzero((size == 0) & (((q > 0) & np.isneginf(lower)) | ((q < 0) & np.isposinf(upper))))
    if bad.size == 0:
        return ""
    i = int(bad[0])
    others = f" (and {bad.size - 1} more such row(s))" if bad.size > 1 else ""
    side = "lower" if q[i] > 0 else "upper"
    return (f"; row {i} of A is zero and q[{i}] = {q[i]:.3g}: w_{i} = q_{i} never vanishes and z_{i} has no {side} "
            f"bound to rest at, the problem has no solution{others}")
