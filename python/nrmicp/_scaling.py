"""Diagonal scaling (equilibration) of ICP(q, A, ζ), and the map back to the original variables.

With positive diagonals D_r (rows) and D_c (columns), ICP(q, A, ζ) in z is equivalent to

    ICP(D_r q, D_r A D_c, ζ')  in y,   z = D_c y,   ζ'(y) = D_c⁻¹ ζ(D_c y):

w' = D_r (A z + q) = D_r w and g' = y − ζ'(y) = D_c⁻¹ (z − ζ(z)) = D_c⁻¹ g, so w' ≥ 0, g' ≥ 0 and
g'ᵀw' = 0 hold exactly when they hold for (w, g) (positive diagonal factors keep signs and zeros).
The residuals differ, though: Res'(y) = ‖min(D_r w, D_c⁻¹ g)‖₂ is not Res(z), so the caller
(nrmicp.Solver) always re-measures Res in the original variables before declaring success.

Every factor is a power of two, so D_r A D_c, D_r q, z = D_c y are computed without rounding
(barring over/underflow) and scaling adds no error of its own.

kinds:
  'units' D_r = σI, D_c = I with σ = units_factor(A): what the default stopping rule iterates on (nrmicp's
          default tol/rtol, README "What you get back"), one number so that A keeps its symmetry; the rule
          measures each row in its own units (units_weights).
  'rows'  D_r = 1/max_j |a_ij| (rows that are entirely zero keep factor 1), D_c = I; ζ unchanged.
  'both'  Ruiz equilibration: a few sweeps of D_r ← D_r/√(row max), D_c ← D_c/√(column max) of
          the current scaled matrix, until every nonzero row and column has max |entry| in
          [1/2, 2] (at most 20 sweeps).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

SCALINGS = ("rows", "both")


def _pow2(v: np.ndarray) -> np.ndarray:
    """Round positive factors to the nearest power of two (exact scaling)."""
    return np.exp2(np.round(np.log2(v)))


def units_factor(A: sp.csr_matrix) -> float:
    """σ = the power of two nearest 1/(geometric mean of the nonzero |a_ii|) (without a nonzero
    diagonal entry: of the nonzero |a_ij|; 1 for A = 0): the size of A's entries in the units the user
    chose. A mean of logarithms, so that a few penalty or identity rows (Dirichlet values) hardly
    move it, and the distributed engine forms it from two global sums (sigma_from_logs)."""
    d = np.abs(A.diagonal())
    d = d[d > 0]
    if d.size == 0:
        d = np.abs(A.data[A.data != 0])
    return sigma_from_logs(float(np.sum(np.log2(d))), d.size)


def units_weights(A: sp.csr_matrix, sigma: float) -> np.ndarray:
    """The default rule's row weights d: 1/max_j |a_ij| of each row as a power of two (σ for a row of zeros), so
    that d_i w_i is row i's residual in the units of z whatever that row's units (σ alone is one number: a row
    far below A's typical size went unmeasured)."""
    return weights_of_rows(_row_max(A), sigma)


def weights_of_rows(row_max: np.ndarray, none: float) -> np.ndarray:
    """1/r_i as a power of two within float's range for each row size r_i = max_j |a_ij| (`none` for a row of
    zeros): units_weights from the row sizes alone (nrmicp.distributed's, PETSc's MatGetRowMaxAbs)."""
    d = np.full(len(row_max), none)
    nz = (row_max > 0) & np.isfinite(row_max)
    d[nz] = np.clip(_pow2(1.0 / row_max[nz]), 2.0 ** -1022, 2.0 ** 1023)
    return d


def row_spread(A: sp.csr_matrix) -> float:
    """The largest over the smallest nonzero row size max_j |a_ij| (1 for fewer than two such rows)."""
    r = _row_max(A)
    r = r[(r > 0) & np.isfinite(r)]
    return float(r.max() / r.min()) if r.size > 1 else 1.0


def sigma_from_logs(sum_log2: float, count: int) -> float:
    """The default rule's σ from Σ log2 |a_ii| over `count` entries: 2^-round(mean), 1 for none."""
    if count == 0:
        return 1.0
    e = -round(sum_log2 / count)
    return float(np.exp2(min(max(e, -1022), 1023)))


def _row_max(M: sp.csr_matrix) -> np.ndarray:
    return np.asarray(abs(M).max(axis=1).todense()).ravel()


def _col_max(M: sp.csr_matrix) -> np.ndarray:
    return np.asarray(abs(M).max(axis=0).todense()).ravel()


def equilibrate(A: sp.csr_matrix, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """-> (d_r, d_c), positive powers of two, for kind 'units', 'rows' or 'both'. A is not modified."""
    n = A.shape[0]
    if kind == "units":
        return np.full(n, units_factor(A)), np.ones(n)
    if kind == "rows":
        return weights_of_rows(_row_max(A), 1.0), np.ones(n)
    if kind != "both":  # pragma: no cover - validated by the caller
        raise ValueError(f"unknown scaling {kind!r}")
    dr = np.ones(n)
    dc = np.ones(n)
    M = A
    for _ in range(20):
        r = _row_max(M)
        c = _col_max(M)
        rnz, cnz = r > 0, c > 0
        done = (np.all((r[rnz] >= 0.5) & (r[rnz] <= 2.0)) and np.all((c[cnz] >= 0.5) & (c[cnz] <= 2.0)))
        if done:
            break
        fr = np.ones(n)
        fc = np.ones(n)
        fr[rnz] = _pow2(1.0 / np.sqrt(r[rnz]))
        fc[cnz] = _pow2(1.0 / np.sqrt(c[cnz]))
        if np.all(fr == 1.0) and np.all(fc == 1.0):
            break
        dr *= fr
        dc *= fc
        M = scale_matrix(A, dr, dc)
    return dr, dc


def scale_matrix(A: sp.csr_matrix, dr: np.ndarray, dc: np.ndarray) -> sp.csr_matrix:
    """D_r A D_c as a new canonical float64 CSR with A's index dtype (A is not modified)."""
    if dr[0] == dr[-1] and np.all(dc == 1.0) and np.all(dr == dr[0]):   # 'units': one factor
        return sp.csr_matrix((A.data * dr[0], A.indices, A.indptr), shape=A.shape, copy=False)  # pattern shared
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    data = A.data * dr[rows] * dc[A.indices]
    return sp.csr_matrix((data, A.indices.copy(), A.indptr.copy()), shape=A.shape)


class ScaledCallable:
    """ζ'(y) = D_c⁻¹ ζ(D_c y) for a user callable ζ given as a CheckedZeta (nrmicp._zeta), which
    hands ζ a read-only copy and checks its output; ζ's exceptions pass through unchanged."""

    def __init__(self, zeta, dc: np.ndarray):
        self.zeta = zeta
        self.dc = dc
        self.overflowed = False  # set when D_c y overflowed: the iterate ran away, ζ did not fail

    def __call__(self, y):
        z = self.dc * y
        if not np.all(np.isfinite(z)):  # finite in the scaled variables, not in the user's
            self.overflowed = True
            return np.full_like(y, np.nan)
        return self.zeta(z) / self.dc
