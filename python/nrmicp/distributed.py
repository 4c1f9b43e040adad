"""nrmicp beyond one machine: the Newton member and the AOR-type NRM members on PETSc over MPI.

Run under ``mpirun -n P python script.py``; every rank calls :func:`solve` with the same
arguments for its own rows. A is a petsc4py ``Mat`` (MPIAIJ; or each rank's CSR row block, a
scipy matrix of shape (n_local, n)), q a petsc4py ``Vec`` with A's row layout (or each rank's
rows as a numpy array). The heavy work is PETSc's: products, PtAP, KSP (CG / BiCGSTAB) with
hypre BoomerAMG, whose classical prolongations (P >= 0, read through PCHMG) are the hierarchy
of the nested iteration. Option names, their checks, the statuses and the result fields are the
serial library's (nrmicp._api, nrmicp._core): one definition.

What is distributed: everything per iteration (products, reductions, the reduced solves, ζ on
each rank's rows). What is not: the hierarchy's set-up is hypre's (itself parallel); a callable
ζ sees only the rank's own rows (an entry-wise or row-local ζ); :func:`gather` copies z to
rank 0 (small problems only).
"""
from __future__ import annotations

import contextlib
import math
import time
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

try:
    from petsc4py import PETSc
except ImportError as exc:  # the core package needs no MPI; this module does
    raise ImportError("nrmicp.distributed needs petsc4py, PETSc (with hypre) and MPI: README, 'Beyond one machine' "
                      f"(make mpideps installs them on Debian); {exc}") from exc

from . import _core
from ._api import (Affine, Result, Status, _checked, _choice, _criterion, _iteration_options, _scalar,
                   at_rounding_floor)
from ._scaling import sigma_from_logs
from ._inputs import as_constant, as_diagonal, as_vector
from ._zeta import CheckedZeta

__all__ = ["solve", "gather", "METHODS", "DistributedError"]

#: The distributed members: Newton, and the AOR-type NRM members as synchronous multisplitting.
METHODS = ("newton", "nrmj", "nrmgs", "nrmsor", "nrmaor")
#: AOR parameters (alpha, beta) the members fix; None: the user's (default 1, beta = alpha).
_AOR_FIXED = {"nrmj": (1.0, 0.0), "nrmgs": (1.0, 1.0)}
#: Longest error message exchanged between ranks (bytes, UTF-8).
_MSG_LEN = 1024
#: Exception types re-raised as themselves on every rank; others become DistributedError.
_KNOWN = {e.__name__: e for e in (ValueError, TypeError, ZeroDivisionError, FloatingPointError,
                                  ArithmeticError, RuntimeError, KeyError, IndexError, MemoryError)}
#: Newton steps' acceptance window (the serial member's non-monotone rule: detail/globalization.hpp).
_WINDOW = 5
#: The serial member's constants (NewtonRun, Globalized), read from the core: one definition.
_TUNING = _core.newton_tuning


class DistributedError(RuntimeError):
    """An exception of a type this module does not re-create, raised on one rank; every rank
    raises it with the original type's name and message."""


# ----------------------------------------------------------------------------- collectives
def _flag_max(comm, value: float) -> float:
    """max over ranks of one float (a one-entry-per-rank Vec: PETSc's own allreduce)."""
    v = PETSc.Vec().createMPI((1, PETSc.DECIDE), comm=comm)
    v.setValue(v.getOwnershipRange()[0], value)
    v.assemble()
    out = v.max()[1]
    v.destroy()
    return out


def _sum(comm, value: float) -> float:
    """sum over ranks of one float (a one-entry-per-rank Vec)."""
    v = PETSc.Vec().createMPI((1, PETSc.DECIDE), comm=comm)
    v.setArray([value])
    out = v.sum()
    v.destroy()
    return out


def _agree(comm, exc: BaseException | None) -> None:
    """Every rank calls this after a step that may fail on some ranks only. When any rank
    failed, every rank raises the same exception (type and message of the lowest failing rank,
    prefixed 'rank r: '); else returns. Collective: no rank is left waiting."""
    if not _flag_max(comm, 0.0 if exc is None else 1.0):
        return
    size = comm.getSize()
    buf = np.zeros(_MSG_LEN)
    if exc is not None:
        text = f"{type(exc).__name__}\x01{exc}".encode("utf-8")[: _MSG_LEN - 1]
        buf[: len(text)] = np.frombuffer(text, dtype=np.uint8)
    v = PETSc.Vec().createMPI((_MSG_LEN, PETSc.DECIDE), comm=comm)
    v.setArray(buf)
    scatter, out = PETSc.Scatter.toAll(v)
    scatter.scatter(v, out, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
    rows = out.getArray().reshape(size, _MSG_LEN)
    for r in range(size):
        if rows[r, 0]:
            raw = bytes(rows[r][rows[r] > 0].astype(np.uint8)).decode("utf-8", "replace")
            name, _, msg = raw.partition("\x01")
            cls = _KNOWN.get(name)
            err = cls(f"rank {r}: {msg}") if cls else DistributedError(f"rank {r}: {name}: {msg}")
            raise err from exc


def _collective(comm, fn, *args):
    """fn(*args) on every rank; an exception on any rank is raised on all (see _agree)."""
    try:
        out, exc = fn(*args), None
    except Exception as e:  # noqa: BLE001 - re-raised on every rank by _agree
        out, exc = None, e
    _agree(comm, exc)
    return out


# ----------------------------------------------------------------------------- inputs
def _check_mat(A):
    """A's local checks: a square AIJ Mat with equal row and column layouts, or a scipy row block
    (returned as canonical float64 CSR)."""
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
    B = sp.csr_matrix(A, dtype=np.float64, copy=True)
    B.sum_duplicates()
    B.sort_indices()
    if not np.all(np.isfinite(B.data)):
        raise ValueError("A must be finite (this rank's rows hold NaN or Inf)")
    return B


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


def _local(v, A, name, *, scalar_ok=False):
    """q, zeta's c, x0 -> this rank's rows as a new float64 array (local checks only: no rank
    waits for another here; the user's object is never modified)."""
    lo, hi = A.getOwnershipRange()
    if isinstance(v, PETSc.Vec):
        if v.getOwnershipRange() != (lo, hi) or v.getSize() != A.getSize()[0]:
            raise ValueError(f"{name}'s layout (rows {v.getOwnershipRange()} of {v.getSize()}) does not match "
                             f"A's rows ({lo}, {hi}) of {A.getSize()[0]}")
        v = v.getArray(readonly=True)
    try:
        return np.array(as_constant(v, hi - lo, name) if scalar_ok else as_vector(v, hi - lo, name))
    except ValueError as exc:
        raise ValueError(f"{exc} (indices of this rank's rows, which start at global row {lo})") from None


def _vec(A, arr):
    """A new Vec in A's row layout holding arr (collective)."""
    out = A.createVecLeft()
    out.setArray(arr)
    return out


def _check_options(method, n, tol, maxiter, omega1, omega2, gamma, alpha, beta, nloc, rtol=0.0):
    """The serial library's checks (nrmicp._api and the core's Options.check)."""
    method = _choice(method, METHODS, "method")
    opts = _iteration_options(_core.Options(), tol=tol, rtol=rtol, maxiter=maxiter, z_update="auto", accelerate="none",
                              anderson_m=5, theta=1.0, record_history=False, stall_iterations=100)
    opts.method = getattr(_core.Method, method)
    opts.gamma = _scalar(gamma, "gamma")
    if method in _AOR_FIXED and (alpha is not None or beta is not None):
        raise ValueError(f"method {method!r} fixes alpha and beta; use 'nrmaor' or 'nrmsor' to set them")
    opts.alpha = math.nan if alpha is None else _scalar(alpha, "alpha")
    opts.beta = math.nan if beta is None else _scalar(beta, "beta")
    _checked(opts, n)
    w1 = as_diagonal(omega1, nloc, "omega1", positive=True)
    w2 = as_diagonal(omega2, nloc, "omega2", positive=True)
    return method, w1, w2


class _Zeta:
    """ζ on this rank's rows: kind 0 none, 1 constant Vec c, 2 Affine (B Mat, c Vec), 3 callable."""

    def __init__(self, zeta, A, comm):
        """Local checks only; make() creates the vectors (collective)."""
        self.comm, self.B, self.c, self.fn = comm, None, None, None
        n = A.getSize()[0]
        if zeta is None:
            self.kind = 0
        elif isinstance(zeta, Affine):
            self.kind = 2
            if not isinstance(zeta.B, PETSc.Mat):
                raise TypeError(f"zeta.B must be a petsc4py Mat in A's layout, got {type(zeta.B).__name__}")
            if zeta.B.getSize() != (n, n) or zeta.B.getOwnershipRange() != A.getOwnershipRange():
                raise ValueError(f"zeta.B must be ({n}, {n}) with A's row layout, got {zeta.B.getSize()} "
                                 f"rows {zeta.B.getOwnershipRange()}")
            self.B, self.c = zeta.B, _local(zeta.c, A, "zeta.c", scalar_ok=True)
        elif callable(zeta):
            self.kind, self.fn = 3, CheckedZeta(zeta, A.getLocalSize()[0])
        else:
            self.kind, self.c = 1, _local(zeta, A, "zeta", scalar_ok=True)

    def _checked(self, z):
        r = self.fn(z)
        if not np.all(np.isfinite(r)):
            i = int(np.flatnonzero(~np.isfinite(r))[0])
            raise ValueError(f"{_core.status_message(int(Status.ZETA_FAILED))} (NaN or Inf: zeta(z)[{i}] of this "
                             f"rank's rows = {r[i]})")
        return r

    def make(self, A):
        if self.c is not None:
            self.c = _vec(A, self.c)
        return self

    def __call__(self, z, out):
        """out = ζ(z); collective: a failure on any rank raises on every rank."""
        if self.kind == 0:
            out.set(0.0)
        elif self.kind == 1:
            self.c.copy(out)
        elif self.kind == 2:
            self.B.multAdd(z, self.c, out)
        else:
            r = _collective(self.comm, self._checked, z.getArray(readonly=True))
            out.setArray(r)
        return out


# ----------------------------------------------------------------------------- the pieces
class _Problem:
    """An LCP(b, A) level of the nested iteration: A, b, diag(A), work vectors."""

    def __init__(self, A, b):
        self.A, self.b = A, b
        self.d = A.getDiagonal()
        self.w = b.duplicate()

    def residual(self, y):
        """w = A y + b (kept in self.w), Res = ‖min(w, y)‖₂."""
        self.A.multAdd(y, self.b, self.w)
        m = self.w.duplicate()
        m.setArray(np.minimum(self.w.getArray(readonly=True), y.getArray(readonly=True)))
        return m.norm()

    def floor(self, y):
        """The rounding level of Res at y (ζ = 0 in y): eps (‖|A||y| + |b|‖ + ‖y‖)."""
        return _rounding_level(self.A, self.b, y, None)


def _abs_mat(A):
    """|A| entry-wise, in A's layout (built for a floor test: at most a few a solve)."""
    indptr, cols, vals = A.getValuesCSR()
    return PETSc.Mat().createAIJ(size=A.getSizes(), csr=(indptr, cols, np.abs(vals)), comm=A.getComm())


def _rounding_level(A, q, z, zt):
    """The serial member's rounding level of Res (detail/newton_level.hpp):
    eps (‖|A||z| + |q|‖ + ‖|z| + |ζ(z)|‖); zt = ζ(z), None for ζ = 0."""
    absA = _abs_mat(A)
    za = z.copy()
    za.abs()
    t = z.duplicate()
    absA.mult(za, t)
    t.setArray(t.getArray(readonly=True) + np.abs(q.getArray(readonly=True)))
    if zt is not None:
        za.setArray(za.getArray(readonly=True) + np.abs(zt.getArray(readonly=True)))
    absA.destroy()
    return float(np.finfo(float).eps * (t.norm() + za.norm()))


#: Options with this prefix tune the nesting hierarchy's BoomerAMG (e.g. -nrmicp_hierarchy_pc_hypre_boomeramg_P_max 4).
_HIERARCHY_PREFIX = "nrmicp_hierarchy_"


def _hierarchy(A, comm, prefix):
    """hypre BoomerAMG's classical prolongations and its Galerkin operators PᵀAP, finest first
    (A excluded), read through PCHMG. PCMG's smoothers are never applied here: Richardson without
    a preconditioner spares their set-up (Chebyshev's eigenvalue estimates: docs/MEASUREMENTS.md)."""
    ours = {"pc_hmg_reuse_interpolation": True, "hmg_inner_pc_type": "hypre",
            "mg_levels_ksp_type": "richardson", "mg_levels_pc_type": "none"}
    # the user's -nrmicp_hierarchy_pc_hypre_boomeramg_... options reach hypre's set-up
    ours.update({"hmg_inner_" + k[len(_HIERARCHY_PREFIX):]: v for k, v in PETSc.Options().getAll().items()
                 if k.startswith(_HIERARCHY_PREFIX)})
    pc = PETSc.PC().create(comm)
    pc.setOptionsPrefix(prefix)
    pc.setOperators(A)
    pc.setType("hmg")
    with _scoped_options(prefix, ours):
        pc.setFromOptions()
        pc.setUp()
    L = pc.getMGLevels()
    Ps = [pc.getMGInterpolation(l) for l in range(L - 1, 0, -1)]
    As = [pc.getMGSmoother(l).getOperators()[0] for l in range(L - 2, -1, -1)]
    return Ps, As, pc


class _Newton:
    """The Newton member on one level's LCP (y = z − c): active-set rule y − w/diag(A) ≥ 0 inactive
    (ties inactive), steps for the correction on the inactive set by KSP (CG on symmetric A,
    else BiCGSTAB). With `ssor_first` (the coarse levels) a step first tries local SSOR as the
    preconditioner, at most _SSOR_ITERATIONS iterations, and sets up BoomerAMG only when that
    does not reach the step's tolerance, going on from SSOR's iterate: a coarse step needs only
    0.1 × Res and BoomerAMG's set-up is most of its cost (docs/MEASUREMENTS.md, "The distributed
    Newton member's choices"). The last set's systems are kept: a set solved again (an exact repeat of
    a loose step) reuses its submatrix and preconditioners."""

    def __init__(self, prob, comm, symmetric, stats, ssor_first=False, sweeps=False):
        self.p, self.comm, self.stats = prob, comm, stats
        self.ksp_type = "cg" if symmetric else "bcgs"
        # The projected sweeps after each step: the finest level only (the coarse levels' SSOR-first
        # steps are cheaper than a sweep) and a symmetric A only (there a sweep descends the LCP's
        # quadratic energy and cannot start a cycle; docs/MEASUREMENTS.md).
        self.smoothing = _TUNING["smoothing_sweeps"] if sweeps and symmetric else 0
        self.ssor_first = ssor_first
        self.inactive = self.h = None
        self.own = None  # smooth's copy of the rank's diagonal block of A (read once a level)
        self.kept = {}  # the last solved set: "h", "is", "A_II" and a KSP per preconditioner

    def plan(self, y):
        """The inactive set of y (w of y in self.p.w), kept for solve; returns its fingerprint."""
        self.inactive = self._inactive_of(y)
        self.h = _fingerprint(self.comm, self.p.A.getOwnershipRange()[0], self.inactive)
        return self.h

    def overshoots(self, y):
        """_overshoots of the step to y (w of y in self.p.w) from the planned set."""
        return _overshoots(self.comm, self.p.A.getSize()[0] - self.h[0], y.getArray(readonly=True),
                           self.p.w.getArray(readonly=True), self.p.d.getArray(readonly=True))

    def smooth(self, y):
        """The serial member's projected Gauss–Seidel sweeps after a step (self.smoothing of them,
        symmetric), on each rank's own rows with the couplings to other ranks' unknowns held at y
        (block Jacobi between ranks, Gauss–Seidel within: PETSc's SOR has no projection). w of y
        in self.p.w on entry. Returns (whether the active set changed on some rank, Res of y);
        self.p.w is then y's."""
        p = self.p
        ya, wa = y.getArray(readonly=True), p.w.getArray(readonly=True)
        before = self._inactive_of(y)
        if self.own is None:
            indptr, indices, data = p.A.getDiagonalBlock().getValuesCSR()
            self.own = sp.csr_matrix((data, indices, indptr), shape=(ya.size, ya.size))
        ys = ya.copy()
        _core.projected_gauss_seidel(self.own.indptr, self.own.indices, self.own.data, wa - self.own @ ya, ys,
                                     self.smoothing)
        y.setArray(ys)
        res = p.residual(y)
        return _flag_max(self.comm, float(np.any(before != self._inactive_of(y)))) > 0, res

    def _inactive_of(self, y):
        """_inactive of y (w of y in self.p.w): this rank's rows."""
        return _inactive(y.getArray(readonly=True), self.p.w.getArray(readonly=True), self.p.d.getArray(readonly=True))

    def solve(self, y, rtol, atol):
        """The step on the planned set, its inner solve stopped at max(rtol ‖rhs‖, atol)."""
        p = self.p
        delta = y.duplicate()
        delta.setArray(np.where(self.inactive, 0.0, -y.getArray(readonly=True)))
        rhs = y.duplicate()
        p.A.mult(delta, rhs)
        rhs.axpy(1.0, p.w)
        rhs.scale(-1.0)
        isI = self._system()
        if isI.getSize() > 0:
            bI, dI = rhs.getSubVector(isI), delta.getSubVector(isI)
            done = self.ssor_first and self._inner("ssor", bI, dI, rtol, atol, False)
            if not done:
                self._inner("hypre", bI, dI, rtol, atol, self.ssor_first)
            self.stats["linear_solves"] += 1
            rhs.restoreSubVector(isI, bI)
            delta.restoreSubVector(isI, dI)
        ynew = y.copy()
        ynew.axpy(1.0, delta)
        return ynew

    def _inner(self, pc, b, x, rtol, atol, warm):
        """One KSP run with preconditioner pc from x (warm) or 0; True when it converged."""
        ksp = self.kept.get(pc)
        if ksp is None:
            ksp = self.kept[pc] = _ksp(self.comm, self.kept["A_II"], self.ksp_type, pc)
        ksp.setInitialGuessNonzero(warm)
        ksp.setTolerances(rtol=rtol, atol=atol)
        ksp.solve(b, x)
        self.stats["inner_iterations"] += ksp.getIterationNumber()
        return ksp.getConvergedReason() > 0

    def _system(self):
        """The planned set's index set (its A_II kept): the kept one when it is the last solved set."""
        if self.kept.get("h") != self.h:
            self._drop_systems()
            lo, _ = self.p.A.getOwnershipRange()
            isI = PETSc.IS().createGeneral((np.flatnonzero(self.inactive) + lo).astype(PETSc.IntType), comm=self.comm)
            self.kept = {"h": self.h, "is": isI, "A_II": self.p.A.createSubMatrix(isI, isI) if isI.getSize() else None}
        return self.kept["is"]

    def release(self):
        """Free the kept systems and the block copy (the level is done)."""
        self._drop_systems()
        self.own = None

    def _drop_systems(self):
        for key, obj in self.kept.items():
            if key != "h" and obj is not None:
                obj.destroy()
        self.kept = {}


#: The coarse levels' SSOR tries: at most this many Krylov iterations before BoomerAMG is set up
#: (more did not pay: docs/MEASUREMENTS.md; -nrmicp_ssor_ksp_max_it overrides).
_SSOR_ITERATIONS = 30


def _ksp(comm, M, kind, pc):
    """CG or BiCGSTAB with hypre BoomerAMG (pc 'hypre': options prefix nrmicp_inner_) or local
    SSOR (pc 'ssor': prefix nrmicp_ssor_), stopping on the true residual (the preconditioned norm
    of a small w_I is far smaller, and stopped the solve before it started)."""
    ksp = PETSc.KSP().create(comm)
    ksp.setOperators(M)
    ksp.setType(kind)
    if kind != "cg":
        ksp.setPCSide(PETSc.PC.Side.RIGHT)
    ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
    if pc == "ssor":
        ksp.getPC().setType("sor")
        ksp.setTolerances(max_it=_SSOR_ITERATIONS)
        prefix, defaults = "nrmicp_ssor_", {"pc_sor_local_symmetric": None}  # on each rank's block
    else:
        ksp.getPC().setType("hypre")
        ksp.setTolerances(max_it=1000)
        prefix, defaults = "nrmicp_inner_", _boomeramg_defaults(M)  # -nrmicp_inner_pc_hypre_boomeramg_...
    ksp.setOptionsPrefix(prefix)
    with _scoped_options(prefix, defaults):   # defaults for this matrix only
        ksp.setFromOptions()
    return ksp


@contextlib.contextmanager
def _scoped_options(prefix, values):
    """PETSc options `values` under `prefix` while the block runs, then removed (the options
    database outlives the solve); an entry the user set already wins and stays."""
    opts = PETSc.Options(prefix)
    ours = [k for k in values if not opts.hasName(k)]
    for k in ours:
        opts[k] = values[k]
    try:
        yield
    finally:
        for k in ours:
            opts.delValue(k)


def _boomeramg_defaults(M) -> dict:
    """BoomerAMG options for a reduced matrix: HMIS coarsening, ext+i interpolation (at most 4
    weights a row) and one level of aggressive coarsening when M has more than 6 nonzeros a row
    (7-point 3D, P1 triangles); hypre's defaults on sparser ones (5-point 2D), the faster on each
    (docs/MEASUREMENTS.md, "The distributed Newton member's choices")."""
    rows = max(M.getSize()[0], 1)
    if M.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"] <= 6 * rows:
        return {}
    return {"pc_hypre_boomeramg_coarsen_type": "HMIS", "pc_hypre_boomeramg_interp_type": "ext+i",
            "pc_hypre_boomeramg_P_max": "4", "pc_hypre_boomeramg_agg_nl": "1"}


def _inactive(g, w, d):
    """The inactive set {g − w/diag(A) ≥ 0} of this rank's rows (g = z − ζ(z); ties inactive: the serial
    NewtonLevel::active_set)."""
    return g - w / d >= 0


def _overshoots(comm, planned, g, w, d):
    """Globalized::overshoots: the trial (this rank's g = z − ζ(z), w and diag(A)) has more than
    _TUNING["overshoot_growth"] times the `planned` active points (over all ranks; 0: never)."""
    if planned <= 0:
        return False
    return _sum(comm, float(np.count_nonzero(~_inactive(g, w, d)))) > _TUNING["overshoot_growth"] * planned


def _fingerprint(comm, lo, inactive):
    idx = np.flatnonzero(inactive) + lo
    weights = ((idx.astype(np.int64) + 1) * 2654435761 % 2147483647) / 2147483647.0
    return _sum(comm, float(idx.size)), round(_sum(comm, float(np.sum(weights))), 8)


class _AOR:
    """An AOR-type member as synchronous multisplitting: this rank's left matrix
    T = αΩ2 + (D − βL_loc)Ω1 + αφΩ1 (L_loc: the strictly lower part of A's diagonal block, so one
    rank is the serial member exactly, and nrmj is Jacobi on any number of ranks); the rest of A
    enters through PETSc's product (Jacobi across ranks)."""

    def __init__(self, A, alpha, beta, omega1, omega2, gamma):
        lo, hi = A.getOwnershipRange()
        indptr, cols, vals = A.getValuesCSR()
        nloc = hi - lo
        d = A.getDiagonal().getArray().copy()
        bad = ~(d > 0)
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"A's diagonal must be positive for the modulus members (Omega2 = diag(A), the AOR "
                             f"sweep divides by it); A[{lo + i}, {lo + i}] = {d[i]}")
        self.w1 = np.ones(nloc) if omega1 is None else omega1
        self.w2 = d if omega2 is None else omega2
        self.alpha, self.gamma = alpha, gamma
        rows = np.repeat(np.arange(nloc), np.diff(indptr))
        lower = (cols >= lo) & (cols < lo + rows)  # strictly lower, inside this rank's block
        SL = sp.csr_matrix((vals[lower] * self.w1[cols[lower] - lo], (rows[lower], cols[lower] - lo)),
                           shape=(nloc, nloc))
        self.K = (sp.diags(d * self.w1) + beta * SL).tocsr()
        self.T = (sp.diags(alpha * self.w2 + d * self.w1) + beta * SL).tocsr()
        self.diagonal = beta == 0 or SL.nnz == 0
        self.Tdiag = alpha * self.w2 + d * self.w1
        if not self.diagonal:
            self._lower_solver()

    def _lower_solver(self):
        """The local forward substitution by PETSc (ILU(0) of a lower-triangular T is T itself)."""
        T = self.T.tocsr()
        T.sort_indices()
        nloc = T.shape[0]
        self._T = PETSc.Mat().createAIJ(size=(nloc, nloc), csr=(T.indptr.astype(PETSc.IntType),
                                        T.indices.astype(PETSc.IntType), T.data), comm=PETSc.COMM_SELF)
        self._ksp = PETSc.KSP().create(PETSc.COMM_SELF)
        self._ksp.setOperators(self._T)
        self._ksp.setType("preonly")
        self._ksp.getPC().setType("ilu")
        self._r, self._x = self._T.createVecs()

    def start(self, g, w):
        """x with g = Ω1(|x|+x)/γ, w = Ω2(|x|−x)/γ for a complementary (g, w) ≥ 0 (a start z)."""
        return 0.5 * self.gamma * (np.maximum(g, 0) / self.w1 - np.maximum(w, 0) / self.w2)

    def sweep(self, x, zt, Av_of):
        """x_{k+1} from x_k and ζ(z_k) (zt); Av_of(v) returns A v + γ q's local rows."""
        v = self.w1 * (x + np.abs(x)) + self.gamma * zt
        r = self.K @ x + self.alpha * self.w2 * np.abs(x) - self.alpha * Av_of(v)
        if self.diagonal:
            return r / self.Tdiag
        self._r.setArray(r)
        self._ksp.solve(self._r, self._x)
        return self._x.getArray().copy()

    def z_of(self, x, zt):
        return zt + self.w1 * (np.abs(x) + x) / self.gamma


def _icp_residual(A, q, zeta, z, w, g, zt):
    """Res(z) = ‖min(Az + q, z − ζ(z))‖ (w, g, zt = ζ(z) filled)."""
    A.multAdd(z, q, w)
    zeta(z, zt)
    z.copy(g)
    g.axpy(-1.0, zt)
    m = w.duplicate()
    m.setArray(np.minimum(w.getArray(readonly=True), g.getArray(readonly=True)))
    return m.norm()


def _stationary(A, q, zeta, member, z, tol, maxiter, stats):
    """Sweeps of an AOR-type member on ICP(q, A, ζ) from z (modified in place: the best iterate).
    Returns (Res, iterations, status)."""
    w, g, zt, v = z.duplicate(), z.duplicate(), z.duplicate(), z.duplicate()
    Av = z.duplicate()
    res = _icp_residual(A, q, zeta, z, w, g, zt)
    x = member.start(g.getArray(readonly=True), w.getArray(readonly=True))
    best = (res, z.copy(), 0)
    gq = member.gamma

    def Av_of(arr):
        v.setArray(arr)
        A.mult(v, Av)
        return Av.getArray(readonly=True) + gq * q.getArray(readonly=True)

    status, k = Status.MAX_ITERATIONS, 0
    while k < maxiter:
        if res < tol:
            status = Status.CONVERGED
            break
        x = member.sweep(x, zt.getArray(readonly=True), Av_of)
        z.setArray(member.z_of(x, zt.getArray(readonly=True)))
        k += 1
        res = _icp_residual(A, q, zeta, z, w, g, zt)
        if not math.isfinite(res):
            status = Status.DIVERGED
            break
        if res < best[0]:
            best = (res, z.copy(), k)
    if res < tol:
        status = Status.CONVERGED
    stats["sweeps"] = stats.get("sweeps", 0) + k
    best[1].copy(z)
    return best[0], best[2], status, k


class _Control(NamedTuple):
    """How the loop on one level solves (the serial member's NewtonControl): inner solves stop at
    forcing × Res (first_forcing for the first step; 0: at `exact`), and a set so solved that
    repeats settles only once Res < repeat_trust × Res(start); before, it is solved again (at
    `exact`, its atol raised to a tenth of repeat_trust × Res(start) where that is finite)."""
    first_forcing: float = 0.0
    forcing: float = 0.0
    repeat_trust: float = math.inf
    exact: tuple = (1e-14, 0.0)  # (rtol, atol) of an exact step


def _newton_loop(residual, stepper, fallback, y, *, tol, maxiter, control, floor, sweep_budget):
    """The serial member's globalization (detail/globalization.hpp) around plain steps: a step is
    accepted when its Res is below the largest of the last 5 accepted (the first after a start is
    exempt); a rejected step or a cycle of active sets hands over to fallback sweeps from the
    best iterate (10, 20, 40, ...), after which Newton resumes. The loop settles when the active
    set repeats (see _Control) or a step that did not halve Res leaves it at its rounding level
    (floor(y), within _TUNING["floor_factor"]); a step that overshoots (stepper.overshoots) is
    damped first, then swept (stepper.smooth, when stepper.smoothing > 0: a repeat of a set the sweeps
    changed is solved again). Returns (y, Res, steps, sweeps, status, floor or None)."""
    res = start = residual(y)
    best = (res, y.copy())
    recent, exempt, seen, last, loose = [res], True, set(), None, False
    trust = control.repeat_trust * start   # a loose repeat settles below it
    again = (control.exact[0], max(control.exact[1], 0.1 * trust)) if math.isfinite(trust) else control.exact
    moved = False  # the sweeps after the last accepted step changed its active set
    smooth = stepper.smooth if getattr(stepper, "smoothing", 0) > 0 else None
    steps = sweeps = 0
    run = 10

    def end(status, level=None):
        return best[1], best[0], steps, sweeps, status, level

    while True:
        if res < tol:
            return end(Status.CONVERGED)
        if steps >= maxiter:
            return end(Status.MAX_ITERATIONS)
        h = stepper.plan(y)
        repeat = h == last
        trusted = not loose or res < trust   # the serial member's Globalized::newton
        if repeat and trusted and not moved:
            return end(Status.STAGNATED, floor(best[1]) if floor and tol > 0 else None)  # settled: no solve needed
        if repeat or h not in seen:
            forcing = 0.0 if repeat else control.first_forcing if steps == 0 else control.forcing
            loose = forcing > 0
            ynew = stepper.solve(y, *((1e-14, max(forcing * res, 0.1 * tol)) if loose else again if repeat else control.exact))
            steps += 1
            rnew = residual(ynew)
            if stepper.overshoots(ynew):
                damping = _TUNING["overshoot_damping"]   # ynew <- y + damping (ynew - y)
                ynew.axpby(1.0 - damping, damping, y)
                rnew = residual(ynew)
            moved_now = False
            if smooth is not None and not repeat:  # a repeat is the exact solve of its set: kept as solved
                moved_now, rnew = smooth(ynew)
            if math.isfinite(rnew) and (exempt or rnew < max(recent)):
                y, res, res_old, exempt, last, moved = ynew, rnew, res, False, h, moved_now
                recent = (recent + [rnew])[-_WINDOW:]
                seen.add(h)
                if rnew < best[0]:
                    best = (rnew, y.copy())
                if floor and not rnew < tol and not rnew < 0.5 * res_old:
                    level = floor(y)
                    if max(rnew, res_old) <= _TUNING["floor_factor"] * level:
                        return end(Status.STAGNATED, level)
                continue
        if fallback is None or sweeps >= sweep_budget:
            return end(Status.STAGNATED)
        y = best[1].copy()
        rb, k = fallback(y, min(run, sweep_budget - sweeps))
        sweeps += k
        run *= 2
        if not rb < best[0]:
            return end(Status.STAGNATED)
        best, res = (rb, y.copy()), residual(y)
        recent, exempt, last, loose, moved = [res], True, None, False, False
        seen.clear()


# ----------------------------------------------------------------------------- the Newton drivers
#: Inner (KSP) tolerance of the affine member's steps relative to the step's right-hand side
#: (inexact Newton); they also stop at tol/10 absolute, as the serial member's iterative inner solve.
_RTOL = 1e-6


class _Levels:
    """The nesting hierarchy, pairs (P, its Galerkin operator or None), built on first use: a user's
    start that converges alone (_nested_lcp) never pays BoomerAMG's set-up."""

    def __init__(self, build=None, pairs=()):
        self._build, self._pairs, self._keep = build, list(pairs), None
        self.seconds = 0.0   # the set-up's, when built

    def __bool__(self):
        return self._build is not None or bool(self._pairs)

    def pairs(self):
        if self._build is not None:
            t0 = time.perf_counter()
            Ps, As, self._keep = self._build()     # the PC that owns them is kept with them
            self._pairs, self._build = list(zip(Ps, As)), None
            self.seconds = time.perf_counter() - t0
        return self._pairs


def _nested_lcp(A, b, y0, Ps, tol, maxiter, symmetric, comm, stats, zero_start=False):
    """LCP(b, A) by the nested Newton member: coarse problems PᵀAP, Pᵀb, solved coarse to fine,
    each solution prolongated and projected (y ≥ 0) as the next start. A start y0 closer than a cold
    one (and not x0 = 0: `zero_start`) is tried first for at most warm_steps finest steps (the serial
    rule: NewtonRun::solve_obstacle; the hierarchy is set up only if the nested start takes over).
    Returns (y, Res, status)."""
    if not (Ps and y0 is not None and not zero_start and _closer_than_cold(A, b, y0)):
        return _levels_lcp(A, b, y0, Ps, tol, maxiter, symmetric, comm, stats)
    budget = min(maxiter, _TUNING["warm_steps"])
    yw, rw, sw = _levels_lcp(A, b, y0, _Levels(), tol, budget, symmetric, comm, stats, guessed=True)
    if sw != Status.MAX_ITERATIONS or maxiter <= budget:
        return yw, rw, sw
    tried, seconds = stats["level_steps"].pop(0), stats["level_seconds"].pop(0)
    if Ps.pairs():   # the nested start; a hierarchy of one level (a small A) goes on from the try
        y, res, status = _levels_lcp(A, b, None, Ps, tol, maxiter - tried, symmetric, comm, stats)
    else:
        y, res, status = _levels_lcp(A, b, yw, Ps, tol, maxiter - tried, symmetric, comm, stats, guessed=True)
    stats["level_steps"][0] += tried
    stats["level_seconds"][0] += seconds
    if status != Status.CONVERGED and rw < res:   # maxiter spent on both: the try's iterate was better
        return yw, rw, sw
    return y, res, status


def _levels_lcp(A, b, y0, Ps, tol, maxiter, symmetric, comm, stats, guessed=False):
    """_nested_lcp's levels: nested over Ps, else from y0 (zeros when None); `guessed`: y0 is the
    user's guess, its finest steps as loose as a nested start's."""
    pairs = Ps.pairs() if Ps else []
    As, bs = [A], [b]
    for P, Ac in pairs:
        As.append(Ac if Ac is not None else As[-1].ptap(P))
        bc = P.createVecRight()
        P.multTranspose(bs[-1], bc)
        bs.append(bc)
    y = None
    for level in reversed(range(len(As))):
        t0 = time.perf_counter()
        prob = _Problem(As[level], bs[level])
        if y is None:
            y = y0.copy() if (level == 0 and y0 is not None) else prob.b.duplicate()
            if y0 is None or level > 0:
                y.set(0.0)
        else:
            yf = As[level].createVecLeft()
            pairs[level][0].mult(y, yf)
            yf.setArray(np.maximum(yf.getArray(readonly=True), 0.0))
            y = yf
        finest = level == 0
        nt = _Newton(prob, comm, symmetric, stats, ssor_first=not finest, sweeps=finest)
        y, res, steps, sweeps, status, floor = _newton_loop(
            prob.residual, nt, _lcp_fallback(prob, comm, stats) if finest else None,
            y, tol=tol if finest else 0.0, maxiter=maxiter if finest else _TUNING["coarse_maxiter"],
            control=_level_control(finest, len(As) > 1 or guessed, tol), floor=prob.floor, sweep_budget=maxiter)
        nt.release()
        if finest:
            stats["floor"] = floor
        stats["level_steps"].insert(0, steps)
        stats["level_seconds"].insert(0, time.perf_counter() - t0)
        stats["fallback_sweeps"] += sweeps
    return y, res, status


def _closer_than_cold(A, b, y0):
    """Res(max(y0, 0)) < warm_start_fraction × Res(0) on LCP(b, A): NewtonRun::closer_than_cold."""
    y, cold = y0.copy(), b.duplicate()
    y.setArray(np.maximum(y.getArray(readonly=True), 0.0))
    cold.setArray(np.minimum(b.getArray(readonly=True), 0.0))
    return _Problem(A, b).residual(y) < _TUNING["warm_start_fraction"] * cold.norm()


def _level_control(finest, nested, tol):
    """The serial member's controls (NewtonRun): coarse levels loose to a settled set; the finest
    level exact (inner solve to tol/10 absolute), loose while its sets are guesses (nested or warm)."""
    exact = (1e-14, 0.1 * tol)
    if not finest:
        return _Control(_TUNING["coarse_forcing"], _TUNING["coarse_forcing"], _TUNING["coarse_repeat_trust"], exact)
    if nested:
        return _Control(_TUNING["nested_first_forcing"], _TUNING["nested_forcing"], 0.0, exact)
    return _Control(exact=exact)


def _lcp_fallback(prob, comm, stats):
    """Fallback sweeps of nrmgs (synchronous multisplitting) on the level's LCP."""
    zeta = _Zeta(None, prob.A, comm)
    member = []  # built on first use: most solves never fall back

    def run(y, k):
        if not member:
            member.append(_AOR(prob.A, 1.0, 1.0, None, None, 1.0))
        res, _, _, done = _stationary(prob.A, prob.b, zeta, member[0], y, 0.0, k, stats)
        return res, done
    return run


def _affine_newton(A, q, zeta, z, tol, maxiter, comm, stats):
    """ICP(q, A, Bz + c) by Newton on the whole problem: rows of A on the inactive set, rows of
    I − B on the active set; BiCGSTAB with hypre BoomerAMG."""
    lo, _ = A.getOwnershipRange()
    d = A.getDiagonal().getArray(readonly=True)
    w, g, zt = z.duplicate(), z.duplicate(), z.duplicate()
    member = _AOR(A, 1.0, 1.0, None, None, 1.0)

    def residual(v):
        return _icp_residual(A, q, zeta, v, w, g, zt)

    class Step:
        def plan(self, v):  # g, w are v's (the loop evaluated v last)
            self.inactive = _inactive(g.getArray(readonly=True), w.getArray(readonly=True), d)
            self.h = _fingerprint(comm, lo, self.inactive)
            return self.h

        def overshoots(self, v):  # g, w are v's
            return _overshoots(comm, A.getSize()[0] - self.h[0], g.getArray(readonly=True), w.getArray(readonly=True), d)

        def solve(self, v, rtol, atol):
            inactive = self.inactive
            mI = _vec(A, inactive.astype(float))
            mA = _vec(A, 1.0 - inactive)
            J = A.copy()
            J.diagonalScale(L=mI)
            BB = zeta.B.copy()
            BB.diagonalScale(L=_vec(A, inactive - 1.0))
            J.axpy(1.0, BB, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
            J.setDiagonal(mA, addv=PETSc.InsertMode.ADD_VALUES)
            rhs = _vec(A, -np.where(inactive, w.getArray(readonly=True), g.getArray(readonly=True)))
            delta = z.duplicate()
            ksp = _ksp(comm, J, "bcgs", "hypre")
            ksp.setTolerances(rtol=rtol, atol=atol)
            ksp.solve(rhs, delta)
            stats["inner_iterations"] += ksp.getIterationNumber()
            stats["linear_solves"] += 1
            ksp.destroy()
            J.destroy()
            out = v.copy()
            out.axpy(1.0, delta)
            return out

    def fallback(v, k):
        res, _, _, done = _stationary(A, q, zeta, member, v, 0.0, k, stats)
        return res, done

    t0 = time.perf_counter()
    z, res, steps, sweeps, status, floor = _newton_loop(
        residual, Step(), fallback, z, tol=tol, maxiter=maxiter, control=_Control(exact=(_RTOL, 0.1 * tol)),
        floor=lambda v: _rounding_level(A, q, v, zt), sweep_budget=maxiter)
    stats["floor"] = floor
    stats["level_steps"], stats["level_seconds"] = [steps], [time.perf_counter() - t0]
    stats["fallback_sweeps"] += sweeps
    return z, res, status


def _obstacle_newton(A, q, c, z0, Ps, tol, maxiter, symmetric, comm, stats):
    """ζ ≡ c (c None: the LCP): the LCP in y = z − c with b = q + A c; returns (z, Res, status)."""
    b = q.copy()
    y0 = None if z0 is None else z0.copy()
    if c is not None:
        A.multAdd(c, q, b)
        if y0 is not None:
            y0.axpy(-1.0, c)
    y, res, status = _nested_lcp(A, b, y0, Ps, tol, maxiter, symmetric, comm, stats,
                                 zero_start=z0 is not None and z0.norm(PETSc.NormType.INFINITY) == 0)
    if c is not None:
        y.axpy(1.0, c)
    return y, res, status


def _callable_newton(A, q, zeta, z0, Ps, tol, maxiter, symmetric, comm, stats):
    """A callable ζ: the outer fixed point c_k = ζ(z_k), each obstacle problem by the Newton member
    (nested the first time, then warm-started), as the serial member without zeta_jacobian."""
    z = z0.copy() if z0 is not None else A.createVecLeft()
    if z0 is None:
        z.set(0.0)
    w, g, zt = z.duplicate(), z.duplicate(), z.duplicate()
    res = _icp_residual(A, q, zeta, z, w, g, zt)
    best, status = (res, z.copy()), Status.MAX_ITERATIONS
    for k in range(maxiter):
        if res < tol:
            status = Status.CONVERGED
            break
        c = zt.copy()
        sub = dict(stats, level_steps=[], level_seconds=[])
        z, _, _ = _obstacle_newton(A, q, c, z if k else None, Ps if k == 0 else _Levels(), 0.1 * tol, maxiter,
                                   symmetric, comm, sub)
        for key in ("linear_solves", "inner_iterations", "fallback_sweeps"):
            stats[key] = sub[key]
        stats["level_steps"], stats["level_seconds"] = sub["level_steps"], sub["level_seconds"]
        stats["outer_iterations"] += 1
        stats["nit"] += sub["level_steps"][0]
        res = _icp_residual(A, q, zeta, z, w, g, zt)
        if not res < best[0] and k > 0:
            status = Status.STAGNATED
            break
        best = (res, z.copy())
    if best[0] < tol:
        status = Status.CONVERGED
    return best[1], best[0], status


def _polish(A, q, zeta, z, res, comm, symmetric, stats):
    """One Newton step from z on its active set with a tight inner solve; kept when it lowers Res."""
    trial = z.copy()
    w, g, zt = z.duplicate(), z.duplicate(), z.duplicate()
    if zeta.kind == 2:
        sub = dict(stats, level_steps=[], level_seconds=[])
        _icp_residual(A, q, zeta, trial, w, g, zt)
        trial, r, _ = _affine_newton(A, q, zeta, trial, 0.0, 1, comm, sub)
    else:
        c = A.createVecLeft()
        zeta(z, c)
        b = q.copy()
        A.multAdd(c, q, b)
        y = z.copy()
        y.axpy(-1.0, c)
        prob = _Problem(A, b)
        prob.residual(y)
        nt = _Newton(prob, comm, symmetric, stats)
        nt.plan(y)
        y = nt.solve(y, 1e-14, 0.0)
        nt.release()
        y.axpy(1.0, c)
        trial = y
    r = _icp_residual(A, q, zeta, trial, w, g, zt)
    return (trial, r) if r < res else (None, res)


# ----------------------------------------------------------------------------- the entry points
def _prepare(A, q, zeta, x0, comm, method, tol, maxiter, omega1, omega2, gamma, alpha, beta, hierarchy, rtol=0.0):
    """Every check, with every rank's failure raised on all ranks; returns the PETSc objects."""
    A_in = _collective(comm, _check_mat, A)
    Am = _as_mat(A_in, comm) if sp.issparse(A_in) else A_in
    n, nloc = Am.getSize()[0], Am.getLocalSize()[0]

    def local():
        m, w1, w2 = _check_options(method, n, tol, maxiter, omega1, omega2, gamma, alpha, beta, nloc, rtol)
        if m != "newton" and hierarchy not in (None, "amg", "auto"):
            raise ValueError(f"hierarchy is the nested iteration of method 'newton'; got {hierarchy!r}")
        if m == "newton" and not (hierarchy in (None, "amg", "auto") or isinstance(hierarchy, (list, tuple))):
            raise ValueError(f"hierarchy must be 'amg', None or a list of PETSc prolongations; got {hierarchy!r}")
        qa = _local(q, Am, "q")
        xa = None if x0 is None else _local(x0, Am, "x0")
        return m, w1, w2, qa, xa, _Zeta(zeta, Am, comm)
    m, w1, w2, qa, xa, zf = _collective(comm, local)
    d = Am.getDiagonal()

    def diagonal():
        da = d.getArray(readonly=True)
        if np.any(~(da > 0)):
            i = int(np.flatnonzero(~(da > 0))[0])
            lo = Am.getOwnershipRange()[0]
            raise ValueError(f"A's diagonal must be positive (method {m!r} divides by it); "
                             f"A[{lo + i}, {lo + i}] = {da[i]}")
    _collective(comm, diagonal)
    return Am, m, w1, w2, _vec(Am, qa), None if xa is None else _vec(Am, xa), zf.make(Am)


def solve(A, q, zeta=None, *, method: str = "newton", tol=None, rtol=None, maxiter: int = 10000,
          omega1=None, omega2=None, gamma: float = 1.0, alpha=None, beta=None, hierarchy="amg",
          x0=None, polish: bool = False, comm=None, upper=None) -> Result:
    """Solve ICP(q, A, ζ) on all ranks of A's communicator (call it on every rank).

    A: petsc4py Mat (AIJ, square, same row and column layout) or this rank's scipy.sparse row
    block (n_local, n). q, x0: petsc4py Vec in A's row layout or this rank's rows. zeta: None,
    a constant (scalar, this rank's rows or a Vec), :class:`nrmicp.Affine` (B a petsc4py Mat in
    A's layout, c) or a callable mapping this rank's rows of z to this rank's rows of ζ(z)
    (entry-wise or row-local ζ only). method: 'newton' (nested over hypre BoomerAMG's
    prolongations with hierarchy='amg', cold with None, or a list of PETSc prolongation Mats,
    finest first) or 'nrmj', 'nrmgs', 'nrmsor', 'nrmaor' (synchronous multisplitting).
    The options mean what they mean in :func:`nrmicp.solve` and are checked by the same code;
    tol and rtol both None is nrmicp.solve's default rule (units-free Res_E, rtol 1e-10), applied by
    solving σA, σq (σ from the diagonal's global geometric mean), ``residual`` the paper's Res.
    Returns a :class:`nrmicp.Result` on every rank, with ``z`` and ``w`` as PETSc Vecs
    (:func:`gather` copies one to rank 0). A failure on any rank raises on every rank.
    """
    if upper is not None:   # bounds arrive with the one Newton driver's PETSc engine (issue 35), not as a second copy here
        raise NotImplementedError("upper: bounds are not available in nrmicp.distributed yet; solve them with "
                                  "nrmicp.solve(..., upper=...) on one machine")
    comm = comm or (A.getComm() if isinstance(A, PETSc.Mat) else PETSc.COMM_WORLD)
    t_start = time.perf_counter()
    it, units = _criterion({"tol": tol, "rtol": rtol})
    Am, m, w1, w2, qv, z0, zf = _prepare(A, q, zeta, x0, comm, method, it["tol"], maxiter, omega1, omega2,
                                         gamma, alpha, beta, hierarchy, it["rtol"])
    A_user, q_user = Am, qv
    if units:   # the iteration runs on σA, σq: its Res is the units-free Res_E
        sigma = _units_sigma(Am)
        Am, qv = Am.copy(), qv.copy()
        Am.scale(sigma)
        qv.scale(sigma)
        w2 = None if w2 is None else sigma * w2
    tol = _target(Am, qv, zf, it["tol"], it["rtol"])
    polish = bool(_collective(comm, lambda: _check_polish(polish)))
    stats = {"linear_solves": 0, "inner_iterations": 0, "fallback_sweeps": 0, "outer_iterations": 0,
             "level_steps": [], "level_seconds": [], "nit": 0}
    symmetric = bool(Am.isSymmetric(1e-14)) and zf.kind != 2
    t_setup = time.perf_counter()
    Ps = _Levels()
    if m == "newton" and hierarchy in ("amg", "auto") and zf.kind != 2:
        Ps = _Levels(lambda: _hierarchy(Am, comm, f"nrmicp_{id(stats)}_"))
    elif m == "newton" and isinstance(hierarchy, (list, tuple)):
        Ps = _Levels(pairs=[(P, None) for P in hierarchy])
    t_iter = time.perf_counter()
    if m == "newton":
        z, res, status, nit, iterations = _newton(Am, qv, zf, z0, Ps, tol, maxiter, symmetric, comm, stats)
    else:
        z, res, status, nit, iterations = _multisplitting(Am, qv, zf, z0, m, tol, maxiter, w1, w2, gamma,
                                                          alpha, beta, stats)
    polished = None
    if polish:
        zp, res = _polish(Am, qv, zf, z, res, comm, symmetric, stats)
        polished = zp is not None
        if zp is not None:
            z = zp
            if res < tol:
                status = Status.CONVERGED
    message = _message(status, res, tol, stats.get("floor"))
    criterion = {"measure": "units" if units else "paper", "target": float(tol), "value": float(res)}
    w, g, zt = z.duplicate(), z.duplicate(), z.duplicate()
    if units:
        status, message = at_rounding_floor(status, message, res, tol, lambda: _rounding_level(Am, qv, z, zf(z, zt)))
        res = _icp_residual(A_user, q_user, zf, z, w, g, zt)   # the paper's Res, and w, in the user's units
    else:
        Am.multAdd(z, qv, w)
    t_end = time.perf_counter()
    fields = dict(z=z, w=w, success=status == Status.CONVERGED, status=Status(status),
                  message=message, nit=int(nit), iterations=int(iterations),
                  residual=float(res), history=None, criterion=criterion,
                  timings={"setup": t_iter - t_setup + Ps.seconds, "iterations": t_end - t_iter - Ps.seconds,
                           "total": t_end - t_start},
                  method=m, inner=("cg" if symmetric else "bicgstab") if m == "newton" else "none",
                  counters={}, ranks=comm.getSize())
    if m == "newton":
        fields.update(_newton_fields(stats, iterations))
    if polish:
        fields["polished"] = polished
    return Result(**fields)


def _units_sigma(Am):
    """The default rule's σ (nrmicp._scaling.units_factor) from global sums over the diagonal."""
    d = Am.getDiagonal()
    a = np.abs(d.getArray(readonly=True))
    logs, count = d.duplicate(), d.duplicate()
    logs.setArray(np.log2(np.where(a > 0, a, 1.0)))
    count.setArray((a > 0).astype(float))
    return sigma_from_logs(float(logs.sum()), int(round(count.sum())))


def _target(Am, qv, zf, tol, rtol):
    """The absolute target of the problem the iteration runs on: the core's rule (Options::target)
    on Res(0) = ‖min(q, −ζ(0))‖₂."""
    if not rtol > 0:
        return tol
    zero, zt = qv.duplicate(), qv.duplicate()
    zero.set(0.0)
    zf(zero, zt)
    m = qv.duplicate()
    m.setArray(np.minimum(qv.getArray(readonly=True), -zt.getArray(readonly=True)))
    opts = _core.Options()
    opts.tol, opts.rtol = tol, rtol
    return opts.target(m.norm())


def _message(status, res, tol, floor):
    """The result's message: the serial member's, with the rounding level where Res settled there."""
    if status == Status.STAGNATED and floor is not None:
        return _core.floor_message(float(res), float(tol), float(floor))
    return _core.status_message(int(status))


def _start(Am, z0):
    """z0, or zeros in A's layout."""
    if z0 is not None:
        return z0.copy()
    z = Am.createVecLeft()
    z.set(0.0)
    return z


def _newton(Am, qv, zf, z0, Ps, tol, maxiter, symmetric, comm, stats):
    """The Newton member by ζ's kind: (z, Res, status, nit, iterations)."""
    if zf.kind == 2:
        z, res, status = _affine_newton(Am, qv, zf, _start(Am, z0), tol, maxiter, comm, stats)
    elif zf.kind == 3:
        z, res, status = _callable_newton(Am, qv, zf, z0, Ps, tol, maxiter, symmetric, comm, stats)
    else:
        z, res, status = _obstacle_newton(Am, qv, zf.c, z0, Ps, tol, maxiter, symmetric, comm, stats)
    return z, res, status, stats["nit"] or stats["level_steps"][0], sum(stats["level_steps"])


def _multisplitting(Am, qv, zf, z0, m, tol, maxiter, w1, w2, gamma, alpha, beta, stats):
    """A stationary member as the synchronous multisplitting: (z, Res, status, nit, iterations)."""
    a, b = _AOR_FIXED.get(m, (None, None))
    a = a if a is not None else (1.0 if alpha is None else float(alpha))
    b = b if b is not None else (a if beta is None else float(beta))
    member = _AOR(Am, a, b, w1, w2, float(gamma))
    z = _start(Am, z0)
    res, nit, status, iterations = _stationary(Am, qv, zf, member, z, tol, maxiter, stats)
    return z, res, status, nit, iterations


def _newton_fields(stats, iterations):
    """The Newton statistics of the result (the serial result's NewtonStats fields)."""
    return dict(linear_solves=stats["linear_solves"], inner_iterations=stats["inner_iterations"],
                fallback_sweeps=stats["fallback_sweeps"], outer_iterations=stats["outer_iterations"],
                level_steps=list(stats["level_steps"]), level_seconds=list(stats["level_seconds"]),
                path="newton+fallback" if stats["fallback_sweeps"] and iterations else
                ("fallback" if stats["fallback_sweeps"] else "newton"))


def _check_polish(polish):
    from ._newton import check_polish
    return check_polish(polish)


def gather(v):
    """A distributed Vec as one numpy array on rank 0 (None on the other ranks); collective."""
    scatter, out = PETSc.Scatter.toZero(v)
    scatter.scatter(v, out, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
    arr = out.getArray().copy() if v.getComm().getRank() == 0 else None
    scatter.destroy()
    out.destroy()
    return arr
