"""Validation and conversion of user input. Nothing the user passed is ever mutated."""
from __future__ import annotations

import os
import sys
import warnings

import numpy as np
import scipy.sparse as sp

__all__ = ["as_csr", "as_vector", "as_constant", "as_diagonal", "ConversionWarning"]


class ConversionWarning(sp.SparseEfficiencyWarning):
    """An input had to be copied/converted before nrmicp could use it (zero-copy needs
    canonical float64 CSR with int32/int64 indices and float64 C-contiguous vectors)."""


_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def _warn(msg: str, category: type = ConversionWarning) -> None:
    """warnings.warn attributed to the user's line: the first frame outside this package
    (however deep the call, e.g. solve() -> Solver() -> as_csr())."""
    frame, level = sys._getframe(0), 1
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE_DIR):
        frame, level = frame.f_back, level + 1
    warnings.warn(msg, category, stacklevel=level)


def as_csr(A, name: str = "A", *, square: bool = True) -> sp.csr_matrix:
    """Return A as canonical float64 CSR (sorted indices, no duplicates), int32 or int64
    indices. Canonical float64 CSR is returned as-is (zero-copy); anything else is copied
    with a ConversionWarning. Raises TypeError/ValueError naming `name`."""
    if sp.issparse(A):
        M = A
        if M.format != "csr":
            _warn(f"{name}: converting {M.format.upper()} to CSR (copy); pass CSR to avoid it")
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
        _warn(f"{name}: a dense array was converted to CSR (copy); pass a scipy.sparse matrix")
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
            _warn(f"{name}: converting dtype {M.dtype} to float64 (copy)")
        M = M.astype(np.float64)
        copied = True
    if M.indices.dtype not in (np.int32, np.int64) or M.indptr.dtype != M.indices.dtype:
        idx = np.int64 if max(M.nnz, M.shape[0]) > np.iinfo(np.int32).max else np.int32
        if not copied:
            _warn(f"{name}: converting index arrays to {np.dtype(idx).name} (copy)")
        M = sp.csr_matrix((M.data, M.indices.astype(idx), M.indptr.astype(idx)), shape=M.shape)
        copied = True
    if not _is_canonical(M):
        if not copied:
            _warn(f"{name}: sorting indices / summing duplicate entries (copy)")
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


def _is_canonical(M: sp.csr_matrix) -> bool:
    # Checks sortedness and duplicates directly (scipy's cached flag may be stale); one pass in
    # C++ for the index types the core takes (the numpy version below costs ~13 ms at nnz = 5e6).
    if M.nnz == 0:
        return True
    if M.indices.dtype == M.indptr.dtype and M.indices.dtype in (np.int32, np.int64) \
            and M.indices.flags.c_contiguous and M.indptr.flags.c_contiguous:
        from . import _core
        return bool(_core.csr_is_canonical(M.indptr, M.indices))
    d = np.diff(M.indices)
    row_starts = M.indptr[1:-1]
    mask = np.ones(d.shape, dtype=bool)
    # positions where a new row starts are allowed to decrease
    starts = row_starts[(row_starts > 0) & (row_starts < M.nnz)] - 1
    mask[starts] = False
    return bool(np.all(d[mask] > 0))


def as_vector(v, n: int, name: str) -> np.ndarray:
    """A float64 C-contiguous copy-free view of v when possible, checked for length and finiteness."""
    if sp.issparse(v):
        raise TypeError(f"{name} must be a dense 1-D array, got a sparse matrix")
    try:
        arr = np.asarray(v)
    except Exception as exc:  # pragma: no cover - numpy's own message is fine
        raise TypeError(f"{name} must be array-like: {exc}") from None
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
                                   or arr.dtype == bool):
        raise TypeError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
    if arr.ndim == 2 and 1 in arr.shape:
        arr = arr.reshape(-1)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D of length {n}, got shape {arr.shape}")
    if arr.shape[0] != n:
        raise ValueError(f"{name} must have length n = {n}, got {arr.shape[0]}")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        i = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ValueError(f"{name} has a non-finite entry {arr[i]} at index {i}")
    return arr


def as_constant(value, n: int, name: str) -> np.ndarray:
    """A real scalar (broadcast to length n; a 0-d array counts as one) or a length-n vector
    -> float64 vector, finite. Raises TypeError/ValueError naming `name`."""
    if np.isscalar(value) or (isinstance(value, np.ndarray) and value.ndim == 0):
        v = value[()] if isinstance(value, np.ndarray) else value
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise TypeError(f"{name} must be a real number or a length-{n} vector, got {value!r}")
        if not np.isfinite(v):
            raise ValueError(f"{name} must be finite, got {value!r}")
        return np.full(n, float(v))
    return as_vector(value, n, name)


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
