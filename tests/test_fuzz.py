"""Fuzz: random problems and options through the Python API (magnitudes 1e-300…1e300, NaN/Inf
inputs, every method including 'newton' with its hierarchy=, polish=, zeta_jacobian= and bounds —
upper= and -inf in zeta), against an oracle that does not trust the library:

- no crash and no hang (every solve is bounded by maxiter);
- success=True only when Res(z), recomputed here in numpy from the original data and the test's
  own ζ (with bounds: ‖mid(z − lower, z − upper, w)‖₂), is below tol (up to rounding in computing
  Res itself);
- z finite for finite input, and within the bounds (up to an ulp of them); the caller's arrays
  unmodified;
- corrupt input -> TypeError/ValueError whose message names the corrupted argument (a raising
  zeta_jacobian: its own exception, unchanged).

What is fuzzed is enumerated, not drawn: every listed corruption, and every method x ζ kind (x
hierarchy for 'newton'), is a test of its own; Hypothesis draws only a seed, from which the sizes
(n up to 300), the matrix and the values come (Hypothesis's preference for simple draws made most
cases n <= 2 before). test_fuzz_coverage asserts what the slice reached: every corruption
rejected, a number of oracle-checked converged solves per method, large n among them.

CI runs a deterministic slice; NRMICP_FUZZ_EXAMPLES=N runs about N random cases, e.g.
``NRMICP_FUZZ_EXAMPLES=5000 python -m pytest -q tests/test_fuzz.py``.
"""
from __future__ import annotations

import collections
import os
import warnings

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import nrmicp
from snapshots import assert_unchanged, snapshot

METHODS = ["nrm", "nrmm", "nrmaor", "nrmsor", "nrmgs", "nrmj", "mms", "two_sweep", "newton"]
EPS = np.finfo(float).eps

#: (argument named in the error, how the input is corrupted)
CORRUPTIONS = [
    ("A", "index out of range"), ("A", "negative index"), ("A", "indptr beyond nnz"), ("A", "indptr not from 0"),
    ("A", "nan entry"), ("A", "complex"), ("A", "not square"), ("q", "nan"), ("q", "wrong length"),
    ("q", "strings"), ("x0", "inf"), ("x0", "wrong length"), ("zeta", "wrong length"), ("zeta", "nan constant"),
    ("zeta", "returns None"), ("zeta", "returns strings"), ("zeta", "returns complex"),
    ("zeta", "returns wrong shape"), ("zeta", "writes into z"), ("zeta.B", "index out of range"),
    ("omega1", "negative"), ("omega2", "zero"), ("phi", "negative"), ("maxiter", "beyond int32"),
    ("maxiter", "negative"), ("tol", "nan"), ("method", "unknown"), ("gamma", "string"),
    ("q", "inf"), ("omega2", "inf"), ("zeta", "inf constant"), ("omega2", "subnormal"), ("polish", "string"),
    ("hierarchy", "rows not n"), ("hierarchy", "not coarser"), ("hierarchy", "second level mismatched"),
    ("hierarchy", "nan entry"), ("hierarchy", "inf entry"), ("hierarchy", "a string"), ("hierarchy", "not a list"),
    ("hierarchy", "list of strings"), ("hierarchy", "for a stationary method"), ("hierarchy", "built on another A"),
    ("zeta_jacobian", "wrong shape"), ("zeta_jacobian", "returns a string"), ("zeta_jacobian", "not callable"),
    ("zeta_jacobian", "raises"), ("zeta_jacobian", "for a stationary method"),
    ("upper", "nan"), ("upper", "-inf"), ("upper", "wrong length"), ("upper", "below lower"), ("upper", "complex"),
    ("upper", "callable returns nan"), ("upper", "callable returns -inf"), ("upper", "Affine of wrong shape"),
    ("upper", "implicit on a stationary method"), ("upper", "with an implicit zeta on a stationary method"),
    ("zeta", "+inf lower with upper"), ("zeta_jacobian", "with bounds"),
    ("zeta_jacobian", "operator of wrong shape"), ("zeta_jacobian", "complex operator"),
    ("zeta_jacobian", "matvec of wrong length"), ("zeta_jacobian", "matvec returns nan"),
]

#: The exception a raising zeta_jacobian throws: it must reach the caller unchanged.
class JacobianError(Exception):
    pass


def random_matrix(rng, n, kind, scale):
    density = rng.uniform(0.1, 1.0)
    R = sp.random(n, n, density=density, random_state=rng, data_rvs=lambda k: rng.standard_normal(k))
    R = sp.csr_matrix(R)
    if kind == "hplus":  # strictly diagonally dominant: every method converges
        R.setdiag(0)
        R.eliminate_zeros()
        R = R + sp.diags(abs(R).sum(axis=1).A1 + rng.uniform(0.5, 2.0, n))
    elif kind == "posdiag":  # positive diagonal, otherwise anything
        R.setdiag(rng.uniform(0.1, 3.0, n))
    elif kind == "singular":
        R = sp.csr_matrix(R.toarray() * (rng.uniform(size=(1, n)) > 0.3))  # some empty columns
    if kind != "singular" and rng.integers(3) == 0:
        # some rows a lone diagonal, columns kept (Dirichlet rows as FE codes leave them; the
        # Newton member solves them in closed form: python/nrmicp/_decoupled.py)
        lone = rng.uniform(size=n) < rng.uniform(0.1, 0.9)
        R = sp.lil_matrix(R)
        for i in np.flatnonzero(lone):
            R.rows[i], R.data[i] = [i], [float(rng.uniform(0.5, 2.0))]
        R = sp.csr_matrix(R)
    R = sp.csr_matrix(R * scale)
    R.sort_indices()
    return R


STATIONARY = [m for m in METHODS if m != "newton"]
ZETA_KINDS = ["none", "constant", "affine", "callable", "callable_f32", "callable_column"]
CALLABLES = ("callable", "callable_f32", "callable_column")
#: The formats a valid zeta_jacobian returns J in (sp.diags' DIA warned at every Newton step;
#: 'operator': a scipy LinearOperator, the matrix-free Newton step).
JACOBIAN_FORMATS = ["csr", "dia", "coo", "csc", "dense", "operator"]
#: Wrong Jacobians of those callables (valid input: a solve may give them up for the outer fixed
#: point, path 'newton+outer', and must say so; a success is still checked by the oracle).
WRONG_JACOBIANS = {"negated": -1.0, "10x": 10.0, "zero": 0.0}
HIERARCHIES = [None, "auto", "amg", "list", "dense list", "Hierarchy"]
#: Every (method, ζ kind, hierarchy) the valid cases run; the hierarchy is 'newton''s argument.
#: Bounds (issue 36), the Newton member's only: 'upper' (ζ None, an upper bound), 'box' (a constant
#: ζ with -inf entries for rows free below, and an upper bound or none): random_bounds; 'implicit
#: upper' (box's ζ and an upper bound u(z), an Affine or a callable): random_implicit_upper.
BOUNDED_KINDS = ["upper", "box", "implicit upper"]
COMBOS = ([(m, z, None) for m in STATIONARY for z in ZETA_KINDS]
          + [("newton", z, h) for z in ZETA_KINDS + BOUNDED_KINDS for h in HIERARCHIES])

_LONG_RUN = int(os.environ.get("NRMICP_FUZZ_EXAMPLES", "0"))
#: Examples per valid combination and per corruption in CI (deterministic); the long run spreads
#: NRMICP_FUZZ_EXAMPLES over all of them, with fresh random seeds.
VALID_EXAMPLES, CORRUPT_EXAMPLES = 6, 2


def _fuzz_settings(per_test):
    share = max(per_test, -(-_LONG_RUN // (len(COMBOS) + len(CORRUPTIONS))))  # never less than CI's slice
    return settings(max_examples=share, deadline=None, derandomize=not _LONG_RUN, database=None,
                    suppress_health_check=list(HealthCheck))


#: What the fuzz slice reached in this session (checked by test_fuzz_coverage).
REACHED = {"combos": collections.Counter(), "drawn": collections.Counter(), "rejected": collections.Counter(),
           "gave_up": collections.Counter(), "bounded": collections.Counter(),
           "converged": collections.Counter(), "n_converged": collections.defaultdict(list)}


def _size(rng, small_only=False):
    """n: about a third tiny (1..12, the edge cases), the rest 13..300."""
    if small_only or rng.uniform() < 0.3:
        return int(rng.integers(1, 13))
    return int(rng.integers(13, 301))


def _common_options(rng, method, n, scale, corrupt):
    opts = dict(method=method, tol=float(rng.choice([1e-8, 1e-12, 1e-3])) * scale,
                z_update=str(rng.choice(["auto", "explicit", "solve"])),
                accelerate=str(rng.choice(["none", "anderson"])),
                scale=[False, "rows", "both"][rng.integers(3)],
                inner=str(rng.choice(["auto", "auto", "umfpack", "cholmod", "eigen_lu", "eigen_llt"])),
                stall_iterations=int(rng.choice([5, 100])), polish=bool(rng.integers(2)))
    if corrupt or not nrmicp.backends().get(opts["inner"], True):
        opts["inner"] = "auto"  # (a forced Cholesky of a nonsymmetric A would fail before the corruption is seen)
    if method in ("nrmaor", "nrmsor") and rng.integers(2):
        opts["alpha"] = float(rng.uniform(0.5, 1.5))
    if method == "two_sweep" and rng.integers(2):
        opts["theta"] = float(rng.uniform(0.3, 1.5))
    if method not in ("mms", "two_sweep") and rng.integers(2):
        opts["omega1"] = rng.uniform(0.5, 2.0, n)
        opts["phi"] = rng.uniform(0.0, 1.0, n)
    return opts


def build_case(seed, method, zkind, hierarchy=None, corrupt=None):
    """A case of the given method, ζ kind and hierarchy, everything else from `seed`: a corrupted
    case is otherwise valid (an H+ matrix), so that the error can only be about the corruption."""
    rng = np.random.default_rng(seed)
    newton = method == "newton"
    n = _size(rng, small_only=corrupt is not None and rng.uniform() < 0.5)
    # half of the valid cases tame (H+ matrix, the method's defaults, maxiter 300): the ones that
    # must converge, so that the oracle checks results of every method
    tame = not corrupt and rng.uniform() < 0.5
    if corrupt or tame:
        kind = "hplus"
    elif newton:
        kind = str(rng.choice(["hplus", "hplus", "hplus", "posdiag"]))
    else:
        kind = str(rng.choice(["hplus", "hplus", "hplus", "posdiag", "random", "singular"]))
    scale = 10.0 ** float(rng.choice([0, 0, 0, -8, 8, -100, 100, -200, 200, -300, 300]))
    A = random_matrix(rng, n, kind, scale)
    if rng.integers(2):
        A = sp.csr_matrix((A.data, A.indices.astype(np.int64), A.indptr.astype(np.int64)), shape=A.shape)
    q = rng.uniform(-1, 1, n) * scale
    c = rng.uniform(-1, 1, n)
    B = sp.csr_matrix(0.1 * sp.random(n, n, density=min(1.0, 3.0 / n), random_state=rng))
    opts = _common_options(rng, method, n, scale, corrupt)
    # Newton: enough iterations to converge (maxiter 0 and 1 are the stationary members' edge cases)
    opts["maxiter"] = int(rng.choice([50, 100, 300] if newton else [0, 1, 50, 300, 300]))
    if tame:
        for k in ("omega1", "phi", "alpha", "theta"):
            opts.pop(k, None)
        opts.update(maxiter=300, inner="auto", tol=float(rng.choice([1e-8, 1e-12])) * scale)
    elif rng.integers(2):
        opts["omega2"] = np.abs(A.diagonal()) + scale * rng.uniform(0.1, 1.0, n)
    x0 = rng.uniform(0, 1, n) if rng.integers(2) else None
    jacobian = None
    # the input paths of issue 38 from a stream of their own: the other draws of a seed stay as they were
    extra = np.random.default_rng([seed, 38])
    if newton:
        newton_options(opts)
        if hierarchy == "Hierarchy":   # the object, built on this A (its operators formed once)
            opts["hierarchy"] = nrmicp.Hierarchy(A, random_hierarchy(rng, n))
        elif hierarchy in ("list", "dense list"):
            opts["hierarchy"] = random_hierarchy(rng, n, dense=hierarchy == "dense list")
            if not corrupt and extra.uniform() < 0.3:   # empty coarsest levels: dropped with a warning
                rows = opts["hierarchy"][-1].shape[1] if opts["hierarchy"] else n
                opts["hierarchy"] += [sp.csr_matrix((rows, 0))] + [sp.csr_matrix((0, 0))] * int(extra.integers(2))
        else:
            opts["hierarchy"] = hierarchy
        if not corrupt and rng.integers(3) == 0:
            opts["inner"] = "cg"  # the iterative inner solve: CG or BiCGSTAB, by K's symmetry
        if zkind in CALLABLES and rng.integers(2):
            jacobian = str(extra.choice(JACOBIAN_FORMATS))
            wrong = np.random.default_rng([seed, 37])   # issue 37's draw, a stream of its own
            if not corrupt and wrong.uniform() < 0.3:
                jacobian = str(wrong.choice(list(WRONG_JACOBIANS)))
    upper = upper_ref = None
    if zkind in BOUNDED_KINDS:   # bounds (issue 36), from a stream of their own
        c, upper = random_bounds(np.random.default_rng([seed, 36]), n, c if zkind != "upper" else None)
    if zkind == "implicit upper":
        upper, upper_ref = random_implicit_upper(np.random.default_rng([seed, 36, 1]), n, c, upper)
    return dict(A=A, q=q, zkind=zkind, c=c, B=B, x0=x0, opts=opts, corrupt=corrupt, rng=rng, jacobian=jacobian,
                upper=upper, upper_ref=upper_ref)


def random_bounds(rng, n, c):
    """(the constant ζ c, with -inf entries for rows free below; upper): upper None, a number or a
    vector (+inf entries: no upper bound there; rows with upper = lower: fixed), never below c.
    c None: ζ None (lower 0) and an upper bound."""
    if c is not None:
        c = np.where(rng.uniform(size=n) < rng.uniform(0.05, 0.6), -np.inf, c)
    lower = np.zeros(n) if c is None else c
    finite = np.where(np.isfinite(lower), lower, rng.uniform(-1, 1, n))
    how = str(rng.choice(["none", "number", "vector", "vector"] if c is not None else ["number", "vector", "vector"]))
    if how == "none":
        return c, None
    if how == "number":
        return c, float(np.max(finite) + rng.uniform(0, 1)) if rng.uniform() < 0.8 else np.inf
    upper = finite + rng.uniform(0, 2, n) * rng.choice([0.1, 1.0, 10.0])
    upper[rng.uniform(size=n) < rng.uniform(0, 0.5)] = np.inf
    fixed = (rng.uniform(size=n) < 0.1) & np.isfinite(lower)
    upper[fixed] = lower[fixed]
    return c, upper


def random_implicit_upper(rng, n, c, upper):
    """(upper to pass, the test's own u) of the kind 'implicit upper': random_bounds' constant upper
    bound u0 (None: 1 above the finite lower bound c) moved with z, u(z) = u0 + Bz (an Affine) or
    u0 + 0.1 tanh(Bz) (a callable), B >= 0 sparse with ‖B‖∞ <= 0.3; +inf rows stay unbounded."""
    u0 = np.where(np.isfinite(c), c, 0.0) + 1.0 if upper is None else np.broadcast_to(upper, (n,)).astype(float)
    B = sp.csr_matrix(sp.random(n, n, density=min(1.0, 3.0 / n), random_state=rng))
    B = sp.csr_matrix(sp.diags(0.3 / np.maximum(B.sum(axis=1).A1, 1.0)) @ B)
    B.sort_indices()
    if rng.integers(2):
        return nrmicp.Affine(B, u0), lambda z: B @ z + u0
    f = lambda z: u0 + 0.1 * np.tanh(B @ z)  # noqa: E731
    return f, f


def corrupt_case(seed, corrupt):
    """A valid case of a method the corrupted argument belongs to (or, for '... on a stationary
    method', one it does not), then corrupted."""
    rng = np.random.default_rng(seed)
    name, how = corrupt
    if name in ("hierarchy", "zeta_jacobian", "upper") or how == "+inf lower with upper":
        stationary = how in ("for a stationary method", "with an implicit zeta on a stationary method",
                             "implicit on a stationary method")
        method = str(rng.choice(STATIONARY)) if stationary else "newton"
    elif name in ("omega1", "phi"):
        method = str(rng.choice(["nrm", "nrmgs", "nrmj", "nrmsor", "nrmaor"]))
    else:
        method = str(rng.choice(METHODS))
    zkind = str(rng.choice(["callable", "callable_f32"] if name == "zeta_jacobian" else ZETA_KINDS))
    if name == "upper" or how in ("with bounds", "+inf lower with upper"):   # bounds go with ζ none or constant only
        zkind = "constant" if name != "upper" else "affine" if how == "with an implicit zeta on a stationary method" else str(
            rng.choice(["none", "constant"]))
    hierarchy = str(rng.choice(["list", "list"] + ([] if name == "zeta_jacobian" else ["amg"])))
    case = build_case(int(rng.integers(2**32)), method, zkind, hierarchy if method == "newton" else None, corrupt)
    if name == "zeta_jacobian":
        case["opts"]["maxiter"] = 50  # (the Jacobian is asked for at the first Newton step)
        case["opts"]["tol"] = 1e-300
    return case


def newton_options(opts):
    """Drop the options of the stationary members that method 'newton' rejects (phi, accelerate,
    z_update): a valid newton case must fail only for what it is fuzzed with."""
    opts.pop("phi", None)
    opts["accelerate"] = "none"
    opts["z_update"] = "auto"


def random_hierarchy(rng, n, dense=False):
    """A valid random hierarchy: prolongations P_l of shape (n_l, n_{l+1}), n_{l+1} < n_l, each
    coarse unknown aggregating at least one fine one (positive weights, some extra entries)."""
    Ps, rows = [], n
    while rows > 1 and rng.uniform() < 0.7:
        cols = int(rng.integers(1, rows))
        agg = np.r_[np.arange(cols), rng.integers(0, cols, rows - cols)]
        rng.shuffle(agg)
        P = sp.csr_matrix((rng.uniform(0.5, 1.5, rows), (np.arange(rows), agg)), shape=(rows, cols))
        P = sp.csr_matrix(P + 0.1 * sp.random(rows, cols, density=0.2, random_state=rng))
        P.sort_indices()
        Ps.append(P.toarray() if dense else P)
        rows = cols
    return Ps


def make_zeta(zkind, c, B):
    """(zeta to pass, the test's own ζ for the oracle)."""
    if zkind == "none":
        return None, lambda z: np.zeros_like(z)
    if zkind in ("constant", "box", "implicit upper"):
        return c, lambda z: c
    if zkind == "upper":
        return None, lambda z: np.zeros_like(z)
    if zkind == "affine":
        return nrmicp.Affine(B, c), lambda z: B @ z + c
    if zkind == "callable":
        f = lambda z: 0.05 * np.sin(z) + c  # noqa: E731
        return f, f
    if zkind == "callable_column":   # a column (n, 1), as MATLAB-style code returns it
        f = lambda z: 0.05 * np.sin(z) + c  # noqa: E731
        return (lambda z: f(z)[:, None]), f
    f = lambda z: (0.05 * np.sin(z) + c).astype(np.float32)  # noqa: E731
    return f, lambda z: f(z).astype(np.float64)


def zeta_jacobian(z):
    """The Jacobian of the callables of make_zeta, 0.05 sin(z) + c."""
    return sp.diags(0.05 * np.cos(z), format="csr")


def jacobian_in(fmt):
    """zeta_jacobian returning J in the format `fmt` ('dense': a numpy array), or a wrong J (WRONG_JACOBIANS)."""
    if fmt in WRONG_JACOBIANS:
        return lambda z: WRONG_JACOBIANS[fmt] * zeta_jacobian(z)
    if fmt == "operator":
        return lambda z: spla.aslinearoperator(zeta_jacobian(z))
    return lambda z: zeta_jacobian(z).toarray() if fmt == "dense" else zeta_jacobian(z).asformat(fmt)


def apply_corruption(case, zeta):
    """Corrupt one argument in place of the case (copies: the snapshot is taken after)."""
    name, how = case["corrupt"]
    A, n, opts = case["A"], case["A"].shape[0], case["opts"]
    if name == "A":
        if how == "index out of range":
            A.indices[-1] = n + 3
        elif how == "negative index":
            A.indices[0] = -1
        elif how == "indptr beyond nnz":
            A.indptr[-1] = A.nnz + 5
        elif how == "indptr not from 0":
            A.indptr[0] = 1
        elif how == "nan entry":
            A.data[0] = np.nan
        elif how == "complex":
            case["A"] = A.astype(complex)
        elif how == "not square":
            case["A"] = sp.csr_matrix(sp.vstack([A, sp.csr_matrix((1, n))]))
    elif name == "q":
        case["q"] = {"nan": np.r_[case["q"][:-1], np.nan], "inf": np.r_[np.inf, case["q"][1:]],
                     "wrong length": np.ones(n + 1),
                     "strings": np.array(["1"] * n)}[how]
    elif name == "x0":
        case["x0"] = np.full(n, np.inf) if how == "inf" else np.zeros(n + 2)
    elif name == "zeta":
        zeta = {"wrong length": np.ones(n + 1), "nan constant": np.full(n, np.nan), "inf constant": np.full(n, np.inf),
                "returns None": lambda z: None, "returns strings": lambda z: ["0.5"] * n,
                "returns complex": lambda z: z + 1j, "returns wrong shape": lambda z: np.zeros((n, 2)),
                "writes into z": _writes_into_z, "+inf lower with upper": np.r_[np.inf, case["c"][1:]]}[how]
        if how == "+inf lower with upper":
            case["upper"] = np.full(n, 2.0)
    elif name == "zeta.B":
        B = case["B"].copy() if case["B"].nnz else sp.csr_matrix(np.eye(n))
        B.indices[0] = n + 7
        zeta = nrmicp.Affine(B, case["c"])
    elif name in ("omega1", "omega2", "phi"):
        opts[name] = np.full(n, {"negative": -1.0, "zero": 0.0, "inf": np.inf, "subnormal": 1e-310}[how])
        if name in ("omega1", "phi"):
            opts["method"] = "nrmgs"
            for k in ("hierarchy", "alpha", "theta"):
                opts.pop(k, None)
    elif name == "maxiter":
        opts["maxiter"] = 2**31 if how == "beyond int32" else -1
    elif name == "tol":
        opts["tol"] = np.nan
    elif name == "method":
        opts["method"] = "newton?"
    elif name == "gamma":
        opts["gamma"] = "1"
    elif name == "polish":
        opts["polish"] = "yes"
    elif name == "hierarchy":
        opts["hierarchy"] = _bad_hierarchy(how, n, case["rng"], case["A"])
    elif name == "upper":
        lower = case["c"] if case["zkind"] == "constant" else np.zeros(n)
        ok = lower + 1.0
        case["upper"] = {"nan": np.r_[ok[:-1], np.nan], "-inf": np.r_[-np.inf, ok[1:]], "wrong length": np.ones(n + 1),
                         "below lower": ok - 2.0, "complex": ok + 0j, "callable returns nan": lambda z: np.r_[ok[:-1], np.nan],
                         "callable returns -inf": lambda z: np.r_[-np.inf, ok[1:]],
                         "Affine of wrong shape": nrmicp.Affine(sp.eye(n + 1, format="csr"), ok),
                         "implicit on a stationary method": lambda z: ok,
                         "with an implicit zeta on a stationary method": ok}[how]
    elif how == "with bounds":   # a zeta_jacobian with ζ constant and an upper bound
        case["upper"] = case["c"] + 1.0
        case["jacobian"] = zeta_jacobian
    elif name == "zeta_jacobian":
        operator = spla.LinearOperator
        case["jacobian"] = {"wrong shape": lambda z: sp.eye(n + 1, format="csr"),
                            "returns a string": lambda z: "J", "not callable": sp.eye(n, format="csr"),
                            "raises": _raising_jacobian, "for a stationary method": zeta_jacobian,
                            "operator of wrong shape": lambda z: spla.aslinearoperator(sp.eye(n + 1)),
                            "complex operator": lambda z: operator((n, n), matvec=lambda v: (1 + 1j) * v, dtype=complex),
                            "matvec of wrong length": lambda z: operator((n, n), matvec=lambda v: np.zeros(n + 1), dtype=float),
                            "matvec returns nan": lambda z: operator((n, n), matvec=lambda v: np.full(n, np.nan), dtype=float)}[how]
    return zeta


def _bad_hierarchy(how, n, rng, A):
    good = random_hierarchy(rng, n) if n > 1 else []
    if how == "built on another A":
        return nrmicp.Hierarchy(sp.csr_matrix(A) * 2.0, good)
    P0 = good[0] if good else sp.csr_matrix(np.ones((n, max(n - 1, 1))))
    if how == "rows not n":
        return [sp.csr_matrix(np.ones((n + 1, 1)))]
    if how == "not coarser":
        return [sp.eye(n, format="csr")]
    if how == "second level mismatched":
        return [P0, sp.csr_matrix(np.ones((P0.shape[1] + 2, 1)))]
    if how in ("nan entry", "inf entry"):
        P = P0.copy()
        P.data[-1] = np.nan if how == "nan entry" else -np.inf
        return [P]
    if how == "for a stationary method":
        return good or [P0]
    return {"a string": "geometric", "not a list": sp.eye(n, format="csr"), "list of strings": ["P0"]}[how]


def _raising_jacobian(z):
    raise JacobianError("from the user's zeta_jacobian")


def _writes_into_z(z):
    z[0] = 0.0
    return np.zeros_like(z)


def oracle_residual(A, q, z, zeta_ref, upper=None):
    """Res(z) from the original data in numpy, and a bound on the rounding in computing it. With
    `upper` (a number or a vector, +inf: none; an implicit one's at z), Res = ‖mid(z − ζ, z − upper, w)‖₂
    = ‖min(z − ζ, max(z − upper, w))‖₂, but max(z − upper, ζ − z) where the bounds cross (ζ > upper:
    no z satisfies both); a -inf in ζ is a row free below (z − ζ = +inf)."""
    Ad = A.toarray()
    with np.errstate(over="ignore", invalid="ignore"):  # an overflowing Az + q is Res = inf
        w = Ad @ z + q
        zz = zeta_ref(z)
        g = z - zz
        if upper is None:
            terms = np.minimum(w, g)
        else:
            terms = np.where(zz > upper, np.maximum(z - upper, zz - z), np.minimum(g, np.maximum(z - upper, w)))
        res = stable_norm(terms)
        slack = 64 * EPS * stable_norm(np.abs(Ad) @ np.abs(z) + np.abs(q) + np.abs(z) + finite_abs(zz) + finite_abs(upper))
    return res, slack


def finite_abs(v):
    """|v| where v is finite, 0 elsewhere (an infinite bound adds no rounding); None: 0."""
    if v is None:
        return 0.0
    v = np.asarray(v, dtype=float)
    return np.where(np.isfinite(v), np.abs(v), 0.0)


def assert_in_bounds(z, lower, upper, res):
    """lower <= z <= upper up to Res(z) (a row outside its box by d has a term of Res at least d in
    size: a loose tol lets an iterate outside through, as the LCP's z >= 0) and two ulps of the
    larger finite bound of a row (the core solves in z − lower:
    test_bounds.test_a_row_at_its_upper_bound_is_the_bound_exactly)."""
    lower, upper = np.broadcast_to(lower, z.shape), np.broadcast_to(np.inf if upper is None else upper, z.shape)
    allowed = 2 * np.spacing(np.maximum(finite_abs(lower), finite_abs(upper))) + res * (1 + 1e-12)
    assert np.all(z >= lower - allowed), np.max(lower - z)
    assert np.all(z <= upper + allowed), np.max(z - upper)


def stable_norm(v):
    """‖v‖₂ scaled by max|vᵢ| (no overflow or underflow for data of magnitude 1e±300)."""
    big = float(np.max(np.abs(v), initial=0.0))
    if not 0.0 < big < np.inf:
        return big
    return big * float(np.linalg.norm(v / big))


#: Corruptions seen only when the library calls the corrupted callable (a Newton solve that stops
#: before its first step never asks for the Jacobian): corrupt_case makes the solve take steps.
LAZY = {("zeta_jacobian", "wrong shape"), ("zeta_jacobian", "returns a string"), ("zeta_jacobian", "raises"),
        ("zeta_jacobian", "operator of wrong shape"), ("zeta_jacobian", "complex operator"),
        ("zeta_jacobian", "matvec of wrong length"), ("zeta_jacobian", "matvec returns nan")}


def check_case(case):
    """Solve the case and check it against the oracle; records what it reached in REACHED."""
    zeta, zeta_ref = make_zeta(case["zkind"], case["c"], case["B"])
    if case["corrupt"] is not None:
        REACHED["drawn"][case["corrupt"]] += 1
        zeta = apply_corruption(case, zeta)
    A, q, x0, opts = case["A"], case["q"], case["x0"], case["opts"]
    jac = jacobian_in(case["jacobian"]) if isinstance(case["jacobian"], str) else case["jacobian"]  # a format
    hier = opts.get("hierarchy")
    hier = list(hier) if isinstance(hier, (list, tuple)) else []
    upper = case.get("upper")
    watched = [A, q, x0, case["B"], case["c"], upper, *(opts.get(k) for k in ("omega1", "omega2", "phi")), *hier]
    before = snapshot(*watched)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = nrmicp.solve(A, q, zeta, upper=upper, x0=x0, zeta_jacobian=jac, **opts)
        # the Jacobian's format is nrmicp's business (DIA warned once per Newton step)
        assert not [w for w in caught if "zeta_jacobian" in str(w.message)]
    except JacobianError:
        event("corrupt input: the user's JacobianError")
        assert case["corrupt"] == ("zeta_jacobian", "raises")
        assert_unchanged(before, watched)
        REACHED["rejected"][case["corrupt"]] += 1
        return
    except (TypeError, ValueError) as exc:  # numpy.linalg.LinAlgError is a ValueError
        msg = str(exc)
        event(f"{'corrupt input' if case['corrupt'] else 'valid input'}: {type(exc).__name__}")
        if case["corrupt"] is not None:
            name = case["corrupt"][0]
            assert name in msg, f"corrupt {case['corrupt']} -> {type(exc).__name__}: {msg}"
            REACHED["rejected"][case["corrupt"]] += 1
        else:  # valid input that the method cannot take: still a clear error naming what
            assert isinstance(exc, (ValueError, np.linalg.LinAlgError)), msg
            assert any(s in msg for s in ("A[", "A (", "A is", "left matrix", "omega2", "alpha")), msg
        assert_unchanged(before, watched)
        return
    assert case["corrupt"] is None or case["corrupt"] in LAZY, f"corrupt {case['corrupt']} was accepted: {res.message}"
    assert_unchanged(before, watched)
    assert isinstance(res.status, nrmicp.Status)
    event(f"valid input: {res.status.name}")
    assert np.all(np.isfinite(res.z)), res.message
    if case.get("upper_ref") is not None:   # an implicit upper bound: its vector at the returned z
        upper = case["upper_ref"](res.z)
    true_res, slack = oracle_residual(A, q, res.z, zeta_ref, None if upper is None else np.asarray(upper, float))
    bounded = case["zkind"] in BOUNDED_KINDS
    if bounded:
        assert_in_bounds(res.z, 0.0 if case["zkind"] == "upper" else case["c"], upper, true_res + slack)
        assert res.active_mask.dtype == np.int8 and res.active_mask.shape == res.z.shape
    if np.isfinite(res.residual) and np.isfinite(true_res):  # the reported Res is the returned z's
        assert abs(res.residual - true_res) <= slack + 1e-10 * true_res, (res.residual, true_res, res.message)
    if opts["method"] == "newton":   # the Jacobian given up (and only a wrong one), and said so
        assert (res.path == "newton+outer") == ("zeta_jacobian looks wrong" in res.message), res.message
        assert res.path != "newton+outer" or case["jacobian"] in WRONG_JACOBIANS, (case["jacobian"], res.message)
        REACHED["gave_up"][case["jacobian"]] += res.path == "newton+outer"
    if res.success:
        assert true_res < opts["tol"] + slack, (res.residual, true_res, opts["tol"], res.message)
        if case["corrupt"] is None:
            REACHED["converged"][opts["method"]] += 1
            REACHED["bounded"]["converged"] += bounded
            REACHED["bounded"]["n >= 100"] += bounded and A.shape[0] >= 100
            REACHED["bounded"]["implicit upper"] += case["zkind"] == "implicit upper"
            REACHED["n_converged"][opts["method"]].append(A.shape[0])
    return res


def _combo_id(combo):
    return "-".join(str(x) for x in combo if x is not None)


@pytest.mark.parametrize("method,zkind,hierarchy", COMBOS, ids=[_combo_id(c) for c in COMBOS])
@_fuzz_settings(VALID_EXAMPLES)
@given(seed=st.integers(0, 2**32 - 1))
def test_fuzz_valid(method, zkind, hierarchy, seed):
    REACHED["combos"][(method, zkind, hierarchy)] += 1
    check_case(build_case(seed, method, zkind, hierarchy))


@pytest.mark.parametrize("corrupt", CORRUPTIONS, ids=[f"{a}-{b}".replace(" ", "_") for a, b in CORRUPTIONS])
@_fuzz_settings(CORRUPT_EXAMPLES)
@given(seed=st.integers(0, 2**32 - 1))
def test_fuzz_corrupt(corrupt, seed):
    check_case(corrupt_case(seed, corrupt))


#: What the CI slice must reach: oracle-checked converged solves per method, and per method the
#: largest n among them.
MIN_CONVERGED = {m: 10 for m in STATIONARY} | {"newton": 80}
MIN_LARGEST_N = 100
#: Oracle-checked converged solves with bounds (upper, or -inf in zeta), and those with n >= 100.
MIN_BOUNDED = {"converged": 15, "n >= 100": 5, "implicit upper": 5}


def test_fuzz_coverage():
    """The slice reaches what it lists (tests deselected in this session are run here first):
    every corruption drawn and rejected, every combination run, converged oracle-checked solves
    of every method, with large n among them."""
    for combo in COMBOS:
        if not REACHED["combos"][combo]:
            test_fuzz_valid(method=combo[0], zkind=combo[1], hierarchy=combo[2])
    for corrupt in CORRUPTIONS:
        if not REACHED["drawn"][corrupt]:
            test_fuzz_corrupt(corrupt=corrupt)
    missed = [c for c in CORRUPTIONS if not REACHED["rejected"][c]]
    assert not missed, f"corruptions never rejected: {missed}"
    for method, k in MIN_CONVERGED.items():
        assert REACHED["converged"][method] >= k, (method, dict(REACHED["converged"]))
        assert max(REACHED["n_converged"][method]) >= MIN_LARGEST_N, (method, REACHED["n_converged"][method])
    for what, k in MIN_BOUNDED.items():
        assert REACHED["bounded"][what] >= k, dict(REACHED["bounded"])


#: (method, ζ kind, hierarchy, seed) of cases the random long run found failing, kept in CI.
REGRESSIONS = [
    # the fallback's sweep run doubled past INT_MAX: "Options: maxiter must be >= 0, got -1610612736"
    ("newton", "affine", "list", 2666965),
    # scale="both" on data at 1e-300: the scaled iterate diverged, D_c y overflowed and ζ got inf
    # ("zeta(z) returned non-finite values" raised instead of the status DIVERGED)
    ("nrmsor", "callable_f32", None, 7),
]


@pytest.mark.parametrize("method,zkind,hierarchy,regression", REGRESSIONS)
@settings(max_examples=1, deadline=None, database=None)
@given(seed=st.just(0))  # (run under Hypothesis, as check_case records events)
def test_fuzz_regressions(method, zkind, hierarchy, regression, seed):
    check_case(build_case(regression, method, zkind, hierarchy))


def _adversarial(A, q, opts, x0=None, zkind="none", c=None, B=None):
    """A case of the adversarial run (issue 38), built by hand in check_case's form."""
    A = sp.csr_matrix(A)
    n = A.shape[0]
    return dict(A=A, q=np.asarray(q, float), zkind=zkind, c=np.zeros(n) if c is None else c,
                B=sp.csr_matrix((n, n)) if B is None else B, x0=x0, opts=opts, corrupt=None, rng=None, jacobian=None)


def _huge_entries(rng, n):
    """Entries 5e292 ... 6e296 on a full diagonal and 5% off it."""
    A = sp.lil_matrix(sp.random(n, n, density=0.05, random_state=rng,
                                data_rvs=lambda k: 10.0 ** rng.uniform(292.7, 296.8, k)))
    A.setdiag(10.0 ** rng.uniform(292.7, 296.8, n))
    return sp.csr_matrix(A)


def _adversarial_cases():
    """name -> (case, the most iterations the solve may take)."""
    rng = np.random.default_rng(38)
    stuck_A = np.array([[0, 0, 0], [0, 3e-323, -1e-323], [0, 0, 0]])
    huge = _huge_entries(rng, 185)
    huge_x0 = 10.0 ** rng.uniform(0, 172.8, 185)
    small = _huge_entries(rng, 30)
    neg_x0 = rng.uniform(0, 1, 30)
    neg_x0[7] = -1.6e296
    B = sp.csr_matrix(rng.uniform(-0.2, 0.2, (15, 15)) * (rng.random((15, 15)) < 0.5))
    return {
        # Res bit-identical from iteration 0 while z_0 grew: MAX_ITERATIONS after 10**6 iterations
        "nrm zero row, q_0 < 0": (_adversarial(stuck_A, [-0.0512, -1.3045, 0.0229],
                                               dict(method="nrm", tol=7.8e-13, gamma=11.59, maxiter=2**31 - 1)), 10),
        # x bitwise fixed at 1e20 (each step below its rounding): 100 iterations to the rounding floor
        "nrmgs fixed point": (_adversarial([[1e-30]], [0.0], dict(method="nrmgs", omega2=[1.0], tol=1e-12),
                                           x0=np.array([2e20])), 10),
        # scale=True: x0 / d_c overflowed, z came back non-finite
        "nrmaor huge A, scaled": (_adversarial(huge, rng.standard_normal(185), dict(method="nrmaor", scale=True),
                                               x0=huge_x0), 10_000),
        "nrm huge A, x0 -1.6e296, scaled": (_adversarial(small, rng.standard_normal(30),
                                                         dict(method="nrm", scale=True), x0=neg_x0), 10_000),
        # A = 0, Affine ζ, a start of 1e59: the reported Res against the oracle's
        "nrmm A = 0, affine": (_adversarial(sp.csr_matrix((15, 15)), 0.1 * rng.standard_normal(15),
                                            dict(method="nrmm", alpha=0.0069, gamma=0.89, scale="rows", maxiter=300,
                                                 stall_iterations=5),
                                            x0=rng.uniform(-1, 1, 15) * 1e59, zkind="affine",
                                            c=rng.standard_normal(15), B=B), 300),
    }


ADVERSARIAL = _adversarial_cases()


@pytest.mark.parametrize("name", sorted(ADVERSARIAL))
@settings(max_examples=1, deadline=None, database=None)
@given(seed=st.just(0))  # (run under Hypothesis, as check_case records events)
def test_fuzz_adversarial_regressions(name, seed):
    case, most = ADVERSARIAL[name]
    res = check_case(case)
    assert res.iterations <= most, res.message
