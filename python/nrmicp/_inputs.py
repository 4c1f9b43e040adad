"""Validation and conversion of user input. Nothing the user passed is ever mutated."""
from __future__ import annotations

import math
import os
import sys
import warnings

import numpy as np
import scipy.sparse as sp

__all__ = ["as_csr", "as_vector", "flat_vector", "as_constant", "as_diagonal", "as_float", "ConversionWarning"]


class ConversionWarning(sp.SparseEfficiencyWarning):
    """An input had to be copied/converted before nrmicp could use it (zero-copy needs
    canonical float64 CSR with int32/int64 indices and float64 C-contiguous vectors), or trimmed
    (a hierarchy's coarse levels without unknowns are dropped). The answer is the same."""


_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def _warn(msg: str, category: type = ConversionWarning) -> None:
    """warnings.warn attributed to the user's line: the first frame outside this package
    (however deep the call, e.g. solve() -> Solver() -> as_csr())."""
    frame, level = sys._getframe(0), 1
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE_DIR):
        frame, level = frame.f_back, level + 1
    warnings.warn(msg, category, stacklevel=level)


def as_csr(A, name: str = "A", *, square: bool = True, warn: bool = True) -> sp.csr_matrix:
    """Return A as canonical float64 CSR (sorted indices, no duplicates), int32 or int64
    indices. Canonical float64 CSR is returned as-is (zero-copy); anything else is copied
    with a ConversionWarning (silently with ``warn=False``). Raises TypeError/ValueError naming `name`."""
    note = _warn if warn else (lambda msg: None)
    canonical = None  # unknown
    if sp.issparse(A):
        if A.ndim != 2:   # (a 1-D sparse array: before its structure is read as rows and columns)
            raise ValueError(f"{name} must be 2-D, got shape {A.shape}")
        M, canonical = _check_structure(A, name)
        if M.format != "csr":
            note(f"{name}: converting {M.format.upper()} to CSR (copy); pass CSR to avoid it")
            M = M.tocsr()
            copied = True
        else:
            copied = False
    elif isinstance(A, np.ndarray) or hasattr(A, "__array__"):
        arr = np.asarray(A)
        if arr.ndim != 2:
            raise ValueError(f"{name} must be a 2-D matrix, got an array of shape {arr.shape}")
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
                or arr.dtype == bool):
            raise TypeError(f"{name} must have a real numeric dtype, got {arr.dtype}")
        note(f"{name}: a dense array was converted to CSR (copy); pass a scipy.sparse matrix")
        M = sp.csr_matrix(arr.astype(np.float64))
        copied = True
    else:
        raise TypeError(f"{name} must be a scipy.sparse matrix or a 2-D numpy array, got {type(A).__name__}")

    if M.ndim != 2:
        raise ValueError(f"{name} must be 2-D, got shape {M.shape}")
    if square and M.shape[0] != M.shape[1]:
        raise ValueError(f"{name} must be square, got shape {M.shape}")
    if np.iscomplexobj(M.data):
        raise TypeError(f"{name} must be real, got dtype {M.dtype}")
    if M.dtype != np.float64:
        if not (np.issubdtype(M.dtype, np.floating) or np.issubdtype(M.dtype, np.integer) or M.dtype == bool):
            raise TypeError(f"{name} must have a real numeric dtype, got {M.dtype}")
        if not copied:
            note(f"{name}: converting dtype {M.dtype} to float64 (copy)")
        M = M.astype(np.float64)
        copied = True
    if M.indices.dtype not in (np.int32, np.int64) or M.indptr.dtype != M.indices.dtype:
        idx = np.int64 if max(M.nnz, M.shape[0]) > np.iinfo(np.int32).max else np.int32
        if not copied:
            note(f"{name}: converting index arrays to {np.dtype(idx).name} (copy)")
        M = sp.csr_matrix((M.data, M.indices.astype(idx), M.indptr.astype(idx)), shape=M.shape)
        copied = True
        canonical = None
    if canonical is None:
        canonical = _is_canonical(M, name)
    if not canonical:
        if not copied:
            note(f"{name}: sorting indices / summing duplicate entries (copy)")
            M = M.copy()
        M.sum_duplicates()  # also sorts
    if not (M.data.flags.c_contiguous and M.indices.flags.c_contiguous and M.indptr.flags.c_contiguous):
        M = sp.csr_matrix((np.ascontiguousarray(M.data), np.ascontiguousarray(M.indices),
                           np.ascontiguousarray(M.indptr)), shape=M.shape)
    if not np.all(np.isfinite(M.data)):
        bad = np.flatnonzero(~np.isfinite(M.data))[0]
        row = int(np.searchsorted(M.indptr, bad, side="right") - 1)
        raise ValueError(f"{name} has a non-finite entry {M.data[bad]} at ({row}, {int(M.indices[bad])})")
    return M


def _index_arrays(M, name: str):
    """M.indptr and M.indices in one index type the core reads (int32 or int64, contiguous):
    the arrays themselves when they already are, else int64 copies."""
    ip, ix = M.indptr, M.indices
    for part, arr in (("indptr", ip), ("indices", ix)):
        if arr.ndim != 1 or arr.dtype.kind not in "iu":
            raise TypeError(f"{name}.{part} must be a 1-D integer array, got dtype {arr.dtype} and shape {arr.shape}")
    if ip.dtype == ix.dtype and ix.dtype in (np.int32, np.int64) and ip.flags.c_contiguous \
            and ix.flags.c_contiguous:
        return ip, ix
    return np.ascontiguousarray(ip, dtype=np.int64), np.ascontiguousarray(ix, dtype=np.int64)


def _check_structure(M, name: str):
    """Validate a sparse matrix's index structure before scipy or the core reads it (a bad
    indptr or an out-of-range index makes them read out of bounds: wrong results or a segfault).
    -> (M, canonical): canonical says whether a CSR matrix has sorted indices without
    duplicates (None for other formats). Raises ValueError naming `name`."""
    fmt = M.format
    if fmt in ("csr", "csc"):
        ip, ix = _index_arrays(M, name)
        outer, inner = M.shape if fmt == "csr" else M.shape[::-1]
        from . import _core
        canonical = _core.check_compressed(ip, ix, len(M.data), outer, inner, name)
        nnz = int(ip[-1])
        if nnz < len(M.indices) or nnz < len(M.data):  # unused storage at the end, as scipy's prune()
            M = type(M)((M.data[:nnz], M.indices[:nnz], M.indptr), shape=M.shape)
        return M, (canonical if fmt == "csr" else None)
    if fmt == "coo":
        row, col = M.row, M.col
        if not len(row) == len(col) == len(M.data):
            raise ValueError(f"{name} is not a valid sparse matrix: {name}.row, {name}.col and {name}.data "
                             f"differ in length ({len(row)}, {len(col)}, {len(M.data)})")
        for part, idx, dim in (("row", row, M.shape[0]), ("col", col, M.shape[1])):
            if len(idx) and (idx.min() < 0 or idx.max() >= dim):
                bad = int(np.flatnonzero((idx < 0) | (idx >= dim))[0])
                raise ValueError(f"{name} is not a valid sparse matrix: {name}.{part}[{bad}] = {idx[bad]} is "
                                 f"outside [0, {dim})")
        return M, None
    if hasattr(M, "check_format"):  # BSR: scipy's own full check
        try:
            M.check_format(full_check=True)
        except ValueError as exc:
            raise ValueError(f"{name} is not a valid sparse matrix: {exc}") from None
    return M, None


def _is_canonical(M: sp.csr_matrix, name: str) -> bool:
    # Checks sortedness and duplicates directly (scipy's cached flag may be stale), in the same
    # C++ pass as the structure.
    return _check_structure(M, name)[1]


#: What an infinite entry means where one is allowed: a bound that is not there (as_vector's `infinite`).
_INFINITE_BOUND = {-1: ("-inf", "a lower bound: z is free below there"),
                   1: ("+inf", "an upper bound: z has no upper bound there")}


def as_vector(v, n: int, name: str, infinite: int = 0) -> np.ndarray:
    """A float64 C-contiguous copy-free view of v when possible, checked for length and finiteness;
    `infinite` = -1 (+1) lets -inf (+inf) entries through: a bound that is absent there."""
    if sp.issparse(v):
        raise TypeError(f"{name} must be a dense 1-D array, got a sparse matrix")
    try:
        arr = np.asarray(v)
    except Exception as exc:  # pragma: no cover - numpy's own message is fine
        raise TypeError(f"{name} must be array-like: {exc}") from None
    # (timedelta64 is an integer subtype in numpy: a duration is no number here)
    if arr.dtype == object or arr.dtype.kind in "mM" or not (
            np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer) or arr.dtype == bool):
        raise TypeError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if np.ma.is_masked(v):
        raise TypeError(f"{name} is a masked array with masked entries: fill them (v.filled(...)) first")
    arr = np.ascontiguousarray(flat_vector(arr, n, name), dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        bad = ~np.isfinite(arr) if not infinite else ~(np.isfinite(arr) | (arr == infinite * np.inf))
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            allowed = f" ({name} may hold {_INFINITE_BOUND[infinite][0]}, {_INFINITE_BOUND[infinite][1]})" if infinite else ""
            raise ValueError(f"{name} has a non-finite entry {arr[i]} at index {i}{allowed}")
    return arr


def flat_vector(arr: np.ndarray, n: int, name: str) -> np.ndarray:
    """The one shape rule for every vector nrmicp reads or ζ returns: shape (n,), or a column (n, 1)
    or row (1, n) as MATLAB-style code passes them, -> arr as shape (n,) (a view); ValueError naming
    `name` otherwise."""
    shape, accepted = arr.shape, f"shape ({n},) or a column ({n}, 1)"
    if arr.ndim == 2 and 1 in shape:
        arr = arr.reshape(-1)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D of length {n} ({accepted}), got shape {shape}")
    if arr.shape[0] != n:
        raise ValueError(f"{name} must have length n = {n} ({accepted}), got shape {shape}")
    return arr


def as_float(v) -> float:
    """float(v) of a real number, ±inf where a Python int is beyond float's range (float() raises)."""
    try:
        return float(v)
    except OverflowError:
        return math.inf if v > 0 else -math.inf


def as_constant(value, n: int, name: str, infinite: int = 0) -> np.ndarray:
    """A real scalar (broadcast to length n; a 0-d array counts as one) or a length-n vector
    -> float64 vector, finite (but for the infinity `infinite` lets through: as_vector). Raises
    TypeError/ValueError naming `name`."""
    if np.isscalar(value) or (isinstance(value, np.ndarray) and value.ndim == 0):
        v = value[()] if isinstance(value, np.ndarray) else value
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise TypeError(f"{name} must be a real number or a length-{n} vector, got {value!r}")
        f = as_float(v)
        if not (math.isfinite(f) or (infinite and f == infinite * math.inf)):
            allowed = f" or {_INFINITE_BOUND[infinite][0]} ({_INFINITE_BOUND[infinite][1]})" if infinite else ""
            raise ValueError(f"{name} must be finite{allowed}, got {value!r}")
        return np.full(n, f)
    return as_vector(value, n, name, infinite)


class WholeRows:
    """How nrmicp.solve reads the parts of ζ and ``upper`` (a matrix B, a constant or vector): whole, n rows.
    nrmicp.distributed reads them as this rank's rows of PETSc objects through the same two methods."""

    def __init__(self, n: int):
        self.n = n

    def matrix(self, B, name: str) -> sp.csr_matrix:
        B = as_csr(B, name)
        if B.shape != (self.n, self.n):
            raise ValueError(f"{name} must have shape ({self.n}, {self.n}), got {B.shape}")
        return B

    def vector(self, v, name: str, infinite: int = 0) -> np.ndarray:
        return as_constant(v, self.n, name, infinite)


def as_diagonal(v, n: int, name: str, *, positive: bool) -> np.ndarray | None:
    """None, a scalar (times I) or a length-n vector -> float64 vector (or None), checked > 0
    (`positive`) or >= 0."""
    if v is None:
        return None
    arr = as_constant(v, n, name)
    bad = (arr <= 0) if positive else (arr < 0)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name}[{i}] = {arr[i]}; {name} must be finite and {'> 0' if positive else '>= 0'}")
    return arr
