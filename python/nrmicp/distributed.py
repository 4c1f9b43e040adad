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

import numpy as np
import scipy.sparse as sp

try:
    from petsc4py import PETSc
except ImportError as exc:  # the core package needs no MPI; this module does
    raise ImportError("nrmicp.distributed needs petsc4py, PETSc (with hypre) and MPI: README, 'Beyond one machine' "
                      f"(make mpideps installs them on Debian); {exc}") from exc

from . import _bounds, _core, _options
from ._newton import AUTO_AMG_MIN_N, check_polish, polish_outcome, result_fields
from ._api import (Affine, Result, Status, _checked, _choice, _criterion, _iteration_options, _scalar, choose_method,
                   dominance_margin,
                   at_rounding_floor)
from ._scaling import sigma_from_logs
from ._inputs import as_constant, as_diagonal, as_vector
from ._zeta import CheckedZeta

__all__ = ["solve", "gather", "METHODS", "DistributedError"]

#: The distributed members: Newton, and the AOR-type NRM members as synchronous multisplitting.
METHODS = ("newton", "nrmj", "nrmgs", "nrmsor", "nrmaor")
#: nrmicp.solve's options that cannot apply on PETSc, and why (refused naming them unless at their defaults).
_UNSUPPORTED = {
    "scale": "the default rule's units scaling is the one scaling here",
    "accelerate": "the multisplitting members are not accelerated", "anderson_m": "no acceleration here",
    "phi": "the multisplitting members have phi = 0", "theta": "two_sweep is serial only",
    "z_update": "the multisplitting members update z explicitly",
    "inner": "the PETSc engine's reduced solves are its own: PETSc options -nrmicp_inner_...",
    "verbose": "no progress lines from several ranks",
    "components": "BoomerAMG builds the hierarchy: PETSc options -nrmicp_hierarchy_pc_hypre_boomeramg_...",
    "zeta_jacobian": "the PETSc engine has no Jacobian path yet: the outer fixed point solves a callable zeta"}
#: AOR parameters (alpha, beta) the members fix; None: the user's (default 1, beta = alpha).
_AOR_FIXED = {"nrmj": (1.0, 0.0), "nrmgs": (1.0, 1.0)}
#: Longest error message exchanged between ranks (bytes, UTF-8).
_MSG_LEN = 1024
#: Exception types re-raised as themselves on every rank; others become DistributedError.
_KNOWN = {e.__name__: e for e in (ValueError, TypeError, ZeroDivisionError, FloatingPointError,
                                  ArithmeticError, RuntimeError, KeyError, IndexError, MemoryError)}


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


def _flag_sum(comm, value: float) -> float:
    """sum over ranks of one float (as _flag_max)."""
    v = PETSc.Vec().createMPI((1, PETSc.DECIDE), comm=comm)
    v.setValue(v.getOwnershipRange()[0], value)
    v.assemble()
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
            self.kind, self.c = 1, _local(zeta, A, "zeta", scalar_ok=True, infinite=-1)  # -inf: free below

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

    def core_args(self, A):
        """(kind, c, fn) for the PETSc engine: this rank's c; a callable (or an affine ζ, as its product
        B z + c) as a CheckedZeta of this rank's rows whose every call is collective (a failure on any
        rank raises on all, in the same call of the one driver)."""
        kinds = _core.ZetaKind
        if self.kind == 0:
            return kinds.none, None, None
        if self.kind == 1:
            return kinds.constant, np.array(self.c.getArray(readonly=True)), None
        zv, out = A.createVecRight(), A.createVecLeft()

        def affine(z):
            zv.setArray(z)
            self.B.multAdd(zv, self.c, out)
            return np.array(out.getArray(readonly=True))
        local = affine if self.kind == 2 else (lambda z: _collective(self.comm, self._checked, z))
        return kinds.functor, None, CheckedZeta(local, A.getLocalSize()[0])


# ----------------------------------------------------------------------------- the pieces
def _abs_mat(A):
    """|A| entry-wise, in A's layout (built for a floor test: at most a few a solve)."""
    indptr, cols, vals = A.getValuesCSR()
    return PETSc.Mat().createAIJ(size=A.getSizes(), csr=(indptr, cols, np.abs(vals)), comm=A.getComm())


def _rounding_level(A, q, z, zt):
    """The serial member's rounding level of Res (detail/newton_level.hpp): eps ‖t‖, t the rounding of
    each row's term of Res (_bounds.term_rounding); zt = ζ(z), None for ζ = 0."""
    absA = _abs_mat(A)
    za = z.copy()
    za.abs()
    t = z.duplicate()
    absA.mult(za, t)
    absA.destroy()
    w = z.duplicate()
    A.multAdd(z, q, w)
    zl = z.getArray(readonly=True)
    g = zl - zt.getArray(readonly=True) if zt is not None else zl
    t.setArray(_bounds.term_rounding(t.getArray(readonly=True) + np.abs(q.getArray(readonly=True)), zl,
                                     w.getArray(readonly=True), g, None))
    level = float(np.finfo(float).eps * t.norm())
    for v in (za, t, w):
        v.destroy()
    return level


#: Options with this prefix tune the nesting hierarchy's BoomerAMG (e.g. -nrmicp_hierarchy_pc_hypre_boomeramg_P_max 4).
_HIERARCHY_PREFIX = "nrmicp_hierarchy_"


#: hypre's options for one aggressive first level (2 paths, multipass weights, at most 4 a row), taken where
#: classical coarsening's first level would hold more nonzeros than A (_dense_first_level).
_AGGRESSIVE = {"agg_nl": 1, "agg_num_paths": 2, "P_max": 4}
#: A's distance-two neighbourhoods more than this many times its rows' (A²'s nonzeros over A's) on a stencil of
#: at most _SPARSE_STENCIL nonzeros a row: 7-point 3D grids (3.5); not 5-point 2D grids (2.6), P1 triangles
#: (2.7) or P2 (4.1 but 11.4 a row), whose classical first levels are sparser than A (docs/MEASUREMENTS.md).
_DENSE_GROWTH = 3.0
_SPARSE_STENCIL = 8.0


def _dense_first_level(A, comm, sample=2000) -> bool:
    """Whether BoomerAMG's classical first coarse level would be denser than A, judged by A's
    neighbourhood growth on up to `sample` evenly spaced rows of each rank's diagonal block (every
    rank decides alike: sums over ranks)."""
    indptr, indices, data = A.getDiagonalBlock().getValuesCSR()
    m = len(indptr) - 1
    B = sp.csr_matrix((np.ones(len(indices)), indices, indptr), shape=(m, m))
    S = B[np.unique(np.linspace(0, m - 1, min(m, sample)).astype(int))] if m else B
    rows, first, second = (_flag_sum(comm, float(v)) for v in (S.shape[0], S.nnz, (S @ B).nnz))
    return first > 0 and first / rows <= _SPARSE_STENCIL and second / first > _DENSE_GROWTH


def _hierarchy(A, comm, prefix):
    """hypre BoomerAMG's classical prolongations and its Galerkin operators PᵀAP, finest first
    (A excluded), read through PCHMG, with one aggressive first level where a classical one would be
    denser than A (_dense_first_level). PCMG's smoothers are never applied here: Richardson without
    a preconditioner spares their set-up (Chebyshev's eigenvalue estimates: docs/MEASUREMENTS.md)."""
    ours = {"pc_hmg_reuse_interpolation": True, "hmg_inner_pc_type": "hypre",
            "mg_levels_ksp_type": "richardson", "mg_levels_pc_type": "none"}
    if _dense_first_level(A, comm):
        ours.update({"hmg_inner_pc_hypre_boomeramg_" + k: v for k, v in _AGGRESSIVE.items()})
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


def _icp_residual(A, q, zeta, z, w, g, zt, upper=None):
    """Res(z) = ‖min(Az + q, z − ζ(z))‖ (w, g, zt = ζ(z) filled); with this rank's upper bounds,
    ‖mid(z − ζ(z), z − upper, w)‖ (the serial nrmicp.residual)."""
    A.multAdd(z, q, w)
    zeta(z, zt)
    z.copy(g)
    g.axpy(-1.0, zt)
    m = w.duplicate()
    wa, ga = w.getArray(readonly=True), g.getArray(readonly=True)
    if upper is not None:
        wa = np.maximum(z.getArray(readonly=True) - upper, wa)
    m.setArray(np.minimum(wa, ga))
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


# ----------------------------------------------------------------------------- the entry points
def _prepare(A, q, zeta, x0, comm, method, tol, maxiter, omega1, omega2, gamma, alpha, beta, hierarchy, rtol=0.0):
    """Every check, with every rank's failure raised on all ranks; returns the PETSc objects."""
    A_in = _collective(comm, _check_mat, A)
    Am = _as_mat(A_in, comm) if sp.issparse(A_in) else A_in
    n, nloc = Am.getSize()[0], Am.getLocalSize()[0]
    if isinstance(method, str) and method.lower() == "auto":
        method = _auto_method(Am, {"hierarchy": hierarchy, "alpha": alpha, "beta": beta}, comm)

    def local():
        m, w1, w2 = _check_options(method, n, tol, maxiter, omega1, omega2, gamma, alpha, beta, nloc, rtol)
        if m != "newton" and hierarchy not in (None, "amg", "auto"):
            raise ValueError(f"hierarchy is the nested iteration of method 'newton'; got {hierarchy!r}")
        if m == "newton" and not (hierarchy in (None, "amg", "auto") or isinstance(hierarchy, (list, tuple))):
            raise ValueError(f"hierarchy must be 'amg', None or a list of PETSc prolongations; got {hierarchy!r}")
        qa = _local(q, Am, "q")
        xa = None if x0 is None else _local(x0, Am, "x0")
        zf = _Zeta(zeta, Am, comm)
        if m != "newton" and zf.kind == 1 and np.any(np.isneginf(zf.c)):
            raise ValueError(f"zeta: -inf entries (rows free below) are solved by method 'newton' in "
                             f"nrmicp.distributed, got method {m!r}")
        return m, w1, w2, qa, xa, zf
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


def solve(A, q, zeta=None, *, upper=None, comm=None, **options) -> Result:
    """Solve ICP(q, A, ζ) on all ranks of A's communicator (call it on every rank).

    A: petsc4py Mat (AIJ, square, same row and column layout) or this rank's scipy.sparse row
    block (n_local, n). q, x0, upper: petsc4py Vec in A's row layout or this rank's rows. zeta: None,
    a constant (scalar, this rank's rows or a Vec), :class:`nrmicp.Affine` (B a petsc4py Mat in
    A's layout, c) or a callable mapping this rank's rows of z to this rank's rows of ζ(z)
    (entry-wise or row-local ζ only). method: 'newton' — the serial library's Newton member itself
    (nrmicp::Newton on the PETSc engine, nrmicp._petsc), nested over hypre BoomerAMG's prolongations
    with hierarchy='amg', cold with None, or over a list of PETSc prolongation Mats, finest first; an
    affine ζ runs its outer fixed point — or 'nrmj', 'nrmgs', 'nrmsor', 'nrmaor' (synchronous
    multisplitting). upper (method 'newton'): z ≤ upper, as in :func:`nrmicp.solve`, constant only (an Affine or callable upper
    raises NotImplementedError). callback(k, z, res)
    sees this rank's rows of z; returning True on any rank stops every rank.
    ``options`` are :func:`nrmicp.solve`'s, with its defaults, checked by the same code (one table:
    nrmicp._options); those that cannot apply on PETSc (``_UNSUPPORTED``: scale, accelerate, anderson_m,
    phi, theta, z_update, inner, verbose, components, zeta_jacobian) raise a ValueError naming them.
    method='auto' is nrmicp.solve's rule on every rank's rows; hierarchy='auto' is 'amg' from
    n = 4096 on (BoomerAMG: no pyamg needed).
    tol and rtol both None is nrmicp.solve's default rule (units-free Res_E, rtol 1e-10), applied by
    solving σA, σq (σ from the diagonal's global geometric mean), ``residual`` the paper's Res.
    Returns a :class:`nrmicp.Result` on every rank, with ``z`` and ``w`` as PETSc Vecs
    (:func:`gather` copies one to rank 0). A failure on any rank raises on every rank.
    """
    comm = comm or (A.getComm() if isinstance(A, PETSc.Mat) else PETSc.COMM_WORLD)
    _collective(comm, lambda: _options.validate(options, where="distributed.solve", unsupported=_UNSUPPORTED))
    o = {**_options.defaults(), **options}
    method, tol, rtol, maxiter, x0, hierarchy = (o[k] for k in ("method", "tol", "rtol", "maxiter", "x0", "hierarchy"))
    omega1, omega2, gamma, alpha, beta = (o[k] for k in ("omega1", "omega2", "gamma", "alpha", "beta"))
    polish, callback, record_history = o["polish"], o["callback"], o["record_history"]
    t_start = time.perf_counter()
    it, units = _criterion({"tol": tol, "rtol": rtol})
    Am, m, w1, w2, qv, z0, zf = _prepare(A, q, zeta, x0, comm, method, it["tol"], maxiter, omega1, omega2,
                                         gamma, alpha, beta, hierarchy, it["rtol"])
    ua = _upper(upper, Am, zf, comm, m)
    A_user, q_user = Am, qv
    if units:   # the iteration runs on σA, σq: its Res is the units-free Res_E
        sigma = _units_sigma(Am)
        Am, qv = Am.copy(), qv.copy()
        Am.scale(sigma)
        qv.scale(sigma)
        w2 = None if w2 is None else sigma * w2
    polish = bool(_collective(comm, lambda: check_polish(polish)))
    if m == "newton":
        z, res, status, message, tol, fields = _newton(Am, qv, zf, z0, ua, hierarchy, it, maxiter, w1, w2, gamma,
                                                       polish, callback, record_history, o["stall_iterations"], comm)
    else:
        tol = _target(Am, qv, zf, it["tol"], it["rtol"])
        t_iter = time.perf_counter()
        z, res, status, nit, iterations = _multisplitting(Am, qv, zf, z0, m, tol, maxiter, w1, w2, gamma,
                                                          alpha, beta, {})
        message = _core.status_message(int(status))
        fields = dict(nit=int(nit), iterations=int(iterations), history=None, inner="none", counters={},
                      timings={"setup": t_iter - t_start, "iterations": time.perf_counter() - t_iter})
    criterion = {"measure": "units" if units else "paper", "target": float(tol), "value": float(res)}
    w, g, zt = z.duplicate(), z.duplicate(), z.duplicate()
    if units:
        status, message = at_rounding_floor(status, message, res, tol, lambda: _rounding_level(Am, qv, z, zf(z, zt)))
        res = _icp_residual(A_user, q_user, zf, z, w, g, zt, ua)   # the paper's Res, and w, in the user's units
    else:
        Am.multAdd(z, qv, w)
    fields["timings"]["total"] = time.perf_counter() - t_start
    return Result(z=z, w=w, success=status == Status.CONVERGED, status=Status(status), message=message,
                  residual=float(res), criterion=criterion, method=m, ranks=comm.getSize(), **fields)


def _auto_method(Am, options, comm):
    """nrmicp.solve's method='auto' (choose_method), A's dominance margin reduced over the ranks."""
    indptr, _, vals = Am.getValuesCSR()
    rows = sp.csr_matrix((vals, np.zeros_like(vals, dtype=np.int32), indptr), shape=(len(indptr) - 1, 1))
    local = dominance_margin(rows, np.array(Am.getDiagonal().getArray(readonly=True))) if rows.shape[0] else math.inf
    margin = -_flag_max(comm, -local)   # (a rank without rows has no say)
    return choose_method(None, options, margin)


def _upper(upper, Am, zf, comm, method):
    """This rank's rows of the upper bound (None: none); method 'newton' only."""
    if upper is None:
        return None

    def local():
        if callable(upper) or isinstance(upper, Affine):   # (the core would take it; the glue's Res does not)
            raise NotImplementedError("upper: an implicit upper bound (Affine or callable) is solved by nrmicp.solve "
                                      "only; nrmicp.distributed.solve takes a constant upper (a number, this rank's "
                                      "rows or a Vec)")
        if method != "newton":
            raise ValueError(f"upper: bounds are solved by method 'newton' in nrmicp.distributed, got method {method!r}")
        u = _local(upper, Am, "upper", scalar_ok=True, infinite=1)
        kind = (_core.ZetaKind.none, _core.ZetaKind.constant, _core.ZetaKind.affine, _core.ZetaKind.functor)[zf.kind]
        c = None if zf.c is None or zf.kind != 1 else np.array(zf.c.getArray(readonly=True))
        _bounds.check(kind, c, u, method, None)
        return u
    return _collective(comm, local)


def _prolongations(Am, hierarchy, comm):
    """The nesting hierarchy's prolongations and their Galerkin operators (None: formed by the core)
    as PETSc Mats, and what keeps them alive (hypre's PC)."""
    if hierarchy == "amg" or (hierarchy == "auto" and Am.getSize()[0] >= AUTO_AMG_MIN_N):
        Ps, As, pc = _hierarchy(Am, comm, f"nrmicp_{id(Am)}_")
        return Ps, As, pc
    if isinstance(hierarchy, (list, tuple)):
        return list(hierarchy), [], None
    return [], [], None


def _newton(Am, qv, zf, z0, ua, hierarchy, it, maxiter, w1, w2, gamma, polish, callback, record_history, stall, comm):
    """The Newton member: nrmicp::Newton on the PETSc engine (nrmicp._petsc), its every decision the
    serial member's. Returns (z, Res, status, message, tol, the result's other fields)."""
    from . import _petsc
    t0 = time.perf_counter()
    Ps, As, keep = _prolongations(Am, hierarchy, comm)
    o = _core.Options()
    o.method, o.tol, o.rtol, o.maxiter, o.gamma = _core.Method.newton, it["tol"], it["rtol"], maxiter, float(gamma)
    o.record_history, o.stall_iterations = bool(record_history), int(stall)
    if w1 is not None:
        o.omega1 = w1
    if w2 is not None:
        o.omega2 = w2
    core = _collective(comm, lambda: _petsc.Newton(Am.handle, o, [P.handle for P in Ps],
                                                   [C.handle for C in As] if len(As) == len(Ps) else []))
    t_iter = time.perf_counter()
    kind, c, fn = zf.core_args(Am)
    args = (np.array(qv.getArray(readonly=True)), kind, c, fn, ua)
    x0 = None if z0 is None else np.array(z0.getArray(readonly=True))
    d = core.solve(*args, x0, callback, o)
    tol = _target_of(o, Am, qv, zf, ua)
    z_arr, res, status, message = d["z"], d["residual"], Status(d["status"]), d["message"]
    polished = None
    if polish:
        p = core.polish(*args, z_arr, tol)
        polished = p["residual"] < res
        if polished:
            z_arr, res = p["z"], p["residual"]
        status, message = polish_outcome(status, message, res, tol, polished, p)
        status = Status(status)
    z = _vec(Am, z_arr)
    report = core.hierarchy
    fields = dict(nit=int(d["nit"]), iterations=int(d["iterations"]), inner=core.inner, counters=dict(d["counters"]),
                  history=d["history"], timings={"setup": t_iter - t0, "iterations": time.perf_counter() - t_iter},
                  **result_fields(d, report))
    if polish:
        fields["polished"] = polished
    del keep
    return z, res, status, message, tol, fields


def _target_of(o, Am, qv, zf, ua):
    """The absolute target the core resolved from tol and rtol (Options::target on the bounded Res(0))."""
    if not o.rtol > 0:
        return o.tol
    z = qv.duplicate()
    z.set(0.0)
    w, g, zt = z.duplicate(), z.duplicate(), z.duplicate()
    return o.target(_icp_residual(Am, qv, zf, z, w, g, zt, ua))


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


def _start(Am, z0):
    """z0, or zeros in A's layout."""
    if z0 is not None:
        return z0.copy()
    z = Am.createVecLeft()
    z.set(0.0)
    return z


def _multisplitting(Am, qv, zf, z0, m, tol, maxiter, w1, w2, gamma, alpha, beta, stats):
    """A stationary member as the synchronous multisplitting: (z, Res, status, nit, iterations)."""
    a, b = _AOR_FIXED.get(m, (None, None))
    a = a if a is not None else (1.0 if alpha is None else float(alpha))
    b = b if b is not None else (a if beta is None else float(beta))
    member = _AOR(Am, a, b, w1, w2, float(gamma))
    z = _start(Am, z0)
    res, nit, status, iterations = _stationary(Am, qv, zf, member, z, tol, maxiter, stats)
    return z, res, status, nit, iterations


def gather(v):
    """A distributed Vec as one numpy array on rank 0 (None on the other ranks); collective."""
    scatter, out = PETSc.Scatter.toZero(v)
    scatter.scatter(v, out, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
    arr = out.getArray().copy() if v.getComm().getRank() == 0 else None
    scatter.destroy()
    out.destroy()
    return arr
