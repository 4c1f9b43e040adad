"""nrmicp beyond one machine: every member on PETSc over MPI — the Newton member (nrmicp::Newton) and
the stationary members (nrmicp::Solver, as synchronous multisplitting), the serial library's C++ on
the PETSc engine (nrmicp._petsc). This module is glue: argument checks and conversion, layouts, the
call into the core.

Run under ``mpirun -n P python script.py``; every rank calls :func:`solve` with the same
arguments for its own rows. A is a petsc4py ``Mat`` (MPIAIJ; or each rank's CSR row block, a
scipy matrix of shape (n_local, n)), q a petsc4py ``Vec`` with A's row layout (or each rank's
rows as a numpy array). The heavy work is PETSc's: products, KSP (CG / BiCGSTAB) preconditioned by
a V-cycle (PCMG) on the nested iteration's hierarchy, whose prolongations are hypre BoomerAMG's
(hierarchy='amg': built by the core, nrmicp/petsc/hierarchy.hpp; PETSc options -nrmicp_hierarchy_...
replace its rule). Option names, their checks, the statuses, the result fields and the advice a
solve that did not converge gives are the serial library's (nrmicp._api, nrmicp._core): one definition.

What is distributed: everything per iteration (products, reductions, the reduced solves, the
stationary members' splittings of each rank's diagonal block, ζ on each rank's rows). What is not: the hierarchy's set-up is hypre's (itself parallel); a callable
ζ sees only the rank's own rows (an entry-wise or row-local ζ); :func:`gather` copies z to
rank 0 (small problems only).
"""
from __future__ import annotations

import functools
import math
import time
import types
import zlib

import numpy as np
import scipy.sparse as sp

try:
    from petsc4py import PETSc
except ImportError as exc:  # the core package needs no MPI; this module does
    raise ImportError("nrmicp.distributed needs petsc4py, PETSc (with hypre) and MPI: README, 'Beyond one machine' "
                      f"(make mpideps installs them on Debian); {exc}") from exc

from . import _bounds, _core, _options
from ._mpi import DistributedError, agree, collective as _collective, flag_max as _flag_max, flag_sum as _flag_sum
from ._newton import (auto_builds_amg, check_jacobian, check_no_hierarchy, check_polish, core_jacobian, hierarchy_report,
                      warn_shortened)
from ._api import (METHODS as _ALL_METHODS, Result, _make_upper, _make_zeta, Status, _Rounds, _choice, _criterion, _settle, _log_final,
                   _omega2_hint, _progress_hook, _units_parameters, core_options, choose_method, dominance_margin,
                   failure_hint)
from ._scaling import sigma_from_logs
from ._hierarchy import Hierarchy, _fingerprint, resolve_hierarchy
from ._inputs import as_constant, as_csr, as_vector
from ._zeta import CheckedZeta

__all__ = ["solve", "Solver", "gather", "METHODS", "DistributedError"]
_K = _core.ZetaKind

#: The distributed members: every member of nrmicp (the stationary ones as synchronous multisplitting).
METHODS = _ALL_METHODS
#: nrmicp.solve's options that cannot apply on PETSc for any member, and why (refused naming them
#: unless at their defaults).
_UNSUPPORTED = {
    "scale": "the default rule's units scaling is the one scaling here",
    "components": "BoomerAMG builds the hierarchy: PETSc options -nrmicp_hierarchy_pc_hypre_boomeramg_..."}
#: ... for the Newton member only (the stationary members' loop takes them).
_UNSUPPORTED_NEWTON = {
    "inner": "the PETSc engine's reduced solves are its own: PETSc options -nrmicp_inner_..."}
#: ... for the stationary members only.
_UNSUPPORTED_STATIONARY = {
    "z_update": "'solve' needs a factorization of the whole A; 'explicit' applies",
    "polish": "polishing is a Newton step: use method 'newton'"}
# ----------------------------------------------------------------------------- inputs
def _check_mat(A):
    """A's local checks: a square AIJ Mat with equal row and column layouts, or a scipy row block
    (returned as canonical float64 CSR, checked as nrmicp.solve checks A)."""
    if isinstance(A, PETSc.Mat):
        if "aij" not in A.getType():
            raise TypeError(f"A must be an AIJ (sparse) PETSc matrix, got type {A.getType()!r}")
        (m, n), (M, N) = A.getLocalSize(), A.getSize()
        if M != N:
            raise ValueError(f"A must be square, got shape ({M}, {N})")
        if m != n:
            raise ValueError(f"A's local row and column sizes differ on this rank ({m} rows, {n} columns): "
                             "create A with the same row and column layout")
        return A
    if not sp.issparse(A):
        raise TypeError(f"A must be a petsc4py Mat or this rank's scipy.sparse row block, got {type(A).__name__}")
    try:
        return as_csr(A, "A", square=False, warn=False)   # (nrmicp.solve's checks; PETSc copies it)
    except ValueError as exc:
        raise ValueError(f"{exc} (of this rank's block of rows: its rows count from the block's first)") from None


def _as_mat(B, comm):
    """This rank's CSR rows -> an MPIAIJ Mat (collective); ValueError when not square in all."""
    mat = PETSc.Mat().createAIJ(size=((B.shape[0], PETSc.DECIDE), (B.shape[0], PETSc.DECIDE)), comm=comm)
    N = mat.getSize()[1]

    def columns():
        if B.shape[1] != N:
            raise ValueError(f"A's row blocks must together be square: this rank's block has {B.shape[1]} "
                             f"columns, the blocks have {N} rows in all")
    _collective(comm, columns)
    mat.setPreallocationCSR((B.indptr.astype(PETSc.IntType), B.indices.astype(PETSc.IntType), B.data))
    mat.assemble()
    return mat


def _local(v, A, name, *, scalar_ok=False, infinite=0):
    """q, zeta's c, x0, upper -> this rank's rows as a new float64 array (local checks only: no rank
    waits for another here; the user's object is never modified); `infinite`: as in as_constant."""
    lo, hi = A.getOwnershipRange()
    if isinstance(v, PETSc.Vec):
        if v.getOwnershipRange() != (lo, hi) or v.getSize() != A.getSize()[0]:
            raise ValueError(f"{name}'s layout (rows {v.getOwnershipRange()} of {v.getSize()}) does not match "
                             f"A's rows ({lo}, {hi}) of {A.getSize()[0]}")
        v = v.getArray(readonly=True)
    try:
        return np.array(as_constant(v, hi - lo, name, infinite) if scalar_ok else as_vector(v, hi - lo, name))
    except ValueError as exc:
        raise ValueError(f"{exc} (indices of this rank's rows, which start at global row {lo})") from None


def _vec(A, arr):
    """A new Vec in A's row layout holding arr (collective)."""
    out = A.createVecLeft()
    out.setArray(arr)
    return out


def _core_options(o, method, nloc, it):
    """The core's Options from nrmicp.solve's options `o` (this rank's rows of the diagonals; tol and
    rtol as _criterion resolved them in `it`), checked by the serial library's code (the one table,
    nrmicp._options, and the core's Options.check), and the options that cannot apply to this member
    on PETSc refused naming them."""
    refused = dict(_UNSUPPORTED_NEWTON if method == "newton" else _UNSUPPORTED_STATIONARY)
    if method != "newton" and o["z_update"] in ("explicit", "auto"):
        refused.pop("z_update")   # (what 'auto' means: the core refuses 'solve', naming z_update)
    _options.validate({k: o[k] for k in refused}, where="distributed.solve", unsupported=refused)
    return core_options(o, method, nloc, {**{k: o[k] for k in _options.names("solve")}, "tol": it["tol"], "rtol": it["rtol"]})


class _Rows:
    """How ζ's and upper's parts are read here (_api._make_zeta, _bounds.as_upper: nrmicp.solve's rules and
    messages): a matrix as a PETSc Mat in A's layout, a constant or vector as this rank's rows."""

    def __init__(self, A):
        self.A = A

    def matrix(self, B, name):
        n, rows = self.A.getSize()[0], self.A.getOwnershipRange()
        if not isinstance(B, PETSc.Mat):
            raise TypeError(f"{name} must be a petsc4py Mat in A's layout, got {type(B).__name__}")
        layout = (B.getOwnershipRange(), B.getOwnershipRangeColumn())
        if B.getSize() != (n, n) or layout != (rows, self.A.getOwnershipRangeColumn()):
            raise ValueError(f"{name} must be ({n}, {n}) with A's row and column layout, got {B.getSize()} rows "
                             f"{layout[0]} columns {layout[1]} on this rank")
        return B

    def vector(self, v, name, infinite=0):
        return _local(v, self.A, name, scalar_ok=True, infinite=infinite)


class _Zeta:
    """ζ on this rank's rows: its kind (_core.ZetaKind: none, constant c, affine B Mat and c, functor a callable)."""

    def __init__(self, zeta, A, comm):
        """Local checks only."""
        _not_a_mat(zeta, "zeta")
        self.comm, nloc = comm, A.getLocalSize()[0]
        self.kind, self.c, self.B, fn = _make_zeta(zeta, nloc, _Rows(A))
        self.fn = None if fn is None else CheckedZeta(fn, nloc)

    def _checked(self, z):
        r = self.fn(z)
        if not np.all(np.isfinite(r)):
            i = int(np.flatnonzero(~np.isfinite(r))[0])
            raise ValueError(f"{_core.status_message(int(Status.ZETA_FAILED))} (NaN or Inf: zeta(z)[{i}] of this "
                             f"rank's rows = {r[i]})")
        return r

    def core_args(self, A):
        """(kind, c, fn) for the PETSc engine: this rank's c; a callable (or an affine ζ, as its product
        B z + c) as a CheckedZeta of this rank's rows whose every call is collective (a failure on any
        rank raises on all, in the same call of the one driver)."""
        if self.kind in (_K.none, _K.constant):
            return self.kind, self.c, None
        local = _affine(self.B, self.c, A) if self.kind == _K.affine else (
            lambda z: _collective(self.comm, self._checked, z))
        return _K.functor, None, CheckedZeta(local, A.getLocalSize()[0])


def _not_a_mat(v, name):
    """A Mat is callable in petsc4py: taken for ζ(z) it would fail deep in the solve."""
    if isinstance(v, PETSc.Mat):
        raise TypeError(f"{name} must not be a bare petsc4py Mat: pass nrmicp.Affine(B, c) for {name}(z) = B z + c")


def _affine(B, c, A):
    """z ↦ B z + c on this rank's rows (PETSc's product: collective)."""
    zv, out, cv = A.createVecRight(), A.createVecLeft(), _vec(A, c)

    def product(z):
        zv.setArray(z)
        B.multAdd(zv, cv, out)
        return np.array(out.getArray(readonly=True))
    return product


# ----------------------------------------------------------------------------- the entry points
def _prepare_matrix(A, comm, o):
    """A's checks and the member, with every rank's failure raised on all ranks: (Am, method). The
    set-up options `o` are checked here too (the core's Options, by the serial code), with tol and
    rtol at their defaults. A Mat made here from scipy row blocks is destroyed when a check fails."""
    A_in = _collective(comm, _check_mat, A)
    _same(comm, float(sp.issparse(A_in)), TypeError,   # (else the ranks would part ways: a hang)
          "A must be a petsc4py Mat on every rank or a scipy row block on every rank, not both")
    Am = _as_mat(A_in, comm) if sp.issparse(A_in) else A_in
    try:
        return Am, _member(Am, comm, o)
    except Exception:
        if Am is not A_in:
            Am.destroy()   # on every rank together (each raises here)
        raise


def _member(Am, comm, o):
    """The member for Am and the set-up options `o` ('auto': nrmicp.solve's rule), checked on every rank;
    A's diagonal positive (_positive_diagonal)."""
    nloc = Am.getLocalSize()[0]
    method = o["method"]
    if isinstance(method, str) and method.lower() == "auto":
        method = _auto_method(Am, o, comm)

    def local():
        m = _choice(method, METHODS, "method")
        _core_options(o, m, nloc, _criterion({"tol": o["tol"], "rtol": o["rtol"]})[0])
        hierarchy = o["hierarchy"]
        if m != "newton":
            check_no_hierarchy(hierarchy, m)
            return m
        check_polish(o["polish"])
        _owns_rows(Am)
        named = hierarchy is None or (isinstance(hierarchy, str) and hierarchy in ("amg", "auto"))
        if not (named or isinstance(hierarchy, (list, tuple, Hierarchy))):
            got = hierarchy if isinstance(hierarchy, str) else type(hierarchy).__name__
            raise ValueError(f"hierarchy must be 'amg', None, a nrmicp.Hierarchy or a list of prolongations (PETSc "
                             f"Mats, or whole scipy matrices on every rank); got {got!r}")
        return m
    m = _collective(comm, local)
    h = o["hierarchy"]   # (its kind: every rank takes the same branches)
    kind = ("amg", "auto").index(h) + 1 if isinstance(h, str) else 0 if h is None else 3
    _same(comm, float(kind) if m == "newton" else 0.0, ValueError, _DIFFERENT_HIERARCHY)
    _positive_diagonal(Am, comm)
    return m


def _positive_diagonal(Am, comm):
    """ValueError on every rank naming the first row whose a_ii is not positive (NaN included): the PETSc
    engine's smoothers, CG and splittings divide by the diagonal, where the serial member has rules for
    such rows (its Ω2, the Krylov choice), which this engine does not have."""
    da = _diagonal(Am)

    def check():
        lo = Am.getOwnershipRange()[0]
        bad = ~(da >= np.finfo(np.float64).tiny)   # (NaN, and subnormal: its reciprocal overflows)
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"A's diagonal must be positive (not subnormal) on the PETSc engine (its smoothers, "
                             f"Krylov solves and splittings divide by it); A[{lo + i}, {lo + i}] = {da[i]}")
    _collective(comm, check)


def _prepare_call(Am, m, q, zeta, x0, comm, o, it):
    """A solve's checks, every rank's failure raised on all: (core Options, this rank's q and x0, ζ)."""
    nloc = Am.getLocalSize()[0]

    def local():
        return _core_options(o, m, nloc, it), _local(q, Am, "q"), None if x0 is None else _local(x0, Am, "x0"), \
            _Zeta(zeta, Am, comm)
    return _collective(comm, local)


def solve(A, q, zeta=None, *, upper=None, comm=None, **options) -> Result:
    """Solve ICP(q, A, ζ) on all ranks of A's communicator (call it on every rank).

    A: petsc4py Mat (AIJ, square, same row and column layout) or this rank's scipy.sparse row
    block (n_local, n), of one kind on every rank (refused otherwise; without ``comm`` each rank's default
    is its A's communicator or PETSc.COMM_WORLD, so a mix of kinds cannot be seen). q, x0, upper: petsc4py Vec in A's row layout or this rank's rows. zeta: None,
    a constant (scalar, this rank's rows or a Vec), :class:`nrmicp.Affine` (B a petsc4py Mat in
    A's layout, c) or a callable mapping this rank's rows of z to this rank's rows of ζ(z)
    (entry-wise or row-local ζ only). method: 'newton' — the serial library's Newton member itself
    (nrmicp::Newton on the PETSc engine, nrmicp._petsc), nested over hypre BoomerAMG's prolongations
    with hierarchy='amg', cold with None, or over given prolongations, finest first: a list of PETSc Mats, or
    a :class:`nrmicp.Hierarchy` or list of whole scipy matrices, the same on every rank (the serial
    engine's levels: its decisions; the core forms the Galerkin operators of this A); an
    affine ζ runs its outer fixed point — or a stationary member ('nrm', 'nrmm', 'nrmaor', 'nrmsor',
    'nrmgs', 'nrmj', 'mms', 'two_sweep'): the serial loop (nrmicp::Solver on the PETSc engine) as
    synchronous multisplitting, each rank splitting its diagonal block (on one rank, the serial
    member's iterates; 'nrmj' takes them on any number). upper: z ≤ upper, as in :func:`nrmicp.solve`: a constant,
    or an implicit upper bound ('newton' only; its outer fixed point) — :class:`nrmicp.Affine` (B a petsc4py
    Mat in A's layout) or a callable of this rank's rows, as zeta.
    zeta_jacobian ('newton', a callable zeta): zeta_jacobian(z) of this rank's rows returns ζ′(z) as a
    linear operator on this rank's rows (a LinearOperator, or anything with shape and matvec: semismooth
    Newton on the whole ICP, its Krylov solve preconditioned by the LCP system; each matvec is called on
    every rank together, so it may communicate) or as a sparse matrix of them (a diagonal one solves
    on the LCP system; any other acts by its product: the rank's block, all of a row-local ζ′).
    callback(k, z, res) sees this rank's rows of z; returning True (or raising StopIteration) on any rank stops
    every rank.
    ``options`` are :func:`nrmicp.solve`'s, with its defaults, checked by the same code (one table:
    nrmicp._options); those that cannot apply on PETSc raise a ValueError naming them:
    ``_UNSUPPORTED`` (scale, components), for 'newton' also ``_UNSUPPORTED_NEWTON``
    (inner), for the stationary members ``_UNSUPPORTED_STATIONARY`` (z_update 'solve',
    polish). verbose prints rank 0's progress lines.
    method='auto' is nrmicp.solve's rule on every rank's rows; hierarchy='auto' is nrmicp.solve's rule
    (n ≥ 1000, at most 10% of A's entries stored), 'amg' there being BoomerAMG's (no pyamg needed).
    tol and rtol both None is nrmicp.solve's default rule (units-free Res_E, rtol 1e-10), applied by
    solving σA, σq (σ from the diagonal's global geometric mean), ``residual`` the paper's Res.
    Returns a :class:`nrmicp.Result` on every rank, with ``z`` and ``w`` as PETSc Vecs
    (:func:`gather` copies one to rank 0). A failure on any rank raises on every rank.
    """
    comm = comm or (A.getComm() if isinstance(A, PETSc.Mat) else PETSc.COMM_WORLD)
    _collective(comm, lambda: _options.validate(options, where="distributed.solve", unsupported=_UNSUPPORTED))
    setup = {k: v for k, v in options.items() if _options.TABLE[k].scope != "call"}   # (method='auto' reads both)
    if options.get("zeta_jacobian") is not None and str(setup.get("method", "auto")).lower() == "auto":
        setup["method"] = "newton"   # (nrmicp.solve's rule: a Jacobian is for Newton)
    t0 = time.perf_counter()
    with Solver(A, comm=comm, **setup) as solver:
        r = solver.solve(q, zeta, upper=upper, **{k: v for k, v in options.items() if k not in setup})
    r.timings["total"] = time.perf_counter() - t0
    return r


class Solver:
    """:class:`nrmicp.Solver` on PETSc: A set up once — checked, its member chosen, and on the first solve
    that needs it the core (nrmicp::Newton or nrmicp::Solver on the PETSc engine: the hierarchy, its
    Galerkin operators, the reduced systems' solvers) — then solved for many q, ζ, x0 (a time march, an
    outer loop of the user's). :func:`solve` is one Solver's one solve.

    ``Solver(A, *, comm=None, **options)`` takes :func:`solve`'s set-up options (method, hierarchy, the
    splitting, ...) and per-solve defaults (tol, maxiter, ...); ``solve(q, zeta=None, *, upper=None,
    **options)`` the per-solve ones and each call's own (x0, callback, zeta_jacobian), as
    :meth:`nrmicp.Solver.solve`. Call both on every rank. The default rule (tol and rtol None) iterates on
    σA, the paper's tol on A: one core each, kept. ``close()`` (or ``with``) frees the cores on every
    rank together: their KSPs' MUMPS factors are freed collectively, and left to each rank's garbage
    collector that happens at different times (a deadlock); a closed Solver raises on solve."""

    def __init__(self, A, *, comm=None, **options):
        t0 = time.perf_counter()
        self.comm = comm = comm or (A.getComm() if isinstance(A, PETSc.Mat) else PETSc.COMM_WORLD)
        _collective(comm, _scoped, options, ("setup", "solve"), "distributed.Solver", "its solve()")
        self._options = {**_options.defaults("setup", "solve"), **options}
        self.A, self.method = _prepare_matrix(A, comm, {**_options.defaults(), **self._options})
        self._owns_A = self.A is not A   # (made from scipy row blocks)
        o = {**_options.defaults(), **self._options}   # (every rank alike: the mean is a reduction)
        self._omega2_hint = _omega2_hint(_mean_abs_diagonal(self.A) if self.method == "nrm" else 1.0, self.method,
                                         o["omega2"], o["accelerate"])
        try:   # given prolongations checked and made PETSc Mats now, once (kept until close)
            self._levels = _prolongations(self._options["hierarchy"], self.A, comm) if self.method == "newton" else ([], [])
        except Exception:
            if self._owns_A:
                self.A.destroy()   # on every rank together (each raises here)
            raise
        self._cores = {}   # units (the default rule's σA) -> [the core, its set-up seconds not yet reported]
        self._operators = {False: (self.A, 1.0)}   # units -> (the Mat the core iterates, σ)
        self._setup_seconds = time.perf_counter() - t0   # reported by the first solve
        self._closed = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        """Frees the cores (collective: on every rank); a closed Solver's solve raises."""
        for core, _ in self._cores.values():
            core.close()
        for units, (mat, _) in self._operators.items():   # the σA copy, and an A made from scipy row blocks
            if units or self._owns_A:
                mat.destroy()
        for P in self._levels[1]:   # the prolongation Mats made from scipy matrices
            P.destroy()
        self._cores, self._operators, self._levels, self._closed = {}, {}, ([], []), True

    def solve(self, q, zeta=None, *, upper=None, **options) -> Result:
        """ICP(q, A, ζ) with this Solver's A: :func:`solve`'s arguments but A, comm and the set-up options."""
        from . import _petsc
        comm = self.comm
        if self._closed:
            raise ValueError("this distributed.Solver was closed")
        _collective(comm, _scoped, options, ("solve", "call"), "distributed.Solver.solve", "distributed.Solver()")
        o = {**_options.defaults(), **self._options, **options, "method": self.method}
        if o["callback"] is not None:
            o["callback"] = _collective_callback(comm, o["callback"])
        t_start = time.perf_counter()
        it, units = _criterion({"tol": o["tol"], "rtol": o["rtol"]})
        A_user, m = self.A, self.method
        opts, qa, xa, zf = _prepare_call(A_user, m, q, zeta, o["x0"], comm, o, it)
        ua, bounded = _upper(upper, A_user, zf, comm, m)
        q_user = qa
        Am, sigma = self._operator(units)
        if units:   # the iteration runs on σA, σq: its Res is the units-free Res_E
            qa = sigma * qa
            _units_parameters(opts, m, sigma, Am.getLocalSize()[0])
        kind, c, fn = zf.core_args(Am)
        measure = _Measure(_petsc, Am, qa, (kind, c, fn, ua), (A_user, q_user) if units else None)
        jacobian = _jacobian(o["zeta_jacobian"], zf, m, Am, comm)
        if opts.rtol > 0:   # the absolute target, on the problem the core iterates (Options::target of Res(0))
            opts.tol, opts.rtol = opts.target(measure(np.zeros_like(qa))[1]), 0.0
        core, setup, earlier = self._core(_petsc, units, Am, opts, o)
        hint = failure_hint(m, self._omega2_hint, lambda: _margin(A_user, comm), units, zf.kind)
        fields = _rounds(core, measure, xa, opts, o, jacobian, bounded, hint)
        if units:   # w in the user's units (re-measured: σ(Az + q) / σ may overflow or underflow)
            fields["w"] = measure(fields["z"], weighted=False)[0]
        timings = fields["timings"]
        timings["setup"] += setup
        timings["total"] = time.perf_counter() - t_start + earlier   # (the core's build is in this call)
        r = Result(**{**fields, "z": _vec(A_user, fields["z"]), "w": _vec(A_user, fields["w"])}, ranks=comm.getSize())
        if opts.verbose > 0:   # (a logger that raises on rank 0 raises on every rank)
            _collective(comm, lambda: comm.getRank() == 0 and _log_final(m, r, fields["timings"]["total"]))
        return r

    def _operator(self, units):
        """(the Mat the core iterates, σ): A, or under the default rule σA (a copy, made once)."""
        if units not in self._operators:
            sigma = _units_sigma(self.A)
            scaled = self.A.copy()
            scaled.scale(sigma)
            self._operators[units] = (scaled, sigma)
        return self._operators[units]

    def _core(self, _petsc, units, Am, opts, o):
        """(the core for this scaling, the set-up seconds this solve reports, the Solver's own set-up
        seconds among them): the core is built on its first solve, which also reports the Solver's set-up
        (the first solve of all; the build's seconds are the calling solve's own)."""
        if units not in self._cores:
            t0 = time.perf_counter()
            if self.method == "newton":
                h = o["hierarchy"]   # 'amg': built by the core (nrmicp/petsc/hierarchy.hpp)
                nnz = Am.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"]
                amg = h == "amg" or (h == "auto" and auto_builds_amg(Am.getSize()[0], nnz))
                Ps = [P.handle for P in self._levels[0]]
                core = _collective(self.comm, lambda: _petsc.Newton(Am.handle, opts, Ps, amg))
            else:
                core = _collective(self.comm, lambda: _petsc.Solver(Am.handle, opts))
            self._cores[units] = [core, time.perf_counter() - t0]   # (kept first: close() frees it whatever follows)
            if self.method == "newton":   # (every rank alike: a warning made an error raises on all)
                warn_shortened(hierarchy_report(core.hierarchy["requested"], None, core), o["hierarchy"])
        entry = self._cores[units]
        earlier, self._setup_seconds = self._setup_seconds, 0.0
        setup, entry[1] = entry[1] + earlier, 0.0
        return entry[0], setup, earlier


def _prolongations(hierarchy, Am, comm):
    """hierarchy= as the core's prolongation Mats, finest first, and those of them made here (the caller
    destroys them): PETSc Mats as given; a nrmicp.Hierarchy's
    prolongations or whole scipy matrices, the same on every rank (checked as nrmicp.solve checks a
    list, and against the other ranks'), as MPIAIJ Mats, level 0's rows in A's layout, each coarser
    level's split evenly over the ranks. The core forms the Galerkin operators of A itself (so a
    Hierarchy's own A does not matter here)."""
    if isinstance(hierarchy, Hierarchy):
        hierarchy = list(hierarchy.prolongations)
    if not isinstance(hierarchy, (list, tuple)):
        return [], []
    n = Am.getSize()[0]
    petsc = _collective(comm, _petsc_list, hierarchy)
    _same(comm, float(petsc), ValueError, _DIFFERENT_HIERARCHY)
    Ps = list(hierarchy) if petsc else _collective(comm, resolve_hierarchy, list(hierarchy),
                                                   types.SimpleNamespace(shape=(n, n))) or []
    shapes = repr([P.getSize() if petsc else (P.shape, _fingerprint(P)) for P in Ps])
    _same(comm, float(zlib.crc32(shapes.encode())), ValueError, _DIFFERENT_HIERARCHY)
    if petsc:
        return Ps, []
    made, (lo, hi) = [], Am.getOwnershipRange()
    for P in Ps:
        layout = PETSc.Vec().createMPI((PETSc.DECIDE, P.shape[1]), comm=comm)   # the coarse level's rows
        (clo, chi), _ = layout.getOwnershipRange(), layout.destroy()
        B = P[lo:hi]
        made.append(PETSc.Mat().createAIJ(size=((hi - lo, P.shape[0]), (chi - clo, P.shape[1])), comm=comm, csr=(
            B.indptr.astype(PETSc.IntType), B.indices.astype(PETSc.IntType), B.data)))
        lo, hi = clo, chi
    return made, made


#: The refusal of hierarchy options that differ between ranks.
_DIFFERENT_HIERARCHY = ("hierarchy must be the same on every rank ('amg', 'auto', None, or the whole prolongations, "
                        "or PETSc Mats); the ranks' differ in kind, number of levels, shapes or values")


def _same(comm, value: float, error: type, message: str) -> None:
    """error(message) raised on every rank (through agree: 'rank r: ...', as every other refusal) unless
    every rank holds this value (a kind of input, or a checksum of it)."""
    differ = _flag_max(comm, value) != -_flag_max(comm, -value)

    def check():
        if differ:
            raise error(message)
    _collective(comm, check)


def _petsc_list(hierarchy):
    """Whether a list of prolongations holds PETSc Mats (True) or matrices to convert (False); not both."""
    kinds = {isinstance(P, PETSc.Mat) for P in hierarchy}
    if len(kinds) > 1:
        raise TypeError("hierarchy must be a list of PETSc Mats or a list of scipy matrices, not both")
    return kinds == {True}


def _scoped(options, scopes, where, elsewhere):
    """TypeError naming the options of `options` outside these scopes (they belong `elsewhere`), then
    the table's checks (_options.validate) with the options PETSc cannot apply refused."""
    misplaced = sorted(k for k in options if k in _options.TABLE and _options.TABLE[k].scope not in scopes)
    if misplaced:
        raise TypeError(f"{where}() does not take {misplaced}: pass them to {elsewhere}")
    _options.validate(options, where=where, unsupported=_UNSUPPORTED)


def _collective_callback(comm, callback):
    """callback(k, z, res) with each call collective (a failure on one rank raises on all, no rank left
    waiting); StopIteration stops the solve as True does (nrmicp.solve's rule)."""
    def call(k, z, res):
        try:
            return callback(k, z, res)
        except StopIteration:
            return True
    return functools.partial(_collective, comm, call)


def _auto_method(Am, options, comm):
    """nrmicp.solve's method='auto' (choose_method), A's dominance margin reduced over the ranks."""
    return choose_method(None, options, _margin(Am, comm))


def _margin(Am, comm):
    """A's dominance_margin over every rank's rows (collective; a rank without rows has no say)."""
    indptr, _, vals = Am.getValuesCSR()
    rows = sp.csr_matrix((vals, np.zeros_like(vals, dtype=np.int32), indptr), shape=(len(indptr) - 1, 1))
    diagonal = _diagonal(Am)   # (collective: on every rank, rows or none)
    local = dominance_margin(rows, diagonal) if rows.shape[0] else math.inf
    return -_flag_max(comm, -local)


def _upper(upper, Am, zf, comm, method):
    """(This rank's rows of the upper bound, None: none; whether the problem is bounded, as
    _bounds.is_bounded on every rank's rows). A -inf entry of a constant ζ on any rank (a free row)
    makes every rank's problem a box problem: for the stationary members upper +inf where none is given.
    An implicit upper (an Affine, B a petsc4py Mat in A's layout, or a callable of this rank's rows) is
    the core's (make_zeta's tuple: a functor whose every call is collective)."""
    nloc = Am.getLocalSize()[0]
    if upper is None:
        free = zf.kind == _K.constant and _flag_max(comm, float(np.any(np.isneginf(zf.c)))) > 0
        return np.full(nloc, np.inf) if free and method != "newton" else None, free

    def local():
        _not_a_mat(upper, "upper")
        u = _make_upper(upper, nloc, _Rows(Am))
        _bounds.check(zf.kind, zf.c if zf.kind == _K.constant else None, u, method, None)
        return np.full(nloc, np.inf) if u is None else u   # (all +inf on this rank: the same core call as the others)
    u = _collective(comm, local)
    if not isinstance(u, _bounds.ImplicitUpper):   # (+inf on every rank's rows: no upper bound, as serially)
        bound = _flag_max(comm, float(np.any(u < np.inf)))
        return (u, True) if bound else _upper(None, Am, zf, comm, method)
    fn = CheckedZeta(_affine(u.B, u.c, Am) if u.kind == _K.affine else (lambda z: _collective(comm, u.fn, z)), nloc)
    fn.what = "upper(z)"
    return (_K.functor, None, None, None, None, fn), True


def _rounds(core, measure, xa, opts, o, jacobian, bounded, hint):
    """Either member on the PETSc engine (`core`: nrmicp::Newton or nrmicp::Solver over it) driven by
    the serial layer's rounds (_api._Rounds: Res of z re-measured where the core iterated another problem
    — a constant ζ's shifted LCP, the default rule's σA — and re-solved with a tighter tolerance when it
    misses tol) and settled by its _settle (polish, the status, the result's fields); `bounded`: polish
    is not run; `hint(status)`: _api.failure_hint's."""
    m, qa, (kind, c, fn, ua) = o["method"], measure.qa, measure.problem
    solver = types.SimpleNamespace(_core=core, method=m, n=len(qa), _dr=None, _dc=None)   # (a serial Solver's shape)
    problem = (qa, kind, c, fn)
    verify = measure.weights is not None or kind == _core.ZetaKind.constant
    it = {**{k: o[k] for k in _options.names("solve")}, "tol": opts.tol, "rtol": 0.0}
    rounds = _Rounds(solver, problem, it, None, {"upper": ua, "zeta_jacobian": jacobian}, measure if verify else None, xa)
    cb = o["callback"]   # (distributed's callback(k, z, res), each rank's rows; k counts on over re-solves)
    rounds.cb = None if cb is None else (lambda k, z, r: cb(k + rounds.cb_offset[0], z, r))
    failed = []   # a progress line that raised (rank 0's: the only one the core calls), raised on every rank after
    rounds.progress = lambda method, n: _deferred(_progress_hook(method, n), failed)
    rounds.run(xa, opts.tol)
    agree(measure.Am.getComm(), failed[0] if failed else None)
    report = hierarchy_report(core.hierarchy["requested"], None, core) if m == "newton" else None
    return _settle(solver, rounds, problem, measure, opts.tol, polish=m == "newton" and o["polish"], bounded=bounded,
                   report=report, hint=hint)


def _deferred(hook, failed):
    """`hook` keeping its first exception in `failed` (its later calls skipped) instead of raising it: the
    core calls the progress hook on rank 0 only, between collectives that the other ranks wait in."""
    def call(*args):
        if not failed:
            try:
                hook(*args)
            except Exception as exc:  # noqa: BLE001 - raised on every rank once the core returns
                failed.append(exc)
    return call


class _Measure:
    """(w, Res) of z on the problem the core iterates, every rank's rows, as _api._OriginalResidual
    for _Rounds and _criterion_outcome: `user` (A, q) under the default rule, whose ``weighted=False``
    is the paper's Res in the user's units."""

    def __init__(self, _petsc, Am, qa, problem, user):
        self._petsc, self.Am, self.qa, self.problem, self.user = _petsc, Am, qa, problem, user
        self.weights = None if user is None else (None, None)

    def __call__(self, z, weighted=True):
        A, q = (self.Am, self.qa) if weighted or self.user is None else self.user
        d = self._petsc.measure(A.handle, q, *self.problem, z)
        return d["w"], d["residual"]

    def rounding_level(self, z):
        return self._petsc.measure(self.Am.handle, self.qa, *self.problem, z, rounding=True)["rounding_level"]


def _jacobian(zeta_jacobian, zf, method, Am, comm):
    """ζ's Jacobian for the core (None: none given): zeta_jacobian(z) of this rank's rows returns a
    linear operator on them (its matvec may communicate: every rank calls it together) or a diagonal
    matrix; nrmicp.solve's checks, each call of the user's code collective. (An Affine ζ takes the outer
    fixed point here: its B as an operator ζ′ fails where the serial member's factorized B converges.)"""
    if not _collective(comm, check_jacobian, zeta_jacobian, method, zf.kind):
        return None
    return core_jacobian(zeta_jacobian, Am.getLocalSize()[0], PETSc.IntType, collective=functools.partial(_collective, comm))


def _owns_rows(Am):
    """The Newton member's driver takes its per-level decisions from each rank's rows: a rank without
    any would take other branches than its peers (a stationary member works there)."""
    if Am.getLocalSize()[0] == 0:
        raise ValueError("A has no rows on this rank: method 'newton' needs at least one row of A on every rank "
                         "(the stationary members, e.g. method='nrmgs', do not)")


def _units_sigma(Am):
    """The default rule's σ (nrmicp._scaling.units_factor) from global sums over the diagonal."""
    a = np.abs(_diagonal(Am))
    comm = Am.getComm()
    logs = _flag_sum(comm, float(np.sum(np.log2(a[a > 0]))))
    return sigma_from_logs(logs, int(round(_flag_sum(comm, float(np.count_nonzero(a > 0))))))


def _mean_abs_diagonal(Am):
    """mean |a_ii| over every rank's rows (collective)."""
    return _flag_sum(Am.getComm(), float(np.sum(np.abs(_diagonal(Am))))) / Am.getSize()[0]


def _diagonal(Am):
    """This rank's a_ii as a numpy array (collective: the Vec PETSc makes is destroyed on every rank
    together, not left to each rank's garbage collector)."""
    d = Am.getDiagonal()
    out, _ = np.array(d.getArray(readonly=True)), d.destroy()
    return out


def gather(v):
    """A distributed Vec as one numpy array on rank 0 (None on the other ranks); collective."""
    scatter, out = PETSc.Scatter.toZero(v)
    scatter.scatter(v, out, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
    arr = out.getArray().copy() if v.getComm().getRank() == 0 else None
    scatter.destroy()
    out.destroy()
    return arr
