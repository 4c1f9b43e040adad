"""nrmicp on PETSc over MPI: every member is the serial library's C++ (nrmicp::Newton, and nrmicp::Solver as
synchronous multisplitting) on the PETSc engine (nrmicp._petsc), settled by the serial layer's code (nrmicp._api).
This module is glue: argument checks and conversion, layouts, the calls into the core. Every rank calls
:func:`solve` (``mpirun -n P python script.py``) with the same arguments for its own rows; a failure on any
rank raises on every rank. What runs where, and how it scales: docs/DISTRIBUTED.md.
"""
from __future__ import annotations

import functools
import math
import time
import types

import numpy as np
import scipy.sparse as sp

try:
    from petsc4py import PETSc
except ImportError as exc:  # the core package needs no MPI; this module does
    raise ImportError("nrmicp.distributed needs petsc4py, PETSc (with hypre) and MPI: README, 'Beyond one machine' "
                      f"(make mpideps installs them on Debian); {exc}") from exc

from . import _bounds, _core, _mpi, _options
from ._mpi import DistributedError, agree, collective as _collective, flag_max as _flag_max, flag_sum as _flag_sum
from ._newton import (auto_builds_amg, check_jacobian, check_no_hierarchy, check_polish, core_jacobian, hierarchy_report,
                      warn_shortened)
from ._api import (METHODS as _ALL_METHODS, Result, _make_upper, _make_zeta, _Rounds, _choice, _criterion, _settle,
                   _log_final, _omega2_hint, _progress_hook, _units_parameters, core_options, choose_method,
                   check_callback, dominance_margin, failure_hint, implied_method)
from ._scaling import sigma_from_logs, weights_of_rows
from ._hierarchy import Hierarchy, _fingerprint, hierarchy_kind, resolve_hierarchy
from ._inputs import as_constant, as_csr, as_vector
from ._zeta import CheckedZeta

__all__ = ["solve", "Solver", "gather", "METHODS", "DistributedError"]
_K = _core.ZetaKind

#: The distributed members: every member of nrmicp (the stationary ones as synchronous multisplitting).
METHODS = _ALL_METHODS
# ----------------------------------------------------------------------------- inputs
def _check_mat(A):
    """A's local checks: a petsc4py Mat (its layout the engine's to check: _member), or a scipy row block (as
    nrmicp.solve checks A)."""
    if isinstance(A, PETSc.Mat):
        return A
    if not sp.issparse(A):
        raise TypeError(f"A must be a petsc4py Mat or this rank's scipy.sparse row block, got {type(A).__name__}")
    try:
        return as_csr(A, "A", square=False, warn=False)   # (nrmicp.solve's checks; PETSc copies it)
    except ValueError as exc:
        raise ValueError(f"{exc} (of this rank's block of rows: its rows count from the block's first)") from None


def _as_mat(B, comm):
    """This rank's CSR rows -> an MPIAIJ Mat (collective); ValueError when not square in all."""
    N = int(_flag_sum(comm, float(B.shape[0])))

    def columns():
        if B.shape[1] != N:
            raise ValueError(f"A's row blocks must together be square: this rank's block has {B.shape[1]} "
                             f"columns, the blocks have {N} rows in all")
    _collective(comm, columns)
    return _aij(B, (B.shape[0], N), (B.shape[0], N), comm)


def _aij(B, rows, cols, comm):
    """This rank's CSR rows B as an MPIAIJ Mat of (local, global) `rows` and `cols` (collective)."""
    return PETSc.Mat().createAIJ(size=(rows, cols), comm=comm,
                                 csr=(B.indptr.astype(PETSc.IntType), B.indices.astype(PETSc.IntType), B.data))


def _local(v, A, name, *, scalar_ok=False, infinite=0):
    """A Vec in A's row layout or this rank's rows -> a new float64 array (`infinite`: as in as_constant)."""
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
    """The core's Options from nrmicp.solve's options `o` (tol, rtol as resolved in `it`), checked by the serial
    code; those PETSc cannot apply to this member (the option table's `distributed` column) refused naming them."""
    refused = _options.distributed_refusals(method)
    _options.validate({k: o[k] for k in refused}, where="distributed.solve", unsupported=refused)
    return core_options(o, method, nloc, {**{k: o[k] for k in _options.names("solve")}, "tol": it["tol"], "rtol": it["rtol"]})


class _Rows:
    """How _api._make_zeta and _bounds.as_upper read ζ's and upper's parts: a Mat in A's layout, this rank's rows."""

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


def _core_zeta(kind, c, B, fn, A, comm):
    """The core's (kind, c, fn) of ζ as _make_zeta read it: an affine or callable ζ as a functor whose every call
    is collective (made after every rank's checks: its Vecs are collective)."""
    if kind in (_K.none, _K.constant):
        return kind, c, None
    checked = None if fn is None else CheckedZeta(fn, A.getLocalSize()[0])   # (NaN raises: on every rank)
    return _K.functor, None, _functor(kind, B, c, checked, A, comm, "zeta(z)")


def _functor(kind, B, c, fn, A, comm, what):
    """An affine part (B z + c, PETSc's product) or a callable as the core's functor of this rank's rows, every
    call collective (a failure on any rank raises on all, in the same call of the driver)."""
    out = CheckedZeta(_affine(B, c, A) if kind == _K.affine else functools.partial(_collective, comm, fn),
                      A.getLocalSize()[0])
    out.what, out.finite = what, False   # (fn checks its values; an overflowing B z + c is the core's to judge)
    return out


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
    """A's checks and the member, every rank's failure raised on all: (Am, method); the set-up options `o`
    checked too (tol, rtol at their defaults). A Mat made here is destroyed on failure."""
    A_in = _collective(comm, _check_mat, A)
    _mpi.same(comm, float(sp.issparse(A_in)), TypeError,   # (else the ranks would part ways: a hang)
              "A must be a petsc4py Mat on every rank or a scipy row block on every rank, not both")
    Am = _as_mat(A_in, comm) if sp.issparse(A_in) else A_in
    try:
        return Am, _member(Am, comm, o)
    except Exception:
        if Am is not A_in:
            Am.destroy()   # on every rank together (each raises here)
        raise


def _member(Am, comm, o):
    """The member for Am and the set-up options `o`, checked on every rank ('auto': nrmicp.solve's rule, A's
    dominance margin reduced over the ranks), and A as the PETSc engine needs it."""
    from . import _petsc   # (the engine's rules, as its cores check them: A's layout now, its diagonal after the options)
    _collective(comm, _petsc.check_layout, Am.handle)
    nloc, method = Am.getLocalSize()[0], o["method"]
    if isinstance(method, str) and method.lower() == "auto":
        method = choose_method(None, o, _margin(Am, comm))

    def local():
        m = _choice(method, METHODS, "method")
        if Am.getSize()[0] == 0:
            raise ValueError("A must have at least one row, got shape (0, 0)")
        _core_options(o, m, nloc, _criterion({"tol": o["tol"], "rtol": o["rtol"]})[0])
        hierarchy = o["hierarchy"]
        if m != "newton":
            check_no_hierarchy(hierarchy, m)
            return m
        check_polish(o["polish"])
        _owns_rows(Am)
        hierarchy_kind(hierarchy)
        return m
    m = _collective(comm, local)
    _collective(comm, _petsc.check_diagonal, Am.handle)
    return m


def _prepare_call(Am, m, q, zeta, x0, comm, o, it):
    """A solve's local checks, every rank's failure raised on all: (core Options, this rank's q and x0, ζ's parts
    as _make_zeta reads them: kind, c, B, fn)."""
    nloc = Am.getLocalSize()[0]

    def local():
        checked = _core_options(o, m, nloc, it), _local(q, Am, "q"), None if x0 is None else _local(x0, Am, "x0")
        check_callback(o["callback"])
        _not_a_mat(zeta, "zeta")
        return (*checked, _make_zeta(zeta, nloc, _Rows(Am)))
    return _collective(comm, local)


def solve(A, q, zeta=None, *, upper=None, comm=None, **options) -> Result:
    """Solve ICP(q, A, ζ) on every rank of A's communicator (call it on every rank) with :func:`nrmicp.solve`'s
    options, defaults and checks; those PETSc cannot apply (the option table's ``distributed`` column,
    ``nrmicp._options.distributed_refusals``) raise a ValueError naming them.

    A: a petsc4py Mat (AIJ, square, equal row and column layouts) or this rank's scipy.sparse row block
    (n_local, n), of one kind on every rank (without ``comm`` each rank's default is its A's communicator or
    PETSc.COMM_WORLD, so a mix of kinds cannot be seen). q, x0 and a vector upper: a Vec in A's row layout or
    this rank's rows. zeta, and an implicit upper: None, a constant, :class:`nrmicp.Affine` (B a petsc4py Mat
    in A's layout) or a callable of this rank's rows (a row-local ζ). zeta_jacobian(z) of this rank's rows: a
    linear operator on them (its matvec is called on every rank together: it may communicate) or a sparse
    matrix. hierarchy ('newton'): 'amg' (BoomerAMG's), 'auto', None, or prolongations, finest first: PETSc
    Mats, or a :class:`nrmicp.Hierarchy` or whole scipy matrices, the same on every rank. callback: as
    nrmicp.solve's (``callback(zk)`` or ``callback(intermediate_result)``) with this rank's rows of z; a stop on
    any rank stops every rank. The stationary members run as synchronous
    multisplitting of each rank's diagonal block.

    Returns a :class:`nrmicp.Result` on every rank, ``z`` and ``w`` as PETSc Vecs (:func:`gather`). A failure
    on any rank raises on every rank. What runs, the options, the scaling: docs/DISTRIBUTED.md.
    """
    comm = comm or (A.getComm() if isinstance(A, PETSc.Mat) else PETSc.COMM_WORLD)
    _collective(comm, lambda: _options.validate(options, where="distributed.solve",
                                                         unsupported=_options.distributed_refusals()))
    method = implied_method(options.get("method", "auto"), zeta, upper, options.get("zeta_jacobian"))
    setup = {k: v for k, v in {**options, "method": method}.items() if _options.TABLE[k].scope != "call"}
    t0 = time.perf_counter()
    with Solver(A, comm=comm, **setup) as solver:
        r = solver.solve(q, zeta, upper=upper, **{k: v for k, v in options.items() if k not in setup})
    r.timings["total"] = time.perf_counter() - t0
    return r


class Solver:
    """:class:`nrmicp.Solver` on PETSc: A checked and its member chosen once, the core (nrmicp::Newton or
    nrmicp::Solver on the PETSc engine: hierarchy, Galerkin operators, reduced solvers) built on the first solve
    that needs it and kept, then solved for many q, ζ, x0. :func:`solve` is one Solver's one solve.

    ``Solver(A, *, comm=None, **options)`` takes :func:`solve`'s set-up options and per-solve defaults;
    ``solve(q, zeta=None, *, upper=None, **options)`` the per-solve ones and each call's own (x0, callback,
    zeta_jacobian), as :meth:`nrmicp.Solver.solve`. Call both on every rank. The default rule (tol and rtol
    None) iterates on σA, the paper's tol on A: one core each. ``close()`` (or ``with``) frees the cores on
    every rank together (PETSc frees MUMPS factors collectively: a garbage collector's timing deadlocks);
    a closed Solver raises on solve."""

    def __init__(self, A, *, comm=None, **options):
        t0 = time.perf_counter()
        self.comm = comm = comm or (A.getComm() if isinstance(A, PETSc.Mat) else PETSc.COMM_WORLD)
        _collective(comm, _scoped, options, ("setup", "solve"), "distributed.Solver", "its solve()")
        self._options = {**_options.defaults("setup", "solve"), **options}
        o = {**_options.defaults(), **self._options}
        _mpi.agree_arguments(comm, self._options, "distributed.Solver")
        self.A, self.method = _prepare_matrix(A, comm, o)
        self._owns_A = self.A is not A   # (made from scipy row blocks)
        mean = _flag_sum(comm, float(np.sum(_diagonal(self.A)))) / self.A.getSize()[0] if self.method == "nrm" else 1.0
        self._omega2_hint = _omega2_hint(mean, self.method, o["omega2"], o["accelerate"])   # (nrm's only)
        try:   # given prolongations checked and made PETSc Mats now, once (kept until close)
            self._levels = _prolongations(o["hierarchy"], self.A, comm) if self.method == "newton" else ([], [])
        except Exception:
            if self._owns_A:
                self.A.destroy()   # on every rank together (each raises here)
            raise
        self._cores = {}   # units (the default rule's σA) -> [the core, its set-up seconds not yet reported]
        self._operators = {False: (self.A, 1.0, None)}   # units -> (the Mat the core iterates, σ, the rule's row weights)
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
        for units, (mat, _, _) in self._operators.items():   # σA, and an A made from scipy row blocks
            if units or self._owns_A:
                mat.destroy()
        for P in self._levels[1]:   # the prolongation Mats made from scipy matrices
            P.destroy()
        self._cores, self._operators, self._levels, self._closed = {}, {}, ([], []), True

    def solve(self, q, zeta=None, *, upper=None, **options) -> Result:
        """ICP(q, A, ζ) with this Solver's A: :func:`solve`'s arguments but A, comm and the set-up options."""
        from . import _petsc
        comm, A, m = self.comm, self.A, self.method
        if self._closed:
            raise ValueError("this distributed.Solver was closed")
        PETSc.garbage_cleanup(comm)   # (earlier Results' Vecs: petsc4py frees parallel objects only collectively)
        _collective(comm, _scoped, options, ("solve", "call"), "distributed.Solver.solve", "distributed.Solver()")
        o = {**_options.defaults(), **self._options, **options, "method": m}
        given = {**{k: o[k] for k in _options.names("solve", "call")}, "zeta": zeta, "upper": upper}
        _mpi.agree_arguments(comm, given, "distributed.Solver.solve")
        t_start = time.perf_counter()
        it, units = _criterion({"tol": o["tol"], "rtol": o["rtol"]})
        opts, q_user, xa, (kind, c, B, fn) = _prepare_call(A, m, q, zeta, o["x0"], comm, o, it)
        core_upper, bounded = _upper(upper, A, (kind, c), comm, m)
        core_zeta = _core_zeta(kind, c, B, fn, A, comm)
        Am, sigma, rows = self._operator(units)
        if units:   # the iteration runs on σA, σq; Res_E is measured on D(Az + q) (_scaling.units_weights)
            _units_parameters(opts, m, sigma, len(q_user))
        measure = _Measure(_petsc, sigma * q_user, (*core_zeta, core_upper), (A, q_user), rows)
        jacobian = _jacobian(o["zeta_jacobian"], kind, m, Am, comm)
        if opts.rtol > 0:   # the absolute target, on the problem the core iterates (Options::target of Res(0))
            opts.tol, opts.rtol = opts.target(measure(np.zeros_like(q_user))[1]), 0.0
        core, setup, earlier = self._core(_petsc, units, Am, opts, o)
        hint = failure_hint(m, self._omega2_hint, lambda: _margin(A, comm), units, kind)
        fields = _rounds(core, measure, xa, opts, o, jacobian, bounded, hint)
        fields["timings"]["setup"] += setup
        fields["timings"]["total"] = time.perf_counter() - t_start + earlier   # (the core's build is in this call)
        r = Result(**{**fields, "z": _vec(A, fields["z"]), "w": _vec(A, fields["w"])}, ranks=comm.getSize())
        if opts.verbose > 0:   # (a logger that raises on rank 0 raises on every rank)
            _collective(comm, lambda: comm.getRank() == 0 and _log_final(m, r, r.timings["total"]))
        return r

    def _operator(self, units):
        """(the Mat the core iterates, σ, the default rule's row weights D or None): A, or under the default rule σA
        (a copy, made once) and D."""
        if units not in self._operators:
            from . import _petsc
            sigma, scaled = _units_sigma(self.A), self.A.copy()
            scaled.scale(sigma)
            self._operators[units] = (scaled, sigma, weights_of_rows(_petsc.row_max_abs(self.A.handle), sigma))
        return self._operators[units]

    def _core(self, _petsc, units, Am, opts, o):
        """(the core for this scaling, built on its first solve; the set-up seconds this solve reports; the
        Solver's own among them: reported by its first solve)."""
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
    """(the core's prolongation Mats, finest first; those made here, destroyed by the caller): PETSc Mats as
    given; a nrmicp.Hierarchy's or whole scipy matrices, checked as nrmicp.solve checks a list and against the
    other ranks', as MPIAIJ Mats (level 0's rows in A's layout, each coarser level's split evenly)."""
    if isinstance(hierarchy, Hierarchy):   # (built on A: this rank's rows against its A's, as serially)
        indptr, indices, data = Am.getValuesCSR()
        mine = sp.csr_matrix((data, indices, indptr), shape=(len(indptr) - 1, Am.getSize()[1]))
        _collective(comm, hierarchy.check_fits, mine, Am.getOwnershipRange())
        hierarchy = list(hierarchy.prolongations)
    if not isinstance(hierarchy, (list, tuple)):
        return [], []
    n = Am.getSize()[0]
    petsc = _collective(comm, _petsc_list, hierarchy)
    _mpi.same(comm, float(petsc), ValueError, _DIFFERENT_HIERARCHY)
    Ps = list(hierarchy) if petsc else _collective(comm, resolve_hierarchy, list(hierarchy),
                                                   types.SimpleNamespace(shape=(n, n))) or []
    shapes = repr([P.getSize() if petsc else (P.shape, _fingerprint(P)) for P in Ps])
    _mpi.same(comm, shapes, ValueError, _DIFFERENT_HIERARCHY)
    if petsc:
        return Ps, []
    made, (lo, hi) = [], Am.getOwnershipRange()
    for P in Ps:
        layout = PETSc.Vec().createMPI((PETSc.DECIDE, P.shape[1]), comm=comm)   # the coarse level's rows
        (clo, chi), _ = layout.getOwnershipRange(), layout.destroy()
        made.append(_aij(P[lo:hi], (hi - lo, P.shape[0]), (chi - clo, P.shape[1]), comm))
        lo, hi = clo, chi
    return made, made


#: The refusal of hierarchy options that differ between ranks.
_DIFFERENT_HIERARCHY = ("hierarchy must be the same on every rank ('amg', 'auto', None, or the whole prolongations, "
                        "or PETSc Mats); the ranks' differ in kind, number of levels, shapes or values")


def _petsc_list(hierarchy):
    """Whether a list of prolongations holds PETSc Mats (True) or matrices to convert (False); not both."""
    kinds = {isinstance(P, PETSc.Mat) for P in hierarchy}
    if len(kinds) > 1:
        raise TypeError("hierarchy must be a list of PETSc Mats or a list of scipy matrices, not both")
    return kinds == {True}


def _scoped(options, scopes, where, elsewhere):
    """TypeError naming the options outside these scopes (they belong `elsewhere`); then _options.validate."""
    misplaced = sorted(k for k in options if k in _options.TABLE and _options.TABLE[k].scope not in scopes)
    if misplaced:
        raise TypeError(f"{where}() does not take {misplaced}: pass them to {elsewhere}")
    _options.validate(options, where=where, unsupported=_options.distributed_refusals())


def _margin(Am, comm):
    """A's dominance_margin over every rank's rows (collective; a rank without rows has no say)."""
    indptr, _, vals = Am.getValuesCSR()
    rows = sp.csr_matrix((vals, np.zeros_like(vals, dtype=np.int32), indptr), shape=(len(indptr) - 1, 1))
    diagonal = _diagonal(Am)   # (collective: on every rank, rows or none)
    return -_flag_max(comm, -(dominance_margin(rows, diagonal) if rows.shape[0] else math.inf))


def _upper(upper, Am, zeta, comm, method):
    """(this rank's rows of the upper bound, None where they have none (the core bounds them by +inf when
    another rank's are bounded), or the core's functor of an implicit one; whether the problem is bounded,
    _bounds.is_bounded over every rank's rows). `zeta`: (kind, c)."""
    nloc, (kind, c) = Am.getLocalSize()[0], zeta

    def local():
        _not_a_mat(upper, "upper")
        u = _make_upper(upper, nloc, _Rows(Am))
        try:
            _bounds.check(kind, c if kind == _K.constant else None, u, method, None)
        except ValueError as exc:
            raise ValueError(f"{exc} (indices of this rank's rows, which start at global row "
                             f"{Am.getOwnershipRange()[0]})") from None
        return u
    u = None if upper is None else _collective(comm, local)
    if isinstance(u, _bounds.ImplicitUpper):
        return (_K.functor, None, None, None, None, _functor(u.kind, u.B, u.c, u.fn, Am, comm, "upper(z)")), True
    return u, _flag_max(comm, float(_bounds.is_bounded(c if kind == _K.constant else None, u))) > 0


def _rounds(core, measure, xa, opts, o, jacobian, bounded, hint):
    """The fields of a Result: `core` (either member on the PETSc engine) run by the serial layer's rounds
    (_api._Rounds: Res re-measured where the core iterated another problem, re-solved when it misses tol) and
    settled by its _settle (polish unless `bounded`, the status, `hint(status)`: _api.failure_hint's)."""
    m, qa, (kind, c, fn, ua), comm = o["method"], measure.qa, measure.problem, measure.user[0].getComm()
    solver = types.SimpleNamespace(_core=core, method=m, n=len(qa), _dr=None, _dc=None)   # (a serial Solver's shape)
    problem = (qa, kind, c, fn)
    verify = measure.weights is not None or kind == _core.ZetaKind.constant
    it = {**{k: o[k] for k in _options.names("solve")}, "tol": opts.tol, "rtol": 0.0}
    rounds = _Rounds(solver, problem, it, o["callback"], {"upper": ua, "zeta_jacobian": jacobian},
                     measure if verify else None, xa)
    if rounds.cb is not None:   # nrmicp.solve's callback, each call collective (a failure on one rank raises on all)
        rounds.cb = functools.partial(_collective, comm, rounds.cb)
    failed = []   # a progress line that raised (rank 0's: the only one the core calls), raised on every rank after
    rounds.progress = lambda method, n: _mpi.deferred(_progress_hook(method, n), failed)
    _collective(comm, rounds.run, xa, opts.tol)   # (the core's refusals during the run, as every other: 'rank r: ')
    agree(comm, failed[0] if failed else None)
    report = hierarchy_report(core.hierarchy["requested"], None, core) if m == "newton" else None
    return _settle(solver, rounds, problem, measure, opts.tol, polish=m == "newton" and o["polish"], bounded=bounded,
                   report=report, hint=hint)


class _Measure:
    """_api._OriginalResidual on PETSc: (w, Res) of z on the user's (A, q), w = Az + q: the paper's Res, or the
    default rule's Res_E on D w (`rows`: D) unless ``weighted=False``. `qa`: the q of the problem the core iterates."""

    def __init__(self, _petsc, qa, problem, user, rows):
        self._petsc, self.qa, self.problem, self.user, self.rows = _petsc, qa, problem, user, rows
        self.weights = None if rows is None else (None, None)

    def __call__(self, z, weighted=True):
        d = self._measure(z, self.rows if weighted else None)
        return d["w"], d["residual"]

    def rounding_level(self, z):
        return self._measure(z, self.rows, rounding=True)["rounding_level"]

    def _measure(self, z, rows, rounding=False):
        A, q = self.user
        return self._petsc.measure(A.handle, q, *self.problem, z, rounding, rows)


def _jacobian(zeta_jacobian, kind, method, Am, comm):
    """ζ's Jacobian for the core (None: none given), nrmicp.solve's checks; every call of the user's code
    collective (an operator's matvec may communicate). An Affine ζ runs the outer fixed point here."""
    if not _collective(comm, check_jacobian, zeta_jacobian, method, kind):
        return None
    return core_jacobian(zeta_jacobian, Am.getLocalSize()[0], PETSc.IntType, collective=functools.partial(_collective, comm))


def _owns_rows(Am):
    """The Newton driver decides from each rank's rows: a rank without any would part ways with its peers."""
    if Am.getLocalSize()[0] == 0:
        raise ValueError("A has no rows on this rank: method 'newton' needs at least one row of A on every rank "
                         "(the stationary members, e.g. method='nrmgs', do not)")


def _units_sigma(Am):
    """The default rule's σ (nrmicp._scaling.units_factor) from global sums over the diagonal."""
    a = np.abs(_diagonal(Am))
    comm = Am.getComm()
    logs = _flag_sum(comm, float(np.sum(np.log2(a[a > 0]))))
    return sigma_from_logs(logs, int(round(_flag_sum(comm, float(np.count_nonzero(a > 0))))))


def _diagonal(Am):
    """This rank's a_ii (collective: PETSc's Vec destroyed on every rank together, not by a garbage collector)."""
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
