"""Copies of what a test passes to nrmicp, to check afterwards that nothing was modified
(shared by the bad-input and fuzz tests)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def snapshot(*objs):
    out = []
    for o in objs:
        if sp.issparse(o):
            names = ("data", "row", "col") if o.format == "coo" else ("data", "indices", "indptr")
            out.append(tuple((name, getattr(o, name).copy()) for name in names))
        elif isinstance(o, np.ndarray):
            out.append(o.copy())
        else:
            out.append(None)
    return out


def assert_unchanged(before, objs):
    for b, o in zip(before, objs):
        if b is None:
            continue
        if isinstance(b, tuple):
            for name, arr in b:
                np.testing.assert_array_equal(arr, getattr(o, name))
                assert getattr(o, name).dtype == arr.dtype
        else:
            np.testing.assert_array_equal(b, o)
