"""The Python side of the Newton member (``method="newton"``) and of ``polish``: option checks,
the hierarchy (prolongations for nested iteration), the polishing step and the result fields.
The algorithm itself is C++ (cpp/include/nrmicp/newton.hpp)."""
from __future__ import annotations

import time

import numpy as np

from . import _core
from ._hierarchy import Hierarchy, HierarchyWarning, amg_levels_why, hierarchy_kind, resolve_hierarchy
from ._inputs import _warn
from ._zeta import CheckedZeta

#: hierarchy="auto" builds the AMG hierarchy (pyamg) for method "newton" from this many unknowns
#: on, and starts cold below, where AMG's set-up outweighs the steps it saves (docs/MEASUREMENTS.md,
#: "`AUTO_AMG_MIN_N` = 1000").
AUTO_AMG_MIN_N = 1000
#: ... and only on a matrix with at most this fraction of its n² entries stored: on a dense one the
#: V-cycle's sweeps and Galerkin products cost more than a dense factorization (docs/MEASUREMENTS.md,
#: "`AUTO_AMG_MIN_N` = 1000", its AUTO_AMG_MAX_DENSITY paragraph).
AUTO_AMG_MAX_DENSITY = 0.1


def _has_pyamg() -> bool:
    try:
        import pyamg  # noqa: F401
    except ImportError:
        return False
    return True


#: polish's target in both entry points: the steps go on to the rounding floor, whatever the member's tol.
POLISH_TOL = np.finfo(float).tiny


def check_polish(polish) -> bool:
    if not isinstance(polish, (bool, np.bool_)):
        raise TypeError(f"polish must be True or False, got {polish!r}")
    return bool(polish)


def check_no_hierarchy(hierarchy, method):
    if hierarchy_kind(hierarchy) not in ("none", "auto"):
        raise ValueError(f"hierarchy is the nested iteration of method 'newton'; method {method!r} has none "
                         f"(got hierarchy={hierarchy!r}; use None)")


def auto_builds_amg(n: int, nnz: float) -> bool:
    """hierarchy='auto''s rule on an n-by-n A storing nnz entries: n >= AUTO_AMG_MIN_N and at most
    AUTO_AMG_MAX_DENSITY of the n² entries stored (both engines: nrmicp.distributed asks it too)."""
    return n >= AUTO_AMG_MIN_N and nnz <= AUTO_AMG_MAX_DENSITY * float(n) * n


def resolves_to_amg(hierarchy, A) -> bool:
    """hierarchy= is 'amg', or 'auto' on an A of auto_builds_amg with pyamg importable."""
    if not isinstance(hierarchy, str):
        return False
    return hierarchy == "amg" or (hierarchy == "auto" and auto_builds_amg(A.shape[0], A.nnz) and _has_pyamg())


def amg_levels_or_rows(A, components=None):
    """amg_levels_why of an unscaled A, or None when one of its Galerkin operators PᵀAP has a
    non-positive diagonal: the core would end the hierarchy there and start cold. That happens when
    A is a symmetric matrix with its rows scaled apart, D·S; equilibrated rows keep the diagonals
    positive, so the caller then scales the rows (scale='rows'; docs/MEASUREMENTS.md, "Row-scaled
    matrices and the amg set-up")."""
    pairs, why = amg_levels_why(A, components)
    return (pairs, why) if all((Ac.diagonal() > 0).all() for _, Ac in pairs) else None


def levels(hierarchy, A, A_core, dc, built=None, asked=None, components=None) -> tuple:
    """hierarchy= -> (prolongations for the core's matrix A_core (= A, or D_r A D_c when scaled),
    their Galerkin operators or None: the amg set-up forms them (or `built`, amg_levels_why's
    formed already, or a Hierarchy's), a given list leaves them to the core; the levels requested; why some are
    given up before the core, or None). 'auto': 'amg' for a sparse A of n >= AUTO_AMG_MIN_N when
    pyamg is importable, else none (cold start). `asked`: (levels requested, why) of a list made
    from the user's (the coupled rows' part: _decoupled.py). `components`: the amg set-up's labels
    (_hierarchy.check_components), or None."""
    if built is not None or resolves_to_amg(hierarchy, A):
        pairs, why = amg_levels_why(A_core, components) if built is None else built
        return [P for P, _ in pairs], [Ac for _, Ac in pairs], len(pairs) + 1 + (why is not None), why
    Ps = resolve_hierarchy(hierarchy, A) or []
    if Ps and dc is not None:
        # z = D_c y: a prolongation of y is D_c⁻¹ P (the coarse variables keep their scale).
        import scipy.sparse as sp
        Ps = [sp.csr_matrix(sp.diags(1.0 / dc) @ Ps[0])] + Ps[1:]
    requested, why = asked or (len(Ps) + 1, None)
    return Ps, None, requested, why


def hierarchy_report(requested: int, why, core) -> dict:
    """The result field ``hierarchy``: {"requested": levels requested, "used": levels the core
    nests over (Solver.levels), "reason": why fewer are used (the Python layer's `why`, then the
    core's), None when all are}."""
    used, core_why = core.levels, core.hierarchy["reason"]
    reasons = [r for r in (why, core_why) if r]
    return {"requested": requested, "used": used, "reason": "; ".join(reasons) if used < requested else None}


def warn_shortened(report: dict, hierarchy) -> None:
    """The HierarchyWarning of a set-up whose requested hierarchy was shortened (once per set-up)."""
    if report["reason"] is None:
        return
    what = (f"[{report['requested'] - 1} prolongations]" if isinstance(hierarchy, (list, tuple)) else
            f"a Hierarchy of {len(hierarchy)} levels" if isinstance(hierarchy, Hierarchy) else repr(hierarchy))
    _warn(f"hierarchy={what}: {shortened(report)}", HierarchyWarning)


def shortened(report: dict) -> str:
    """The shortening in words: levels requested and used, and why."""
    used = report["used"]
    how = "a cold start (no nested iteration)" if used == 1 else f"nested iteration over {used} levels"
    return f"{report['requested']} levels requested, {used} used, {how}: {report['reason']}"


def make_core(A_core, opts, hierarchy, A, dc, built=None, asked=None, components=None):
    """(The C++ Newton object (NewtonI32/NewtonI64) with its prolongations (and coarse operators),
    the hierarchy_report of its set-up)."""
    idx = A_core.indices.dtype
    Ps, coarse, requested, why = levels(hierarchy, A, A_core, dc, built, asked, components)

    def triple(M):
        return (M.indptr.astype(idx, copy=False), M.indices.astype(idx, copy=False),   # the core copies them
                np.ascontiguousarray(M.data, dtype=np.float64),
                M.shape[0], M.shape[1])
    cls = _core.NewtonI64 if idx == np.int64 else _core.NewtonI32
    prolongations, coarse_operators = [triple(P) for P in Ps], [triple(Ac) for Ac in coarse or []]
    del Ps, coarse  # the core copies each level and empties these lists as it goes: one copy at a time
    core = cls(A_core.indptr, A_core.indices, A_core.data, A_core.shape[0], opts, prolongations, coarse_operators)
    return core, hierarchy_report(requested, why, core)


def polisher(solver):
    """The Newton object used to polish a stationary member's answer (built on first use, no
    hierarchy). None when Newton cannot be set up on A (e.g. diag(A) not positive)."""
    if solver._polisher is None:
        A_core = solver.A if solver._dr is None else None
        if A_core is None:
            from ._scaling import scale_matrix
            A_core = scale_matrix(solver.A, solver._dr, solver._dc)
        opts = _core.Options()
        opts.method = _core.Method.newton
        try:
            solver._polisher = make_core(A_core, opts, None, solver.A, solver._dc)[0]
        except ValueError:
            solver._polisher = False
    return solver._polisher or None


def polish(solver, problem, z, res, original_residual, dc, upper=None):
    """Newton steps from z on its active set (``polish=True``) to the rounding floor of Res (at
    most 3: Newton::polish). Returns (z, w, Res, core result) when they lowered Res (measured in
    the original variables), else (None, core result); the core result's status is STAGNATED
    with the floor in its message when the floor was reached.

    `problem` is the core's solve arguments before x0 in the core's variables (serial: q, kind, c,
    B-indptr, B-indices, B-data, fn); dc the column scaling (None when unscaled); `upper` the core's
    upper bound as its solves took it (None: none)."""
    t0 = time.perf_counter()
    core = solver._core if solver.method == "newton" else polisher(solver)
    if core is None or not np.isfinite(res):
        return None, None
    built = time.perf_counter() - t0   # the polisher's set-up on first use (else a few µs)
    z0 = z / dc if dc is not None else z
    d = core.polish(*problem, np.ascontiguousarray(z0), POLISH_TOL, upper=upper)
    d["timings"]["setup"] += built
    zp = d["z"] * dc if dc is not None else d["z"]
    wp, rp = original_residual(zp)
    if not rp < res:
        return None, d
    return (zp, wp, rp), d


def polish_outcome(status, message: str, res: float, tol: float, polished: bool, polish_core):
    """(status, message) after ``polish``: CONVERGED where the kept polish steps brought Res below tol;
    where they could not, STAGNATED at Res's rounding floor with the polish's message appended (its
    core result `polish_core`, None when not run). Both entry points (nrmicp.solve, distributed) ask it."""
    if polished and res < tol and int(status) != int(_core.Status.CONVERGED):
        return int(_core.Status.CONVERGED), "converged: Res < tol after polishing (Newton steps)"
    if (res >= tol and polish_core is not None and int(polish_core["status"]) == int(_core.Status.STAGNATED)
            and "rounding floor" in polish_core["message"]):
        return int(_core.Status.STAGNATED), f"{message}; polish: {polish_core['message']}"
    return status, message


def result_fields(d, report: dict) -> dict:
    """The Newton member's result fields: every field of the core's NewtonStats (result.hpp), and
    ``hierarchy`` (a copy of the set-up's hierarchy_report)."""
    stats = d["newton"]
    return {**{name: getattr(stats, name) for name in _core.NewtonStats.fields}, "hierarchy": dict(report)}


def with_shortening(status, message: str, report) -> str:
    """A message of a solve that did not converge, with the hierarchy's shortening (once) if any."""
    if int(status) == int(_core.Status.CONVERGED) or report is None or report["reason"] is None:
        return message
    note = f"; the hierarchy: {shortened(report)}"
    return message if note in message else message + note


#: The starts of the core's notes that it gave up a zeta_jacobian (path 'newton+outer'; detail::JacobianCheck::message):
#: one that looks wrong, and one that matches ζ's difference quotient but whose steps stopped converging.
JACOBIAN_NOTES = ("zeta_jacobian looks wrong", "the Newton steps with zeta_jacobian")


def with_jacobian_note(message: str, path: str, core_message: str) -> str:
    """`message` with the core's note that it gave up the zeta_jacobian, when the returned round did
    (path 'newton+outer') and the message, re-decided in Python, lost it."""
    starts = [core_message.index(note) for note in JACOBIAN_NOTES if note in core_message]
    if path != "newton+outer" or not starts or any(note in message for note in JACOBIAN_NOTES):
        return message
    return f"{message}; {core_message[min(starts):]}"


def check_jacobian(zeta_jacobian, method, kind) -> bool:
    """Whether a ``zeta_jacobian`` was given; TypeError/ValueError when it cannot be used."""
    if zeta_jacobian is None:
        return False
    if not callable(zeta_jacobian):
        raise TypeError(f"zeta_jacobian must be callable, got {type(zeta_jacobian).__name__}")
    if method != "newton" or kind != _core.ZetaKind.functor:
        raise ValueError("zeta_jacobian is used by method 'newton' with a callable zeta only")
    return True


class JacobianProduct(CheckedZeta):
    """The product v ↦ J v of a ``zeta_jacobian(z)`` returned as a linear operator, for one solve (its
    ``fn`` is the current Newton step's): the core calls ``fn`` on its own read-only buffer, as it
    calls a CheckedZeta's, and hands a result that is not a finite float64 vector of length n to
    :meth:`CheckedZeta.output`, which converts it or raises naming zeta_jacobian."""

    what = "zeta_jacobian(z).matvec(v)"

    def wrap(self, matvec, dc=None):
        """matvec as ``fn``: in the scaled variables when dc is given (D_c⁻¹ J D_c v), and its
        ValueErrors named (a LinearOperator's reshape of a result of the wrong length raises one), but
        for a write into the read-only v, which the core names itself."""
        def fn(v):
            try:
                y = matvec(v if dc is None else v * dc)
            except ValueError as exc:
                if self.read_only_message(exc) is not None:
                    raise
                raise ValueError(f"{self.what} failed: {exc}") from exc
            return y if dc is None else self.output(y) / dc
        return fn


def is_matrix(J) -> bool:
    """Whether a zeta_jacobian's return value takes the sparse path (a matrix, dense or sparse); anything
    else is read as a linear operator."""
    import scipy.sparse as sp
    return sp.issparse(J) or isinstance(J, np.ndarray) or hasattr(J, "__array__")


def as_operator(J, n: int):
    """J as a real scipy LinearOperator of shape (n, n) (scipy's aslinearoperator: a LinearOperator,
    or anything with shape and matvec); TypeError/ValueError naming zeta_jacobian otherwise."""
    from scipy.sparse.linalg import aslinearoperator
    try:
        op = aslinearoperator(J)
    except (TypeError, ValueError, AttributeError):
        raise TypeError("zeta_jacobian(z) must return a scipy.sparse matrix, a 2-D numpy array or a linear operator "
                        f"(scipy.sparse.linalg.LinearOperator, or anything with shape and matvec), got "
                        f"{type(J).__name__}") from None
    if tuple(op.shape) != (n, n):
        raise ValueError(f"zeta_jacobian(z) must return an ({n}, {n}) operator, got shape {tuple(op.shape)}")
    dtype = np.dtype(op.dtype) if op.dtype is not None else np.dtype(np.float64)
    if dtype.kind not in "fiub":
        raise TypeError(f"zeta_jacobian(z) must return a real operator, got dtype {dtype}")
    return op


def jacobian_argument(zeta_jacobian, solver, kind, dc) -> dict:
    """The core's ``zeta_jacobian`` keyword for a serial Solver: {} without one, else core_jacobian's."""
    if not check_jacobian(zeta_jacobian, solver.method, kind):
        return {}
    return {"zeta_jacobian": core_jacobian(zeta_jacobian, solver.n, solver._index_dtype, dc)}


def _direct(fn, *args):
    return fn(*args)


def core_jacobian(zeta_jacobian, n, idx, dc=None, collective=_direct):
    """The core's Jacobian callable (bridge.hpp CallableJacobian): a wrapper returning, for a matrix,
    canonical CSR arrays with the index type ``idx``, for a linear operator its JacobianProduct (in the
    scaled variables y = D_c⁻¹ z: J' = D_c⁻¹ J(D_c y) D_c). ``collective(fn, *args)`` runs each call of
    the user's code and its checks (the distributed engine's: a failure on one rank raises on all)."""
    import scipy.sparse as sp
    from ._inputs import as_csr

    product = JacobianProduct(None, n)   # one per solve: its dtype warning once

    def convert(y):
        z = y * dc if dc is not None else y
        J = zeta_jacobian(z)
        if not is_matrix(J):
            matvec = product.wrap(as_operator(J, n).matvec, dc)
            product.fn = matvec if collective is _direct else (lambda v: collective(lambda u: product.output(matvec(u)), v))
            return product
        # silent: J is copied every step anyway (index type, scaling); sp.diags' DIA is no mistake
        J = as_csr(J, "zeta_jacobian(z)", warn=False)
        if J.shape != (n, n):
            raise ValueError(f"zeta_jacobian(z) must return an ({n}, {n}) matrix, got shape {J.shape}")
        if dc is not None:
            J = sp.csr_matrix(sp.diags(1.0 / dc) @ J @ sp.diags(dc))
            J.sort_indices()
        return J.indptr.astype(idx), J.indices.astype(idx), np.ascontiguousarray(J.data, dtype=np.float64)

    return lambda y: collective(convert, y)
