"""A user's ζ callable as nrmicp calls it: on a read-only copy of z (never an array nrmicp
returns), with its output checked. Every message about ζ's output names zeta.

The C++ core calls ``CheckedZeta.fn`` itself on its own read-only buffer and hands anything that
is not already a float64 vector of length n to :meth:`CheckedZeta.output`, and a ValueError to
:meth:`CheckedZeta.read_only_message`: the rules and their wording live here only.
"""
from __future__ import annotations

import warnings

import numpy as np

from ._inputs import ConversionWarning, flat_vector

#: numpy's messages for a write into a read-only array (item assignment; a ufunc's out=, e.g. z += 1).
_NUMPY_READ_ONLY = ("assignment destination is read-only", "output array is read-only")


def read_only_copy(z) -> np.ndarray:
    v = np.array(z, dtype=np.float64, copy=True)
    v.flags.writeable = False
    return v


class CheckedZeta:
    """ζ for one solve. ``warned``: a dtype conversion was already reported in this solve."""

    #: How messages name the call.
    what = "zeta(z)"
    #: Its values at a finite z must be finite: NaN or ±inf raises ValueError at the call that returned it, in
    #: every member (the core hands a non-finite result to :meth:`output`); an upper bound's +inf is no bound.
    finite = True

    def __init__(self, fn, n: int):
        self.fn = fn
        self.n = n
        self.warned = False

    def __call__(self, z) -> np.ndarray:
        v = read_only_copy(z)
        try:
            r = self.fn(v)
        except ValueError as exc:
            msg = self.read_only_message(exc)
            if msg is None:
                raise
            raise ValueError(msg) from exc
        return self.output(r, finite_input=bool(np.all(np.isfinite(v))))

    def read_only_message(self, exc) -> str | None:
        """The message naming zeta for numpy's bare 'assignment destination is read-only', else None
        (every other exception of ζ reaches the caller unchanged)."""
        if str(exc) not in _NUMPY_READ_ONLY:
            return None
        arg = self.what[self.what.rindex("(") + 1:-1]
        return (f"{self.what} tried to modify its input {arg}, which is read-only (nrmicp reuses it); "
                f"compute on a copy ({arg} = {arg}.copy()) or return a new array ({exc})")

    def output(self, r, finite_input: bool = True) -> np.ndarray:
        """ζ's return value as a C-contiguous float64 vector of length n (shapes as every vector input:
        _inputs.flat_vector); TypeError/ValueError naming zeta otherwise. Other real dtypes are
        converted, with one ConversionWarning per solve."""
        n = self.n
        expected = f"a real floating-point array of shape ({n},)"
        if r is None or isinstance(r, (str, bytes)):
            raise TypeError(f"{self.what} must return {expected}, got {type(r).__name__}")
        try:
            arr = np.asarray(r)
        except Exception:  # ragged lists and the like
            raise TypeError(f"{self.what} must return {expected}, got {type(r).__name__}") from None
        if arr.dtype.kind not in "fiu":
            raise TypeError(f"{self.what} returned {'an array' if isinstance(r, np.ndarray) else type(r).__name__} "
                            f"of dtype {arr.dtype}; expected {expected}")
        arr = flat_vector(arr, n, f"{self.what}'s return value")
        if arr.dtype != np.float64 or not arr.dtype.isnative:
            if not self.warned:
                self.warned = True
                warnings.warn(f"{self.what} returned dtype {arr.dtype}; converting it to float64 at every call "
                              "(a float32 result also limits the accuracy Res can reach): return float64",
                              ConversionWarning, stacklevel=2)
        out = np.ascontiguousarray(arr, dtype=np.float64)
        # (at a non-finite z, or one whose scaling overflowed, the iteration ran away: the core's to judge)
        if self.finite and finite_input and not getattr(self.fn, "overflowed", False):
            bad = np.flatnonzero(~np.isfinite(out))
            if bad.size:
                raise ValueError(f"{self.what} returned non-finite values (NaN or Inf): {self.what}[{int(bad[0])}] = "
                                 f"{out[bad[0]]}")
        return out
