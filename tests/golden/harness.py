"""The golden-master harness: record every observable of a list of solves into a pickle, and
diff two recordings. A developer's regression check for refactorings that must change nothing
(bit for bit), run on the old build and the new one: not a CI test (it compares the code with
its own earlier output). The case lists are tests/golden/newton.py and tests/golden/family.py.

    make golden GOLDEN=before      # on the old build: before.newton.pkl, before.family.pkl
    make golden GOLDEN=after       # on the new build
    make golden-diff BEFORE=before GOLDEN=after
"""
import os
import pickle
import sys
import warnings

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))  # tests/

FIELDS = ("z", "w", "nit", "iterations", "residual", "status", "message", "success", "linear_solves",
          "fallback_sweeps", "outer_iterations", "level_steps", "path", "inner", "polished", "counters")


def fields(res):
    """Every observable of a result but its timings."""
    d = {}
    for k in FIELDS:
        if hasattr(res, k):
            v = getattr(res, k)
            d[k] = np.array(v) if isinstance(v, np.ndarray) else (str(v) if k == "status" else v)
    h = getattr(res, "history", None)
    if h is not None:
        d["history"] = {k: (np.array(v) if k != "seconds" else len(v)) for k, v in h.items()}
    return d


def run(fn):
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return fields(fn())
    except Exception as exc:
        return {"exception": f"{type(exc).__name__}: {exc}"}


def diff(a, b, path=""):
    out = []
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append(f"{path}/{k}: missing on one side")
            else:
                out += diff(a[k], b[k], f"{path}/{k}")
        return out
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        if a.shape != b.shape or not np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
            same = a.shape == b.shape and a.dtype.kind == "f"
            out.append(f"{path}: arrays differ" + (f" max {np.nanmax(np.abs(a - b)):.3g}" if same
                                                   else f" {a.shape} vs {b.shape}"))
        return out
    if isinstance(a, float) and isinstance(b, float) and np.isnan(a) and np.isnan(b):
        return out
    if a != b:
        out.append(f"{path}: {a!r} != {b!r}")
    return out


def diff_files(before, after) -> int:
    A = pickle.load(open(before, "rb"))
    B = pickle.load(open(after, "rb"))
    nd = 0
    for k in A:
        d = diff(A[k], B.get(k, {}))
        if d:
            nd += 1
            print(k, d[:6])
    print(f"{before} vs {after}: {len(A)} solves compared, {nd} differ; {len(set(B) - set(A))} only in second")
    return nd


def main(cases):
    """`script out.pkl` records `cases()`; `script --diff before.pkl after.pkl` compares."""
    if sys.argv[1] == "--diff":
        sys.exit(1 if diff_files(sys.argv[2], sys.argv[3]) else 0)
    out = {}
    for name, fn in cases():
        if name in out:
            raise KeyError(f"duplicate case name {name}")
        out[name] = run(fn)
    pickle.dump(out, open(sys.argv[1], "wb"))
    ex = sum("exception" in v for v in out.values())
    print(sys.argv[1], len(out), "solves,", ex, "exceptions")


if __name__ == "__main__":
    main(None)
