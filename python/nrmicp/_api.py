"""The Python API: solve(), Solver, Affine, Result, Status."""
from __future__ import annotations

import contextlib
import enum
import logging
import math
import re
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable, Optional, Union

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from . import _core
from ._inputs import WholeRows, as_csr, as_vector
from ._scaling import SCALINGS, ScaledCallable, equilibrate, scale_matrix, row_spread, units_factor, units_weights
from . import _bounds, _newton, _options
from ._options import _INT_MAX, _choice, _scalar  # noqa: F401 (the distributed glue imports them from here)
from ._zeta import CheckedZeta
from ._decoupled import Reduced, decoupled_rows
from ._hierarchy import Hierarchy, check_components
from ._result import Result, wants_result
from ._infeasible import box_infeasibility, evident_infeasibility

__all__ = ["solve", "Solver", "Affine", "Result", "Status", "METHODS", "residual", "backends"]

#: What ``A`` may be: a scipy.sparse matrix or a dense 2-D array.
MatrixLike = Any
#: What ``zeta`` may be: None (LCP), a constant, :class:`Affine`, or a callable z -> ζ(z).
ZetaLike = Union[None, float, ArrayLike, "Affine", Callable[[np.ndarray], ArrayLike]]
#: A diagonal parameter (omega1, omega2, phi): a scalar (times I) or a length-n vector.
DiagonalLike = Union[None, float, ArrayLike]

# The options and the statuses are declared once, in the C++ core (options.hpp's option table,
# read by _options.py; result.hpp).
#: The methods, in the order of the paper: the NRM family, then the baselines.
METHODS = tuple(_core.Method.__members__)
#: method= also takes "auto" (the default): nrmgs or newton by choose_method's rule.
METHOD_CHOICES = _options.choices("method")
Z_UPDATES = _options.choices("z_update")
INNERS = _options.choices("inner")
ACCELERATIONS = _options.choices("accelerate")

class _NamedIntEnum(enum.IntEnum):
    """An IntEnum (compares and indexes like the core's int codes) that prints its name:
    str(), format() and f-strings give 'CONVERGED' (a numeric spec such as ':d' the code),
    repr() 'Status.CONVERGED'."""

    def __str__(self) -> str:
        return self.name

    def __repr__(self) -> str:
        return f"{type(self).__name__}.{self.name}"

    def __format__(self, spec: str) -> str:
        if spec and spec[-1] in "bcdoxXneEfFgG%":  # a numeric format asks for the code
            return format(int(self), spec)
        return format(self.name, spec)


#: Why a solve ended (CONVERGED, MAX_ITERATIONS, DIVERGED, STAGNATED, CALLBACK_STOP, ZETA_FAILED);
#: only CONVERGED means success. ``nrmicp._core.status_message(code)`` says what each means.
#: The members come from the C++ core (result.hpp), the one place they are defined.
Status = _NamedIntEnum("Status", [(name, int(v)) for name, v in _core.Status.__members__.items()],
                       module=__name__)


@dataclass(frozen=True)
class Affine:
    """ζ(z) = B z + c, evaluated in C++ (no Python call per iteration)."""
    B: MatrixLike
    c: Union[float, ArrayLike]

    def __call__(self, z: np.ndarray) -> np.ndarray:
        return self.B @ z + self.c


_WHY_MISSING = {
    "disabled": "disabled at build time (NRMICP_USE_SUITESPARSE=OFF)",
    "not found": "not found at build time (install libsuitesparse-dev, then rebuild nrmicp)",
}


def backends(why: bool = False) -> Union[dict[str, bool], dict[str, str]]:
    """Which inner solvers this build has: ``{'cholmod': bool, 'umfpack': bool, 'eigen_llt': True,
    'eigen_lu': True}``. With ``why=True`` the values say why instead: ``'compiled in'``,
    ``'disabled at build time (NRMICP_USE_SUITESPARSE=OFF)'`` or ``'not found at build time ...'``
    (recorded by CMake when the module was configured)."""
    have = {name: bool(v) for name, v in _core.backends().items()}
    if not why:
        return have
    try:
        from ._build_info import BACKENDS as recorded
    except ImportError:  # a module built outside CMake's install step
        recorded = {}
    return {name: "compiled in" if ok else _WHY_MISSING.get(recorded.get(name, ""), "not compiled in")
            for name, ok in have.items()}


def residual(A: MatrixLike, q: ArrayLike, z: ArrayLike, zeta: ZetaLike = None, *, upper: Any = None) -> float:
    """Res(z) = ‖min(Az + q, z − ζ(z))‖₂, computed in numpy (independent of the C++ core); +inf when
    Az + q overflows. With bounds (``upper``, or ζ with -inf entries): ‖mid(z − ζ, z − upper, Az + q)‖₂.
    The arguments are checked as :func:`solve` checks them (TypeError/ValueError naming the argument)."""
    A = as_csr(A, "A")
    n = A.shape[0]
    qv, zv = as_vector(q, n, "q"), as_vector(z, n, "z")
    kind, c, B, fn = _make_zeta(zeta, n)
    us = _make_upper(upper, n)
    if us is not None:
        _bounds.check(kind, c, us, "newton", None)
    with np.errstate(over="ignore", invalid="ignore"):
        return _OriginalResidual(A, qv, kind, c, B, None if fn is None else CheckedZeta(fn, n), upper=us)(zv)[1]


def _norm(m) -> float:
    """‖m‖₂ without overflow or underflow: numpy's plain norm where its sum of squares is safe,
    else scaled by max |mᵢ|."""
    with np.errstate(over="ignore", under="ignore"):
        plain = float(np.linalg.norm(m))
    if 1e-140 < plain < 1e150:
        return plain
    big = float(np.max(np.abs(m), initial=0.0))
    if not (0.0 < big < math.inf):
        return plain
    return big * float(np.linalg.norm(m / big))


def _iteration_options(opts, **values):
    """Fill a core SolveOptions (or Options) from per-solve options, checking types here (_options.fill);
    values are checked by the core (Options.check), which knows the rules."""
    return _options.fill(opts, values)


#: Progress lines of solves with ``verbose > 0`` go to this logger (level INFO).
logger = logging.getLogger("nrmicp")


def _log_progress(line):
    """One progress line: to the 'nrmicp' logger, and to stderr when logging is not configured
    (no handler would show an INFO record), as scipy/OSQP print their progress."""
    logger.info(line)
    if not logger.hasHandlers():
        print(line, file=sys.stderr, flush=True)


def _progress_hook(method, n):
    """The core calls this every `verbose` seconds (not every iteration), and once at the end with
    its message: that last call is left out, Solver.solve's final line reports the Result instead
    (re-solves, polishing and the decoupled rows change status, message and nit after the core)."""
    def report(k, res, best, seconds, message):
        if not message:
            _log_progress(f"nrmicp {method}: iteration {k:>7d}  Res {res:.3e}  best {best:.3e}  {seconds:9.2f} s")
    return report


def _log_final(method, result, seconds):
    """The final progress line: the returned result's message, nit (and the iterations run when
    they differ: the best iterate is not the last), the call's seconds."""
    count = f"nit = {result.nit}" + (f" of {result.iterations} iterations" if result.iterations != result.nit else "")
    _log_progress(f"nrmicp {method}: {result.message} ({count}, {seconds:.2f} s)")


def _checked(opts, n):
    """opts after the core's Options.check (ValueError naming the field)."""
    opts.check(n)
    return opts


ZetaKind = _core.ZetaKind  # the C++ core's (zeta.hpp): none, constant, affine, functor


def _make_zeta(zeta, n, read=None):
    """Validate ζ -> (kind, c, B, fn): a ZetaKind, the constant c (constant, affine), B canonical
    CSR (affine), the callable (functor). `read`: how B and c are read (_inputs.WholeRows(n) unless
    given: nrmicp.distributed reads this rank's rows)."""
    read = read or WholeRows(n)
    if zeta is None:
        return ZetaKind.none, None, None, None
    if isinstance(zeta, Affine):
        B = read.matrix(zeta.B, "zeta.B")
        return ZetaKind.affine, read.vector(zeta.c, "zeta.c"), B, None
    if callable(zeta):
        return ZetaKind.functor, None, None, zeta
    return ZetaKind.constant, read.vector(zeta, "zeta", infinite=-1), None, None   # (-inf: free below)


def _make_upper(upper, n, read=None):
    """``upper=`` checked -> None, a vector (+inf: no bound there) or an implicit upper bound
    (_bounds.ImplicitUpper: an Affine or a callable); `read` as in _make_zeta."""
    return _bounds.as_upper(upper, n, (upper.B, upper.c) if isinstance(upper, Affine) else None, read)


def _scale_choice(scale):
    if scale is None or scale is False:
        return None
    if scale is True:
        return "both"
    if isinstance(scale, str) and scale.lower() in SCALINGS:
        return scale.lower()
    raise ValueError(f"scale must be False, True, 'rows' or 'both'; got {scale!r}")


#: The default stopping rule (tol and rtol both left None): Res measured in the units of z,
#: Res_E(z) = ‖min(D(Az + q), z − ζ(z))‖₂ with D_ii = 1/(the size of row i) (_scaling.units_weights),
#: below DEFAULT_RTOL · Res_E(0): a change of units of A and q, of a row, or of z, changes nothing. The value is
#: the loosest that keeps the stationary members' error below 1e-6 (docs/MEASUREMENTS.md, "DEFAULT_RTOL").
DEFAULT_RTOL = 1e-10


def core_options(values: dict, method: str, n: int, resolved: dict):
    """The core's Options of `method` on n rows: the splitting and the inner solver from `values`, the
    per-solve options `resolved` (tol and rtol numbers: _criterion's), checked by the core (both engines)."""
    opts = _core.Options()
    opts.method = getattr(_core.Method, method)
    _options.fill(opts, {k: values[k] for k in _SPLITTING}, n)
    return _checked(_iteration_options(opts, **resolved), n)


def _criterion(it: dict) -> tuple[dict, bool]:
    """(it with numeric tol and rtol, units): units is True for the default rule (tol and rtol both
    None: DEFAULT_RTOL on the units-free measure Res_E); else the paper's Res with max(tol, rtol ·
    Res(0)), a missing one taken as 0."""
    tol, rtol = it["tol"], it["rtol"]
    if tol is None and rtol is None:
        return dict(it, tol=0.0, rtol=DEFAULT_RTOL), True
    return dict(it, tol=0.0 if tol is None else tol, rtol=0.0 if rtol is None else rtol), False


def _absolute_target(it: dict, checked_opts, measure, n: int) -> dict:
    """The iteration options with an absolute tol: the core's rule (Options::target) max(tol,
    rtol · Res(0)) when rtol > 0, Res(0) in the original variables; then rtol = 0."""
    if checked_opts.rtol > 0:
        return dict(it, tol=checked_opts.target(measure(np.zeros(n))[1]), rtol=0.0)   # target: inf Res(0) counts 0
    return dict(it, tol=float(it["tol"]))


def _core_callback(callback: Callable[..., Any], dc: Optional[np.ndarray],
                   offset: Optional[list] = None) -> Callable[[int, np.ndarray, float], bool]:
    """The core's per-iterate hook (k, z, Res) -> stop?, calling ``callback`` by scipy's rule:
    a callback whose only parameter is named ``intermediate_result`` receives a :class:`Result`
    with ``z`` (= ``x``), ``nit`` and ``residual``; any other callback receives the iterate z
    alone (``callback(xk)``). Raising StopIteration (or returning True) stops the solve.
    ``dc``: column scaling, mapping the core's z back to the original variables. ``offset[0]``:
    the iterations of earlier rounds (scaled re-solves), added to k as the history does."""
    wants = wants_result(callback)

    def hook(k: int, z: np.ndarray, res: float) -> bool:
        zk = z * dc if dc is not None else z  # a fresh array: the core passes a copy
        try:
            nit = k + offset[0] if offset else k
            stop = callback(intermediate_result=Result(z=zk, nit=nit, residual=res)) if wants \
                else callback(zk)
        except StopIteration:
            return True
        return callback_stops(stop)

    return hook


def callback_stops(stop) -> bool:
    """Whether a callback's return value stops the solve (its truth value); TypeError for one without any."""
    try:
        return bool(stop)
    except (TypeError, ValueError):   # an array of several entries has no truth value
        raise TypeError(f"callback must return None or a bool (True stops the solve), got {type(stop).__name__}") from None


def _omega2_hint(diagonal, method, omega2, accelerate) -> str:
    """What to try when the paper's nrm (Omega2 = I) does not converge, added to its message: only
    advice that applies to this A (omega2=A.diagonal(), nrmm and nrmgs need a positive diagonal).
    `diagonal`: A's diagonal, or (on PETSc, every a_ii positive) the mean of |a_ii| over all rows."""
    if method != "nrm" or omega2 is not None:
        return ""
    d = np.atleast_1d(diagonal)
    if not np.all(d > 0):
        i = int(np.flatnonzero(~(d > 0))[0])
        tried = (accelerate or "none").lower() == "anderson"
        return (f"; note: A[{i},{i}] = {d[i]:.3g}, so the advice for a positive diagonal (omega2=A.diagonal(), "
                f"'nrmm', 'nrmgs') does not apply: try method 'newton'"
                f"{'' if tried else ' or accelerate=' + repr('anderson')}")
    dmean = float(np.mean(np.abs(d)))
    if 0.1 <= dmean <= 10:
        return ""
    return (f"; note: method 'nrm' uses the paper's Omega2 = I, while mean |diag(A)| = "
            f"{dmean:.3g}: pass omega2=A.diagonal() or use method 'nrmm' or 'nrmgs'")


@contextlib.contextmanager
def _user_entries(A, A_core):
    """The core's ValueErrors name entries of the matrix it was given: "A[i,j] = v" of a scaled
    A_core is rewritten to the user's A[i,j]."""
    try:
        yield
    except ValueError as exc:
        if A_core is A:
            raise
        text = re.sub(r"A\[(\d+),(\d+)\] = [-+0-9.eE]+|A\[(\d+),(\d+)\] = (?:-?inf|nan)",
                      lambda m: f"A[{m[1]},{m[2]}] = {A[int(m[1]), int(m[2])]:g}" if m[1] else m[0], str(exc))
        if text == str(exc):
            raise
        raise type(exc)(text) from None   # LinAlgError stays LinAlgError


def _units_parameters(opts, method: str, sigma: float, n: int) -> None:
    """The parameters in the units of w (Ω2, φ, nrmm's α) for the core's σA, σq, so that the
    iterates are those of A, q (σ a power of two: bit for bit); nrm's default Ω2 = I becomes σI."""
    if opts.omega2.size:
        opts.omega2 = sigma * np.asarray(opts.omega2)
    elif method == "nrm":
        opts.omega2 = np.full(n, sigma)
    if opts.phi.size:
        opts.phi = sigma * np.asarray(opts.phi)
    if method == "nrmm" and not math.isnan(opts.alpha):
        opts.alpha = sigma * opts.alpha


#: method="auto" takes nrmgs when every row of A is diagonally dominant by at least this fraction of
#: its diagonal (Gauss–Seidel then contracts by about 1 − margin a sweep: tens of sweeps, as on Bai's
#: shifted matrices, margin 0.5), else newton: an unshifted elliptic A (margin 0 on its interior
#: rows) needs O(h⁻²) sweeps, and a zero or negative diagonal stops the AOR-type members.
AUTO_MARGIN = 0.25
#: Options only the stationary members read: given with method="auto", they choose nrmgs.
_STATIONARY_ONLY = {k: _options.TABLE[k].default for k in ("accelerate", "z_update", "theta", "alpha", "beta")}
#: The set-up options the core's Options holds beside the method (the splitting, the inner solver).
_SPLITTING = tuple(k for k in _options.names("setup") if _options.TABLE[k].kind != "python" and k != "method")


def dominance_margin(A: sp.csr_matrix, diagonal=None) -> float:
    """min_i (a_ii − Σ_{j≠i} |a_ij|) / a_ii over the rows of A; −inf when some a_ii <= 0.
    `diagonal`: the rows' a_ii when A is a block of rows (a rank's, in nrmicp.distributed)."""
    d = A.diagonal() if diagonal is None else diagonal
    if A.shape[0] == 0 or not np.all(d > 0):   # (an empty row has a_ii = 0: every row is stored below)
        return -math.inf
    row_sums = np.add.reduceat(np.abs(A.data), A.indptr[:-1])   # one pass, no copy of A
    return float(np.min((2 * d - row_sums) / d))


def choose_method(A: sp.csr_matrix, options: dict, margin=None) -> str:
    """What method="auto" takes for A (the rule of README "Which method for which problem"):
    the member of any stationary-only option given, newton for a hierarchy list (and, in
    :func:`solve`, for a ``zeta_jacobian``), else nrmgs where A's rows are dominant by AUTO_MARGIN and newton elsewhere.
    `margin`: A's dominance_margin when known (nrmicp.distributed reduces it over the ranks)."""
    if any(options.get(k, v) is not None and options.get(k, v) != v for k, v in _STATIONARY_ONLY.items()):
        return "nrmgs"
    if isinstance(options.get("hierarchy"), (list, tuple, Hierarchy)):
        return "newton"
    return "nrmgs" if (dominance_margin(A) if margin is None else margin) >= AUTO_MARGIN else "newton"


def failure_hint(method: str, omega2_hint: str, margin: Callable[[], float], default_rule: bool, kind,
                 infeasibility: Callable[[], str] = str, spread: Callable[[], float] = lambda: 1.0
                 ) -> Callable[[Status], str]:
    """hint(status) for _settle, both engines: the sentence added to the message of a solve that did not
    converge — why an infeasible problem has no solution, else the nrm hint (`omega2_hint`), and where the
    iterations ran out or stalled, the member, outer-fixed-point and row-scaling advice. `margin()`: A's
    dominance margin, asked only then (on PETSc a reduction: every rank has the same status); `default_rule`:
    the solve iterated under the default rule (Res_E); `kind`: ζ's ZetaKind as the user gave it; `spread()`:
    how far A's rows lie apart in size (_scaling.row_spread), 1 where scale='rows' cannot help (given a
    scaling, or on PETSc, which has no scale option)."""
    def hint(status):
        infeasible = infeasibility()   # (no parameter or member helps an infeasible problem)
        if infeasible or status not in (Status.MAX_ITERATIONS, Status.STAGNATED):
            return infeasible or omega2_hint
        return (omega2_hint + _member_hint(margin, method) + _outer_hint(method, default_rule, kind)
                + _rows_hint(spread))
    return hint


#: Rows whose sizes (max_j |a_ij|) lie further apart than this get the scale='rows' advice.
ROWS_APART = 1e4


def _rows_hint(spread: Callable[[], float]) -> str:
    """Advice for a solve that did not converge on an A whose rows lie far apart in size: the members weigh
    every row by one factor (σ under the default rule), so the large rows steer the steps and their Res."""
    s = spread()
    if not s > ROWS_APART:
        return ""
    return (f"; A's rows differ in size by a factor up to {s:.2g} (max_j |a_ij|), and the iteration weighs them "
            f"alike, so the large rows steer it: scale='rows' equilibrates them")


def _outer_hint(method: str, default_rule: bool, kind) -> str:
    """Advice for a newton solve on a callable ζ without Jacobian (the outer fixed point) that failed
    under the default rule: its target, 1e-10 of Res_E(0), may lie below what ζ's own evaluation
    resolves (a ζ that solves an ill-conditioned problem inside: docs/MEASUREMENTS.md, "The outer
    fixed point in z's units"); tol or rtol sets a target of the user's own."""
    if method != "newton" or not default_rule or kind != ZetaKind.functor:
        return ""
    return ("; the default target (Res_E below 1e-10 of its value at z = 0) may lie below what zeta itself resolves "
            "(its outer steps no longer contract there): pass tol (the paper's Res, e.g. tol=1e-8) or rtol")


def _member_hint(margin: Callable[[], float], method: str) -> str:
    """Advice for a stationary solve that did not converge, when newton is the member for this A
    (`margin()`: its dominance_margin)."""
    if method == "newton":
        return ""
    margin = margin()
    if margin >= AUTO_MARGIN:   # choose_method's rule: nrmgs is right for this A
        return ""
    why = ("A has a diagonal entry <= 0" if margin == -math.inf else
           f"A's rows are dominant by only {max(margin, 0.0):.2g} of their diagonal")
    return (f"; {why}, where the stationary members need O(h^-2) iterations: method='newton' "
            f"(what method='auto' takes for such an A, unless an option only they read is given) solves such "
            f"problems in a few Newton steps")


#: With scaling, at most this many re-solves with a tighter tolerance when the scaled problem
#: converged but Res in the original variables is still >= tol.
MAX_REFINEMENTS = 3


class Solver:
    """Set up once (splitting, factorizations), then solve ICP(q, A, ζ) for many q and ζ.

    ``Solver(A, method=..., **options)`` accepts the set-up options of :func:`solve`
    (method, omega1, omega2, gamma, phi, alpha, beta, inner, scale, hierarchy, components, polish) and defaults for the
    iteration options (tol, rtol, maxiter, theta, z_update, accelerate, anderson_m, record_history,
    stall_iterations, verbose), each of which :meth:`solve` may override (give ``tol``/``rtol`` here
    when every solve uses them: a Solver set up for the default rule iterates on σA, and a solve under
    the paper's tol then re-measures and may re-solve). A is referenced, not
    copied, when it is canonical float64 CSR and ``scale`` is off: do not modify it while the
    Solver lives. Threads may share a Solver (a ``newton`` one runs their solves one at a time); a
    ``newton`` solve started from inside a solve of the same Solver (its callback or ζ) raises
    RuntimeError: use a second Solver for an inner problem.

    Typical use: implicit time stepping (the same A every step, warm start from the previous
    solution)::

        s = nrmicp.Solver(A, method="nrmgs")
        for k in range(steps):
            res = s.solve(q_k, zeta=payoff, x0=res.z if k else None)
    """

    def __init__(self, A: MatrixLike, *, method: str = "auto", omega1: DiagonalLike = None,
                 omega2: DiagonalLike = None, gamma: float = 1.0, phi: DiagonalLike = None,
                 alpha: Optional[float] = None, beta: Optional[float] = None, inner: str = "auto",
                 tol: Optional[float] = None, rtol: Optional[float] = None, maxiter: int = 10000, theta: float = 1.0,
                 z_update: str = "auto",
                 accelerate: Optional[str] = "none", anderson_m: int = 5, record_history: bool = False,
                 stall_iterations: int = 100, scale: Union[bool, str] = False, verbose: int = 0,
                 hierarchy: Any = "auto", components: Any = None, polish: bool = False, _decouple: bool = True,
                 _units_factor: Optional[float] = None, _hierarchy_asked: Optional[tuple] = None) -> None:
        settings = _options.pick(locals(), "setup", "solve")   # the options, as given
        t0 = time.perf_counter()
        self.A = as_csr(A, "A")
        n = self.A.shape[0]
        if n == 0:
            raise ValueError("A must have at least one row, got shape (0, 0)")
        self.n = n
        if isinstance(hierarchy, Hierarchy):
            hierarchy.check_fits(self.A)
        # one label per unknown (None: scalar); a Reduced passes its rows' labels on
        settings["components"] = self._components = check_components(components, n)
        self._dr = self._dc = None
        method = _choice(method, METHOD_CHOICES, "method")
        self.method = choose_method(self.A, settings) if method == "auto" else method
        # The paper's NRM fixes Omega2 = I, which only suits diag(A) of order 1; say so on failure.
        self._omega2_hint = _omega2_hint(self.A.diagonal(), self.method, omega2, accelerate)
        self.scale = _scale_choice(scale)
        self._defaults = {k: settings[k] for k in _options.names("solve")}
        resolved, units = _criterion(self._defaults)
        opts = core_options(settings, self.method, n, resolved)
        # the default rule's σ: the whole A's (a Reduced passes it to the solver of its coupled rows)
        self._units_factor = units_factor(self.A) if _units_factor is None else _units_factor
        self._row_weights = None   # the default rule's measure (_units_weights), formed on its first solve
        # Newton: rows with a lone positive diagonal are solved in closed form, the rest on A_FF
        # (python/nrmicp/_decoupled.py); another ζ than none/constant solves on A (self._whole).
        D = decoupled_rows(self.A) if self.method == "newton" and _decouple else None
        self._reduced = None if D is None else Reduced(Solver, self.A, D, settings, self._units_factor)
        self._settings, self._whole_solver = settings, None
        if self._reduced is not None:
            self.polish = self._reduced.inner.polish
            self._hierarchy = self._reduced.inner._hierarchy   # it warned
            factorization = self._reduced.inner.setup_timings["factorization"]
        else:
            self._build_core(opts, hierarchy, polish, units, _hierarchy_asked)
            factorization = self._core.setup_timings()["factorization"]
        self._setup_timings = {"setup": time.perf_counter() - t0, "factorization": factorization}

    def _build_core(self, opts, hierarchy, polish, units, asked=None) -> None:
        """The C++ core on A (scaled when asked or, under the default rule `units`, by σ; method
        'newton': with its hierarchy, `asked` as _newton.levels takes it)."""
        n = self.n
        built = self._hierarchy = None
        if units and self.scale is None:   # the default rule iterates on σA, σq (σ a power of two: exact)
            self.scale = "units"
        if self.method == "newton" and self.scale in (None, "units") and _newton.resolves_to_amg(hierarchy, self.A):
            built = _newton.amg_levels_or_rows(self.A, self._components)
            if built is None:   # rows scaled apart: equilibrated, the amg hierarchy stays (_newton.py)
                self.scale = "rows"
        elif self.method == "newton" and self.scale in (None, "units") and isinstance(hierarchy, Hierarchy):
            built = (list(zip(hierarchy.prolongations, hierarchy.operators[1:])), None)   # formed once, by it
        if built is not None and self.scale == "units":
            built = ([(P, self._units_factor * Ac) for P, Ac in built[0]], built[1])
        if self.scale is None:
            self._dr = self._dc = None
            A_core = self.A
        else:
            self._dr, self._dc = ((np.full(n, self._units_factor), np.ones(n)) if self.scale == "units"
                                  else equilibrate(self.A, self.scale))
            A_core = scale_matrix(self.A, self._dr, self._dc)
            if self.scale == "units":   # parameters in w's units (Ω2, φ, nrmm's α) follow A; nrm's Ω2 = I
                _units_parameters(opts, self.method, self._units_factor, n)
        self._index_dtype = A_core.indices.dtype
        self.polish = _newton.check_polish(polish)
        self._polisher = None
        with _user_entries(self.A, A_core):
            if self.method == "newton":
                self._core, self._hierarchy = _newton.make_core(A_core, opts, hierarchy, self.A, self._dc, built,
                                                                asked, self._components)
                _newton.warn_shortened(self._hierarchy, hierarchy)
                return
            _newton.check_no_hierarchy(hierarchy, self.method)
            core_cls = _core.SolverI64 if self._index_dtype == np.int64 else _core.SolverI32
            # A failed factorization raises numpy.linalg.LinAlgError (MemoryError when out of memory),
            # here or in a lazy one during solve().
            self._core = core_cls(A_core.indptr, A_core.indices, A_core.data, n, opts)

    @property
    def setup_timings(self) -> dict[str, float]:
        """Seconds of this Solver's set-up (the constructor): ``setup`` (validation, conversion,
        scaling, the hierarchy, the core's set-up) and ``factorization`` (the part of it spent in
        factorizations). A :meth:`solve`'s ``timings`` count that call only; :func:`nrmicp.solve`'s
        include this set-up (docs/SPEC.md, "Timings")."""
        return dict(self._setup_timings)

    @property
    def parameters(self) -> dict[str, Any]:
        """The method's parameters with defaults resolved: omega1, omega2, phi, gamma, alpha, beta, inner.
        With ``scale``, they are those of the scaled problem; for method 'newton' on an A with
        decoupled rows (a lone diagonal), those of the coupled rows' problem."""
        if self._reduced is not None:
            return self._reduced.inner.parameters
        p = dict(self._core.parameters())
        if self.scale == "units":   # reported in the user's units, as given
            sigma = self._units_factor
            p.update({k: p[k] / sigma for k in ("omega2", "phi") if k in p})
            if self.method == "nrmm":
                p["alpha"] = p["alpha"] / sigma
        return p

    @property
    def levels(self) -> int:
        """Levels of nested iteration (method 'newton': 1 + the number of prolongations used, fewer
        than requested when the set-up gave some up (a HierarchyWarning said why); else 1). A count: the
        levels themselves are the :class:`nrmicp.Hierarchy` a caller builds once and passes as ``hierarchy=``
        (``Hierarchy.amg(A)`` is the 'amg' set-up): one set-up for every Solver of that A."""
        if self._reduced is not None:
            return self._reduced.inner.levels
        return self._core.levels if self.method == "newton" else 1

    @property
    def scaling(self) -> Optional[tuple[np.ndarray, np.ndarray]]:
        """(d_r, d_c), the row and column factors of the scaled matrix D_r A D_c, or None (method
        'newton' on an A with decoupled rows: those of the coupled rows' matrix A_FF)."""
        if self._reduced is not None:
            return self._reduced.inner.scaling
        if self._dr is None or self.scale == "units":   # the default rule's σ is not the user's scaling
            return None
        return self._dr.copy(), self._dc.copy()

    def solve(self, q: ArrayLike, zeta: ZetaLike = None, *, upper: Any = None, x0: Optional[ArrayLike] = None,
              callback: Optional[Callable[..., Any]] = None, zeta_jacobian: Optional[Callable[..., Any]] = None,
              **iteration_options: Any) -> Result:
        """Solve ICP(q, A, ζ), or with ``upper`` the mixed problem ζ ≤ z ≤ upper. See
        :func:`nrmicp.solve` for the arguments. ``timings`` count this call (its ``total``: from entry
        to return); the constructor's are :attr:`setup_timings`."""
        t0 = time.perf_counter()
        res = self._solve(q, zeta, upper=upper, x0=x0, callback=callback, zeta_jacobian=zeta_jacobian,
                          **iteration_options)
        res.timings["total"] = time.perf_counter() - t0
        if iteration_options.get("verbose", self._defaults["verbose"]) > 0:   # checked by _solve
            _log_final(self.method, res, res.timings["total"])
        return res

    def _solve(self, q, zeta=None, *, upper=None, x0=None, callback=None, zeta_jacobian=None,
               **iteration_options) -> Result:
        """:meth:`solve` without its final progress line and ``total`` (the inner solves of the
        decoupled rows and of the whole A)."""
        n = self.n
        units = iteration_options.pop("_units", None)   # a Reduced's inner solve: the whole problem's rule
        it, checked_opts, units = self._solve_options(iteration_options, units)
        qv = as_vector(q, n, "q")
        z0 = None if x0 is None else as_vector(x0, n, "x0")
        kind, c, B, fn = _make_zeta(zeta, n)
        us = _make_upper(upper, n)
        bounded = _bounds.is_bounded(c if kind == ZetaKind.constant else None, us)
        if bounded:
            _bounds.check(kind, c, us, self.method, zeta_jacobian)
        check_callback(callback)
        if self._reduced is not None:
            zD = None
            if kind in (ZetaKind.none, ZetaKind.constant) and not bounded:   # (the closed form is the LCP's)
                _newton.check_jacobian(zeta_jacobian, self.method, kind)
                zD = self._reduced.z_decoupled(qv, c)
            if zD is not None:
                return self._solve_reduced(qv, c, zD, z0, callback, it, checked_opts, units)
            # bounds, a coupling ζ (or a z_D that overflows): the whole A; ζ as checked here (B converted once)
            whole_zeta = Affine(B, c) if kind == ZetaKind.affine else zeta
            built = self._whole_solver is None
            res = self._whole()._solve(qv, whole_zeta, upper=us, x0=z0, callback=callback, zeta_jacobian=zeta_jacobian,
                                       **iteration_options)
            if built:   # its set-up happened in this call
                _charge_setup(res.timings, self._whole_solver._setup_timings)
            return res
        core_kw = _newton.jacobian_argument(zeta_jacobian, self, kind, self._dc)
        if us is not None:
            core_kw["upper"] = _bounds.core_upper(us, self._index_dtype, None if self._dr is None else self._dc)
        checked = None if fn is None else CheckedZeta(fn, n)  # read-only input, checked output: one per solve
        problem, z0s = self._core_problem(qv, z0, kind, c, B, checked)
        measure = _OriginalResidual(self.A, qv, kind, c, B, checked, self._units_weights() if units else None, us)
        # Res is re-measured in the original variables whenever that costs no call of a user ζ
        # (constant: the core iterated the shifted LCP; Affine), and always with scaling (then a
        # callable ζ is called once more per round): success is never declared on the strength of
        # a different residual. An unscaled LCP needs no re-check: the core's Res is already
        # min(Az + q, z) of the returned z in the original variables.
        verify = kind in (ZetaKind.constant, ZetaKind.affine) or self._dr is not None or units
        it = _absolute_target(it, checked_opts, measure, n)
        tol = it["tol"]
        rounds = _Rounds(self, problem, it, callback, core_kw, measure if verify else None, z0)
        rounds.run(z0s, tol)
        return self._assemble(rounds, problem, tol, measure, bounded)

    def _units_weights(self):
        """(d_r, d_c) of the default rule's measure: the user's equilibration ('rows'/'both') the core iterates
        on, else each row's weight (_scaling.units_weights; the core iterates on σA: one number, A symmetric)."""
        if self._dr is not None and self.scale != "units":
            return self._dr, self._dc
        if self._row_weights is None:
            self._row_weights = units_weights(self.A, self._units_factor)
        return self._row_weights, np.ones(self.n)

    def _solve_reduced(self, qv, c, zD, z0, callback, it, checked_opts, units) -> Result:
        """Solve on the coupled rows (self._reduced); z, w, Res and the status of the whole problem,
        the status re-decided on that Res as rule 1 of docs/SPEC.md does."""
        kind = ZetaKind.none if c is None else ZetaKind.constant
        measure = _OriginalResidual(self.A, qv, kind, c, None, None, self._units_weights() if units else None)
        it = _absolute_target(it, checked_opts, measure, self.n)
        tol = it["tol"]
        r = self._reduced.solve(qv, c, zD, z0, callback, dict(it, _units=units), measure)
        if r.residual < tol:
            r.status, r.message = Status.CONVERGED, _core.status_message(int(Status.CONVERGED))
        elif r.status == Status.CONVERGED:
            r.status, r.message = Status.STAGNATED, (
                f"stagnated: the coupled rows met tol but Res(z) = {r.residual:.3g} >= tol = {tol:.3g} with the "
                "decoupled rows; returning the best iterate")
        else:
            r.message = f"{r.message}; Res(z) = {r.residual:.3g} with the decoupled rows"
        r.active_mask = measure.active_mask(r.z)
        r.status, r.message, r.residual, r.criterion = _criterion_outcome(measure, r.z, r.residual, tol, r.status,
                                                                          r.message)
        if r.status != Status.CONVERGED:
            r.message = _newton.with_shortening(r.status, r.message + measure.infeasibility(), self._hierarchy)
        r.success = r.status == Status.CONVERGED
        return r

    def _whole(self) -> "Solver":
        """The Newton member on the whole A (an affine or callable ζ couples the decoupled rows)."""
        if self._whole_solver is None:
            self._whole_solver = Solver(self.A, _decouple=False, **self._settings)
        return self._whole_solver

    def _solve_options(self, iteration_options: dict, units=None) -> tuple:
        """(options, checked core options, units): the set-up's per-solve options overridden by the
        solve's, tol/rtol resolved by _criterion (`units` given: kept as they are, under that rule),
        checked against the method."""
        unknown = set(iteration_options) - set(self._defaults)
        if unknown:
            raise TypeError(f"Solver.solve() got unexpected keyword argument(s) {sorted(unknown)}; the set-up "
                            f"options ({', '.join(_options.names('setup'))}) are fixed by Solver(...)")
        it = dict(self._defaults, **iteration_options)
        if units is None:
            it, units = _criterion(it)
        checked = _iteration_options(_core.Options(), **it)
        checked.method = getattr(_core.Method, self.method)
        _checked(checked, self.n)  # validates every iteration option once, against this method
        return it, checked, units

    def _core_problem(self, qv, z0, kind, c, B, checked):
        """The problem handed to the core, (q, kind, c, B-indptr, B-indices, B-data, fn), and its
        start: in the scaled variables y = D_c⁻¹ z when scaled."""
        dr, dc = self._dr, self._dc
        if dr is not None:
            qs = dr * qv
            with np.errstate(over="ignore"):  # x0 / dc beyond float's range: _Rounds returns x0 instead
                z0s = None if z0 is None else z0 / dc
            cs = None if c is None else c / dc
            Bs = None if B is None else scale_matrix(B, 1.0 / dc, dc)
            fns = None if checked is None else (checked if np.all(dc == 1.0) else
                                                CheckedZeta(ScaledCallable(checked, dc), self.n))
        else:
            qs, z0s, cs, Bs, fns = qv, z0, c, B, checked
        if Bs is not None:
            bp = Bs.indptr.astype(self._index_dtype, copy=False)
            bi = Bs.indices.astype(self._index_dtype, copy=False)
            bd = Bs.data
        else:
            bp = bi = bd = None
        return (qs, kind, cs, bp, bi, bd, fns), z0s

    def _assemble(self, rounds: "_Rounds", problem, tol: float, measure, bounded) -> Result:
        """The result of the rounds (_settle), with what the serial layer adds: hints where it did not
        converge, the scaling's rounds, the active mask."""
        hint = failure_hint(self.method, self._omega2_hint, lambda: dominance_margin(self.A),
                            self.scale == "units" and measure.weights is not None, measure.kind, measure.infeasibility,
                            lambda: row_spread(self.A) if self.scale in (None, "units") else 1.0)
        fields = _settle(self, rounds, problem, measure, tol, polish=self.polish, bounded=bounded,
                         report=self._hierarchy, hint=hint)
        if self._dr is not None and self.scale != "units":
            fields["scaling"] = {"kind": self.scale, "refinements": rounds.refined,
                                 "rounds": [(float(tk), Status(s).name, float(r)) for tk, s, r in rounds.rounds]}
        return Result(active_mask=measure.active_mask(fields["z"]), **fields)


def _settle(solver, rounds: "_Rounds", problem, measure, tol: float, *, polish: bool, bounded: bool, report,
            hint=None) -> dict:
    """The fields of a Result from the core's rounds, both engines: the best round's z or its polish
    (_newton.polish, within the bounds the core was given), the status re-decided as docs/SPEC.md says ("When the
    Python layer changes the core's status"), then by the polish and the default rule's criterion;
    the Newton member's fields and notes (`report`: its hierarchy_report); the rounds' history,
    timings and counters. `hint(status)`: a sentence for a solve that did not converge."""
    polished = polish_core = None
    if polish:
        polished, polish_core = _newton.polish(solver, problem, rounds.z, rounds.res, measure, solver._dc,
                                               rounds.core_kw.get("upper"))
        if polish_core is not None:
            rounds.add_timings(polish_core["timings"])
    z, w, res = polished or (rounds.z, rounds.w, rounds.res)
    status, message = rounds.status(res, tol)
    if status != Status.CONVERGED and hint is not None:
        message += hint(status)
    extra = {}
    if polish:
        extra["polished"] = polished is not None
        status, message = _newton.polish_outcome(status, message, res, tol, polished is not None, polish_core)
    if solver.method == "newton":
        extra.update(_newton.result_fields(rounds.best_d, report))
        message = _newton.with_jacobian_note(message, extra["path"], rounds.best_d["message"])
    status, message, res, extra["criterion"] = _criterion_outcome(measure, z, res, tol, Status(status), message)
    message = _newton.with_shortening(status, message, report)
    return dict(z=z, w=w, success=status == Status.CONVERGED, status=Status(status), message=message,
                nit=int(rounds.nit), iterations=int(rounds.done_iters), residual=res, history=rounds.history(),
                timings=rounds.timings, method=solver.method, inner=rounds.best_d["inner"], counters=rounds.counters,
                **extra)


class _OriginalResidual:
    """(w, Res(z)) in the original variables, in numpy: w = Az + q, g = z − ζ(z). With `weights`
    (d_r, d_c), the default rule's units-free Res_E = ‖min(d_r w, g / d_c)‖₂ (w itself unweighted)."""

    def __init__(self, A, qv, kind, c, B, checked, weights=None, upper=None):
        self.A, self.qv, self.kind, self.c, self.B, self.checked = A, qv, kind, c, B, checked
        self.weights, self.upper = weights, upper
        self.bounded = _bounds.is_bounded(c if kind == ZetaKind.constant else None, upper)
        self._last = None   # (z, w, g, u) of the last call: the paper's Res of the returned z calls no ζ, u again

    def infeasibility(self) -> str:
        """The message part naming a row that makes the problem evidently infeasible, or "" (bounds: constant
        ones only)."""
        if self.bounded:
            if self.kind not in (ZetaKind.none, ZetaKind.constant) or isinstance(self.upper, _bounds.ImplicitUpper):
                return ""
            n = len(self.qv)
            lower = np.zeros(n) if self.kind == ZetaKind.none else self.c
            return box_infeasibility(self.A, self.qv, lower, np.full(n, np.inf) if self.upper is None else self.upper)
        lcp = self.kind in (ZetaKind.none, ZetaKind.constant)
        return evident_infeasibility(self.A, self.qv, lcp, self.c if self.kind == ZetaKind.constant else None)

    def _g(self, z):
        if self.kind == ZetaKind.none:
            return z
        if self.kind == ZetaKind.constant:
            return z - self.c
        if self.kind == ZetaKind.affine:
            return z - (self.B @ z + self.c)
        return z - self.checked(z)  # on a read-only copy: ζ never sees (or writes into) the result

    def _wg(self, z):
        """(w, g, u) at z (u: the upper bound's vector there, or None), from the last call's when z is
        the same array (a user ζ or upper is called once)."""
        if self._last is None or self._last[0] is not z:
            self._last = (z, self.A @ z + self.qv, self._g(z), _bounds.upper_at(self.upper, z))
        return self._last[1:]

    def __call__(self, z, weighted=True):
        w, g, u = self._wg(z)
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(z))):
            return w, math.inf   # an overflowing Az + q is no certificate: min(w, g) is blind to w = +inf
        if self.weights is None or not weighted:
            return w, _norm(_bounds.residual_terms(z, w, g, u))
        dr, dc = self.weights
        with np.errstate(over="ignore", invalid="ignore"):
            r = _norm(_bounds.residual_terms(z / dc, dr * w, g / dc, None if u is None else u / dc))
        return w, r if r == r else math.inf   # a factor beyond float range (inf · 0): no certificate

    def active_mask(self, z):
        """scipy's active_mask of z (_bounds.active_mask)."""
        return _bounds.active_mask(z, *self._wg(z))

    def rounding_level(self, z) -> float:
        """ε ‖t‖₂, t the rounding of each row's term of Res_E at z: d_r(|A||z| + |q|) where it is d_r w,
        (|z| + |ζ(z)|)/d_c where it is g/d_c: what double precision can resolve of Res_E (the core's own
        rule, detail::rounding_level: the Newton member's floor, in the default rule's measure)."""
        dr, dc = self.weights
        w, g, u = self._wg(z)
        vectors = (None if v is None else np.ascontiguousarray(v, dtype=float) for v in (z, self.qv, g, w, u, dr, dc))
        return _core.rounding_level(self.A.indptr, self.A.indices, self.A.data, *vectors)   # (A: as_csr's, canonical)


#: The default rule accepts a Res_E within this factor of its rounding level: the Newton member's
#: floor rule (kFloorFactor, globalization.hpp), asked of the core.
FLOOR_FACTOR = float(_core.newton_tuning["floor_factor"])


def _criterion_outcome(measure, z, res, tol, status, message):
    """(status, message, the paper's Res of z, the criterion field) of a solve whose stopping measure
    gave `res` against the absolute target `tol`. Under the default rule a Newton solve (or polish)
    that settled at its rounding floor is success when Res_E is within FLOOR_FACTOR of its rounding
    level (a target below it is the rule's, not the user's), and Res is re-measured as the paper's
    for ``residual``."""
    if measure.weights is None:
        return status, message, res, {"measure": "paper", "target": float(tol), "value": float(res)}
    crit = {"measure": "units", "target": float(tol), "value": float(res)}
    status, message = at_rounding_floor(status, message, res, tol, lambda: measure.rounding_level(z))
    paper = measure(z, weighted=False)[1] if math.isfinite(res) else res
    return status, message, paper, crit


def at_rounding_floor(status, message, res, tol, level):
    """(status, message) under the default rule: a Newton solve (or polish) that stopped STAGNATED at
    its rounding floor (the core's evidence: "rounding floor" in its message) with Res_E within
    FLOOR_FACTOR of `level()`, the rounding level of Res_E at z, is CONVERGED; else unchanged. Both
    engines ask this rule."""
    if not (status == Status.STAGNATED and "rounding floor" in message and math.isfinite(res)):
        return status, message
    lv = level()
    if not (math.isfinite(lv) and res <= FLOOR_FACTOR * lv):   # (an overflowing level certifies nothing)
        return status, message
    return Status.CONVERGED, (f"converged to the rounding level: Res_E(z) = {res:.3g} is within {FLOOR_FACTOR:g}x "
                              f"of what double precision resolves ({lv:.3g}), above the default target {tol:.3g}")


class _Rounds:
    """The core's solves of one Solver.solve: the first, then (when `measure` re-measures Res in
    the original variables and the core met its tol but Res(z) >= tol) at most MAX_REFINEMENTS
    re-solves with a tighter tolerance. Keeps the best iterate and sums what the rounds report."""

    def __init__(self, solver, problem, it, callback, core_kw, measure, z0):
        self.solver, self.problem, self.it, self.core_kw, self.measure = solver, problem, it, core_kw, measure
        self.z0 = np.zeros(solver.n) if z0 is None else z0  # the start in the original variables
        self.scaled = solver._dr is not None
        self.cb_offset = [0]  # the callback's nit counts on over re-solves, as the history's
        self.cb = None if callback is None else _core_callback(callback, solver._dc if self.scaled else None,
                                                               self.cb_offset)
        self.best = None
        self.done_iters = 0
        self.rounds, self.histories = [], []
        self.timings = None
        self.counters: dict[str, int] = {}
        self.refined = 0
        self.last = None
        self.progress = _progress_hook   # (method, n) -> the core's progress hook

    def run(self, z0s, tol):
        tol_k, x0k = tol, z0s
        while True:
            d, status = self.round(tol_k, x0k)
            if status != Status.CONVERGED or self.rounds[-1][2] < tol or self.measure is None:
                return
            # The core met tol_k on its own residual, but Res(z) >= tol: tighten and re-solve
            # from where it stopped, at most MAX_REFINEMENTS times.
            if self.refined >= MAX_REFINEMENTS:
                return
            res = self.rounds[-1][2]
            ratio = res / d["residual"] if d["residual"] > 0 else math.inf
            new_tol = min(0.5 * tol_k, 0.5 * tol / ratio) if math.isfinite(ratio) else 0.0
            if not (new_tol >= 1e-300):
                return
            tol_k, x0k = new_tol, d["z"]
            self.refined += 1

    def ran_away(self) -> bool:
        """The scaled ζ was handed a z that overflowed in the user's variables (docs/SPEC.md)."""
        fn = self.problem[-1]
        return isinstance(getattr(fn, "fn", None), ScaledCallable) and fn.fn.overflowed

    def round(self, tol_k, x0k):
        """One solve by the core at tolerance tol_k from x0k; its outcome folded in."""
        solver = self.solver
        self.cb_offset[0] = self.done_iters
        opts = _iteration_options(_core.SolveOptions(), **dict(self.it, tol=tol_k))
        self.core_kw["progress"] = self.progress(solver.method, solver.n) if opts.verbose > 0 else None
        d = solver._core.solve(*self.problem, x0k, self.cb, opts, **self.core_kw)
        status = Status(d["status"])
        if status == Status.ZETA_FAILED and self.ran_away():
            d["status"], d["message"] = int(Status.DIVERGED), (
                "diverged: the iterate overflowed in the original (unscaled) variables before zeta "
                f"could be evaluated; {d['message'].split('; ', 1)[-1]}")
            status = Status.DIVERGED
        if status == Status.ZETA_FAILED:
            raise ValueError(f"{d['message']} (NaN or Inf)")
        z = d["z"] * solver._dc if self.scaled else d["z"]
        if not np.all(np.isfinite(z)):
            # z_s · dc overflowed in the user's variables, or the scaled start x0 / dc did (then the
            # core had no finite iterate): the user's start stands in, finite whenever x0 was
            z = self.z0
            d["message"] += "; the iterate overflowed in the original variables: returning the initial guess"
        w, res = self.measure(z) if self.measure is not None else (d["w"], d["residual"])
        key = res if res == res else math.inf
        if self.best is None or key < self.best[0]:
            self.best = (key, z, w, res, self.done_iters + d["nit"], d)
        if d["history"] is not None:
            h = d["history"]
            self.histories.append((h["iteration"] + self.done_iters, h["seconds"], h["residual"]))
        self.add_timings(d["timings"])
        for name, count in d["counters"].items():
            self.counters[name] = self.counters.get(name, 0) + int(count)
        self.done_iters += d["iterations"]
        self.rounds.append((tol_k, status, res))
        self.last = d
        return d, status

    def add_timings(self, t):
        """A core call's timings summed in (each counts its own call only; the caller sets total)."""
        if self.timings is None:
            self.timings = dict(t)
            return
        for name in t:
            self.timings[name] += t[name]

    z = property(lambda self: self.best[1])
    w = property(lambda self: self.best[2])
    res = property(lambda self: self.best[3])
    nit = property(lambda self: self.best[4])
    best_d = property(lambda self: self.best[5])

    def status(self, res, tol):
        """Status and message of the returned z with Res `res` (rule 1 of docs/SPEC.md, "When the
        Python layer changes the core's status")."""
        last_status, last_message = self.rounds[-1][1], self.last["message"]
        if self.measure is None:
            return last_status, last_message
        if not math.isfinite(res):
            return Status.DIVERGED, ("diverged: Res of the returned iterate is not finite in the original variables "
                                     "(A z + q or z overflowed); scale the data")
        if res < tol:
            message = _core.status_message(int(Status.CONVERGED))
            if self.refined:
                message += f" (after {self.refined} re-solve(s) with a tighter tolerance on the scaled problem)"
            return Status.CONVERGED, message
        if last_status == Status.CONVERGED:
            tol_k = self.rounds[-1][0]
            return Status.STAGNATED, (
                f"stagnated: the {'scaled' if self.scaled else 'shifted'} problem met its tolerance {tol_k:.3g} "
                f"but {self.label}(z) = {res:.3g} >= tol = {tol:.3g} in the original variables"
                f"{' after %d re-solve(s)' % self.refined if self.refined else ''}; returning the best iterate")
        return last_status, f"{last_message}; {self.label}(z) = {res:.3g} in the original variables"

    @property
    def label(self) -> str:
        """The stopping measure's name in messages: the paper's Res, or the default rule's Res_E."""
        return "Res" if self.measure is None or self.measure.weights is None else "Res_E"

    def history(self):
        if not self.histories:
            return None
        return {"iteration": np.concatenate([h[0] for h in self.histories]),
                "seconds": np.concatenate([h[1] for h in self.histories]),
                "residual": np.concatenate([h[2] for h in self.histories])}


def solve(A: MatrixLike, q: ArrayLike, zeta: ZetaLike = None, *, upper: Any = None, method: str = "auto",
          tol: Optional[float] = None,
          rtol: Optional[float] = None, maxiter: int = 10000, omega1: DiagonalLike = None, omega2: DiagonalLike = None, gamma: float = 1.0,
          phi: DiagonalLike = None, alpha: Optional[float] = None, beta: Optional[float] = None,
          theta: float = 1.0, z_update: str = "auto", inner: str = "auto", accelerate: Optional[str] = "none",
          anderson_m: int = 5, x0: Optional[ArrayLike] = None, callback: Optional[Callable[..., Any]] = None,
          record_history: bool = False, stall_iterations: int = 100, scale: Union[bool, str] = False,
          verbose: int = 0, hierarchy: Any = "auto", components: Any = None, polish: bool = False,
          zeta_jacobian: Optional[Callable[..., Any]] = None) -> Result:
    r"""Solve the implicit complementarity problem ICP(q, A, ζ):

    find z with  w = Az + q ≥ 0,  g = z − ζ(z) ≥ 0,  gᵀw = 0   (ζ ≡ 0: the LCP),

    by Method 3.1 of Kumar, Deepmala & Das (the NRM family) or a baseline.

    Parameters
    ----------
    A : scipy.sparse matrix (CSR, CSC or COO; int32 or int64 indices) or dense ndarray, (n, n)
        Canonical float64 CSR is used without a copy; anything else is converted with a
        :class:`nrmicp.ConversionWarning`.
    q : array_like, (n,)
    zeta : None, array_like, :class:`Affine` or callable
        ``None``: the LCP (ζ is never evaluated). An array ``c``: a constant obstacle, solved as
        the shifted LCP in ``z − c``; it may hold ``-inf`` where z has no lower bound (free rows). ``Affine(B, c)``: ζ(z) = Bz + c, evaluated in C++. A
        callable ``zeta(z) -> ndarray``: called once per iteration with a read-only float64
        array (valid only during the call); exceptions it raises reach the caller unchanged.
        ζ returning an array of the wrong shape or dtype raises TypeError/ValueError; ζ
        returning NaN or Inf raises ValueError (the core's status ZETA_FAILED).
    upper : None, float, array_like (n,), Affine or callable, optional
        An upper bound: solve the mixed complementarity problem ζ ≤ z ≤ upper (PATH's and PETSc's
        convention): w = Az + q ≥ 0 where z = ζ, w ≤ 0 where z = upper, w = 0 strictly between.
        ``+inf`` entries: no upper bound there; with ``zeta`` ``-inf`` too, the row is free (w = 0).
        Res becomes ‖mid(z − ζ, z − upper, w)‖₂ (the paper's Res without ``upper``). Bounds need
        ``zeta`` None or constant for every method (the stationary members iterate their box form,
        which converges where the LCP form does; 'auto' chooses as without bounds); an Affine or
        callable ζ with ``upper``: method 'newton' (the outer fixed point, no ``zeta_jacobian``;
        'auto' picks it); lower > upper anywhere is a ValueError naming both.
        An implicit upper bound u(z) — ``Affine(B, c)`` (u = Bz + c, evaluated in C++) or a callable
        returning a length-n float vector (numbers or +inf, never NaN or -inf: a ValueError naming
        ``upper``) — is method 'newton''s ('auto' picks it): its outer fixed point solves the box
        ζ(z_k) ≤ z ≤ u(z_k) frozen at each outer step's z_k; where the frozen bounds cross the upper
        one wins, and a returned z at which ζ(z) > u(z) is not a success (the message says so).
        Res and ``active_mask`` take u at the returned z.
        ``result.active_mask`` says where z is at a bound.
    method : {'auto', 'nrm', 'nrmm', 'nrmaor', 'nrmsor', 'nrmgs', 'nrmj', 'mms', 'two_sweep', 'newton'}, default 'auto'
        ``'auto'`` (default): ``'nrmgs'`` when every row of A is diagonally dominant by at least
        a quarter of its diagonal (Bai's shifted matrices, implicit time steps with a large mass
        term: tens of sweeps), else ``'newton'`` (unshifted elliptic A, zero diagonals); an option
        only the stationary members read (accelerate, z_update, theta, alpha, beta) picks
        ``'nrmgs'``, a hierarchy list ``'newton'``; ``result.method`` says which ran. Or one member: ``'nrmgs'``, ``'nrm'``, ``'nrmm'``,
        ``'nrmaor'``, ``'nrmsor'``, ``'nrmj'``, ``'mms'`` (Zheng–Vong baseline), ``'two_sweep'`` (two-sweep baseline). The AOR-type
        methods need no factorization (forward substitution, O(nnz) per iteration); NRM and
        NRMM factorize Ω2 + (A + φ)Ω1 once. ``'newton'``: the semismooth Newton member on the same
        modulus equation (one sparse factorization of A restricted to the inactive set per step,
        symbolic analysis once; nested iteration over ``hierarchy``; falls back to sweeps of 'nrm'
        when a step does not reduce Res or the active set cycles). Its ``maxiter`` counts Newton
        steps (and bounds the fallback sweeps). The rule of 'auto': README "Which method for which problem".
    tol : float > 0, default None
        Stop when Res(z) = ‖min(Az + q, z − ζ(z))‖₂ < tol (absolute, the paper's criterion;
        scipy.sparse.linalg's ``atol``). With ``rtol``, the target is max(tol, rtol · Res(0)).
        Giving ``tol`` or ``rtol`` selects the paper's Res (the other one defaults to 0).
    rtol : float in [0, 1), default None
        Relative tolerance, as scipy.sparse.linalg's: stop when Res(z) < max(tol, rtol · Res(0)),
        Res(0) = ‖min(q, −ζ(0))‖₂ the residual at z = 0 (scipy's ‖b‖; it does not depend on
        ``x0``). ``tol=0`` with ``rtol > 0`` is a purely relative target.

        **Default (both None): a rule that does not depend on units.** Res is measured in the
        units of z, Res_E(z) = ‖min(D(Az + q), z − ζ(z))‖₂ with D_ii = 1/max_j |a_ij|, a power of
        two, and the solve stops when Res_E(z) < 1e-10 · Res_E(0) (``DEFAULT_RTOL``), or when Res_E is
        within 100x of the rounding level of double precision at z. Scaling A and q together, or z,
        changes neither the iterates nor the decision; scaling a row (its equation's units) not the decision. ``result.criterion`` says
        which rule decided, its target and value; ``residual`` is always the paper's Res of ``z``.
    maxiter : int >= 0, default 10000
        At most this many x-updates (method 'newton': Newton steps on the finest level, which also
        bound its fallback sweeps).
    omega1, omega2 : float or array_like (n,) > 0, default None
        Ω1, Ω2. Defaults: Ω1 = I; Ω2 = I (nrm, the paper's definition), αI (nrmm),
        diag(A) (AOR types, mms, two_sweep; Theorem 4.2's Ω2 ≥ DΩ1).
    gamma : float > 0, default 1.0
        γ; only rescales the modulus variable.
    phi : float or array_like (n,) >= 0, default None
        The relaxation diagonal φ (default 0).
    alpha : float > 0, default None
        AOR α (nrmaor, nrmsor: default 1); for nrmm α sets Ω2 = αI (default: the mean of diag(A)).
        nrmgs and nrmj fix α and β.
    beta : float >= 0, default None
        AOR β (nrmaor: default β = α; nrmsor has β = α).
    theta : float in (0, 2], default 1.0
        Relaxation of the two-sweep method only.
    z_update : {'auto', 'explicit', 'solve'}, default 'auto'
        How z is recovered from the modulus vector: 'solve' is the paper's Step 1 (a solve with A,
        factorized once); 'explicit' needs no solve with A. 'auto' = 'explicit' (measured 4-10x
        faster on ICPs at equal iteration counts, and convergent on unshifted-Laplacian and
        thermoforming ICPs where 'solve' stagnates), except 'solve' on an ICP for method 'nrm' with
        the paper's Ω2 = I (there only 'solve' converged) and for the baseline 'mms' (whose
        definition, Zheng–Vong, includes it). Use 'solve' when ζ has Lipschitz
        constant about 1 (impulse control). An LCP never factorizes A unless 'solve' is asked for.
    inner : {'auto', 'cholmod', 'umfpack', 'eigen_llt', 'eigen_lu', 'cg'}, default 'auto'
        Factorization for Ω2 + (A + φ)Ω1 (nrm, nrmm) and for A ('solve' z-update). 'auto':
        CHOLMOD when symmetric positive definite, else UMFPACK (Eigen's solvers without SuiteSparse).
        'cg' (method 'newton' only): the reduced systems by a Krylov method preconditioned with a
        multigrid V-cycle on the hierarchy's prolongations (needs a hierarchy; else the direct
        solve): CG when the reduced system is symmetric positive definite (an LCP or obstacle
        problem with symmetric A), else BiCGSTAB (nonsymmetric A, affine ζ); ``Result.inner`` says
        which ('cg' or 'bicgstab'). A Krylov solve that does not converge is redone by the direct
        solve. 'auto' picks it with a hierarchy from n = 1,000 on (measured 2-8x faster than the
        direct solve up to n = 10,000, 2.4-10x above with CG, 2.6-3.7x with BiCGSTAB on 2D
        convection-diffusion; README, "Newton's inner solve").
    accelerate : {'none', 'anderson'}, default 'none'
        Safeguarded Anderson acceleration of the fixed-point map (memory ``anderson_m``).
    anderson_m : int in [1, 100], default 5
        Anderson memory: the number of past differences kept.
    x0 : array_like (n,), default None
        Initial guess for z (warm start); default zeros.
    callback : callable, default None
        Called once for every iterate k = 0 (the start), 1, 2, ..., the last one too whatever ended
        the solve (the iterates of ``result.history``; method 'newton': the finest-level ones, numbered
        as ``nit`` counts them: an Affine or callable ζ's Newton steps from the last step of their start's
        obstacle solve on, with the outer steps' steps between them), by
        scipy's rule: ``callback(intermediate_result)`` (the only parameter named exactly so)
        receives a :class:`Result` with ``z`` (alias ``x``), ``nit`` (= k) and ``residual``; any
        other callable is called as ``callback(zk)`` with the iterate. For a converged solve the
        last call has ``result.z`` (before ``polish``). Raise StopIteration (or return True) to
        stop: status CALLBACK_STOP (unless that iterate converged).
    record_history : bool, default False
        Keep (iteration, seconds, Res) of every iterate in ``result.history``.
    stall_iterations : int >= 1, default 100
        The window of the no-progress rules: STAGNATED when Res stops improving at rounding level
        for this many iterations, when 3 consecutive windows of this many iterations bring no lower
        Res, or when the best Res has not improved for 10 windows and, at the rate Res falls, would
        not be reached again within maxiter (README "What you get back").
    verbose : int >= 0, default 0
        0 or False (default): silent; True means 1. k > 0: a progress line (iteration, Res, best Res, elapsed seconds) at
        the first iterate, then about every k seconds, and a final line with the result's message,
        ``nit`` (and ``iterations`` when they differ) and the call's seconds. Lines go
        to the ``logging`` logger ``"nrmicp"`` at level INFO, and to stderr when logging is not
        configured. The C++ loop decides when to report: there is no per-iteration Python call.
    scale : False, True, 'rows' or 'both', default False
        Diagonal equilibration for badly scaled problems (default off). 'rows': D_r = 1/max|row|;
        'both' (= True): Ruiz equilibration of rows and columns. The solver then iterates on
        ICP(D_r q, D_r A D_c, ζ') in y = D_c⁻¹ z with ζ'(y) = D_c⁻¹ ζ(D_c y) (None stays None, a
        constant c becomes D_c⁻¹ c, Affine(B, c) becomes Affine(D_c⁻¹ B D_c, D_c⁻¹ c), a callable is
        wrapped); the factors are powers of two, so scaling is exact. omega1/omega2/phi and the
        callback's ``residual`` refer to the scaled problem; the callback's ``z`` and the result
        are in the original variables. Success is decided on Res(z) re-measured in the ORIGINAL
        variables (a callable ζ is called once more for that): when the scaled solve meets tol but
        Res(z) >= tol, it is re-solved from there with a tighter tolerance, at most 3 times, and
        otherwise ends with status STAGNATED (success False) and the best iterate.
        ``result.scaling`` records the kind, the number of re-solves and each round's
        (tolerance, status, Res).
    hierarchy : 'auto', 'amg', list of sparse matrices, or None, default 'auto'
        Nested iteration of method 'newton' (other methods: 'auto' or None only). A list
        [P_0, P_1, ...] of prolongations (P_l of shape (n_l, n_{l+1}), n_0 = n) defines coarse
        problems P_lᵀ A_l P_l, P_lᵀ q_l, solved coarse to fine, each solution prolongated,
        projected onto z ≥ ζ and used as the next start; 'amg' builds classical Ruge–Stüben
        prolongations with pyamg; None starts cold (from x0 or zeros). 'auto': 'amg' for
        n >= 1000 when A stores at most 10% of its n² entries and pyamg is installed, else None
        (measured: README "Mesh-independent solves"; docs/MEASUREMENTS.md, AUTO_AMG_MIN_N).
        With a hierarchy the start is the nested solution, unless ζ is None or constant and ``x0``
        is nonzero and closer than a cold start (its Res below half the Res at the obstacle: a time
        step's previous solution): ``x0`` is then tried for up to 6 finest-level steps, the hierarchy
        serving the inner solves, before the nested start takes over (README "Time stepping").
        A coarse operator with a non-positive diagonal ends the hierarchy there; any level given up
        raises a :class:`nrmicp.HierarchyWarning` at set-up and shows in ``result.hierarchy``.
    components : None, int or array_like of int (n,), default None
        The unknowns of a vector problem (elasticity: displacement components), for the 'amg'
        hierarchy ('amg', or 'auto' where it builds amg; not used otherwise): an int k when k
        components are interleaved (unknown i is component i mod k; n a multiple of k), or one
        integer label per unknown (any ordering). 'amg' then coarsens and interpolates each
        component by itself (strength only between unknowns of the same component: the
        unknown-based classical AMG for systems), so each P stays ≥ 0 and block-diagonal by
        component, the coarse operators PᵀAP keep the couplings. None or 1 (default): a scalar
        problem. Elastic contact at n = 262,656: 3-4 finest Newton steps and 2 CG iterations a
        solve against 7-8 and 81-96 without (README "Bounds and free unknowns").
    zeta_jacobian : callable, default None
        Method 'newton' with a callable ζ: ``zeta_jacobian(z)`` returns a generalized Jacobian of ζ
        at z as an (n, n) sparse matrix or 2-D array, or as a linear operator (a
        ``scipy.sparse.linalg.LinearOperator``, or anything with ``shape`` and ``matvec`` that
        ``aslinearoperator`` takes: a dense ζ' known by its products, solved matrix-free by FGMRES);
        then Newton works on the whole ICP (a semismooth Newton method: for a max-type ζ, policy
        iteration), each step's active set placed by an outer step. Without it, a callable ζ is
        handled by an outer fixed point ζ(z_k) -> obstacle problem, each solved by warm-started Newton.
    polish : bool, default False
        After the method stops, take Newton steps from its answer on its active set (at most 3)
        and keep them if they lower Res (``result.polished``); typically the first one drops Res
        to rounding level. When Res stays above ``tol`` at its rounding floor, the status is
        STAGNATED and the message gives the floor.

    Returns
    -------
    Result
        ``z``, ``w``, ``success``, ``status``, ``message``, ``nit``, ``residual``, ``history``,
        ``timings``, ``active_mask`` (scipy's, as ``lsq_linear``'s: -1 where z is at its lower bound
        ζ, i.e. z − ζ <= w; +1 at ``upper``; 0 between). A solve that does not converge says so in
        ``status`` and returns its best iterate.
        Method 'newton' adds ``linear_solves`` (all levels), ``inner_iterations`` (CG or BiCGSTAB
        iterations of ``inner='cg'``, all levels; 0 for direct solves), ``fallback_sweeps``, ``outer_iterations``
        (callable ζ), ``level_steps`` and ``level_seconds`` (per level, finest first), ``path``
        ('newton', 'newton+fallback', 'fallback', or 'newton+outer': a ``zeta_jacobian`` whose Newton
        steps did not deliver was given up for the outer fixed point, and the message says so) and
        ``hierarchy`` (levels requested and used, and why fewer: :class:`Result`); its ``nit`` counts
        finest-level Newton steps.
        Without a callable ζ, Res(z) is re-measured in numpy in the original variables before
        success is declared (this matters for a constant obstacle, which the core solves as the
        shifted LCP), with the same re-solve rule as for ``scale``.
    """
    options = _options.pick(locals())   # the options, as given
    t0 = time.perf_counter()
    options["method"] = implied_method(method, zeta, upper, zeta_jacobian)
    s = Solver(A, **_options.pick(options, "setup", "solve"))
    res = s.solve(q, zeta, upper=upper, **_options.pick(options, "call"))
    _charge_setup(res.timings, s._setup_timings)   # the whole call: the set-up is part of it
    res.timings["total"] = time.perf_counter() - t0
    return res


def check_callback(callback) -> None:
    """TypeError naming ``callback`` unless it is None or callable (both engines' rule)."""
    if callback is not None and not callable(callback):
        raise TypeError(f"callback must be callable, got {type(callback).__name__}")


def implied_method(method, zeta, upper, zeta_jacobian):
    """'newton' for 'auto' given what only newton solves (a ζ Jacobian, an implicit upper bound, an implicit ζ with
    bounds), else `method`. Bounds alone take choose_method's rule: nrmgs's box form contracts as its LCP form does
    (m(x) is 1-Lipschitz as |x| is, detail/modulus.hpp), so a row-dominant A needs as few sweeps."""
    if isinstance(method, str) and method.lower() == "auto" and (
            zeta_jacobian is not None or callable(upper) or isinstance(upper, Affine) or
            (upper is not None and (callable(zeta) or isinstance(zeta, Affine)))):
        return "newton"
    return method


def _charge_setup(timings: dict, setup: dict) -> None:
    """A Solver's set-up (Solver.setup_timings) into the timings of the call that built it."""
    timings["setup"] += setup["setup"]
    timings["factorization"] += setup["factorization"]
