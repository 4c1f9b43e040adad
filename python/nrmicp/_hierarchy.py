"""Prolongations for nested iteration (the ``hierarchy=`` option of ``method="newton"``).

A hierarchy is a list of prolongation matrices [P_0, P_1, …]: P_l maps level l + 1 to level
l, shape (n_l, n_{l+1}), level 0 being the problem itself (n_0 = n). The coarse problems
are the Galerkin ones, A_{l+1} = P_lᵀ A_l P_l and q_{l+1} = P_lᵀ q_l; the C++ solver takes the
list and solves coarse to fine. Building it is this module's job:

- ``"amg"``: classical Ruge–Stüben prolongations (no grid needed), the first level built on an
  auxiliary M-matrix (A's positive off-diagonals lumped into the diagonal) with Jacobi-improved
  interpolation, the coarser ones by Ruge–Stüben on pyamg's compiled kernels. Nonnegative, so a
  prolongated feasible start stays feasible; on finite-element matrices (P2: no M-matrix) the
  coarse problems then predict the fine active set (docs/finite_elements.md has the measurements).
  With ``components`` (a vector problem's unknowns: elasticity's displacement components) every
  level is built by component, P block-diagonal (:func:`same_component`; docs/MEASUREMENTS.md,
  "The amg hierarchy by component").
- a list of matrices: a geometric hierarchy (the grid scenes offer theirs as
  ``Problem.prolongations``), checked here.
- None: no hierarchy (a cold start).

pyamg is imported only when ``"amg"`` is asked for (its import costs about a second).
"""
from __future__ import annotations

import contextlib

import numpy as np
import scipy.sparse as sp

from . import _core
from ._inputs import ConversionWarning, _warn, as_csr
from ._scaling import units_factor

__all__ = ["Hierarchy", "amg_prolongations", "amg_levels", "amg_levels_why", "resolve_hierarchy", "HierarchyWarning"]


class HierarchyWarning(UserWarning):
    """A requested hierarchy (``hierarchy='amg'``, ``'auto'`` where it builds amg, or a list) was
    shortened or given up at set-up: the Newton member nests over fewer levels than requested (a
    cold start with one). The answer meets the same tol; its cost may not. Raised once per Solver
    set-up; ``result.hierarchy`` and :attr:`Solver.levels` say what is used."""

# Classical strength on A's rows (needs no symmetry); each value took the fewest finest steps
# measured (docs/MEASUREMENTS.md, "`_RS_DEFAULTS` of the amg set-up").
_RS_DEFAULTS = {"theta": 0.25, "max_coarse": 10, "max_levels": 30, "sweeps": 3, "truncate": 0.2, "aux_levels": 1}


def _pyamg():
    """pyamg's compiled kernels (pyamg.amg_core), or an ImportError that says what to do."""
    try:
        from pyamg import amg_core
    except ImportError as exc:
        raise ImportError(
            "hierarchy='amg' needs pyamg (pip install pyamg); pass hierarchy=None for a cold "
            "start or a list of prolongation matrices for a geometric hierarchy") from exc
    return amg_core


@contextlib.contextmanager
def _small_pages():
    """numpy's madvise(MADV_HUGEPAGE) on its large arrays switched off for the set-up's
    temporaries (restored after). Each of them is written once and freed: where the kernel
    backs madvised memory by freshly zeroed 2 MB pages, that zeroing is the largest single
    cost of the set-up (docs/MEASUREMENTS.md, "Set-up: fresh pages and copies")."""
    try:
        from numpy._core.multiarray import _set_madvise_hugepage   # numpy >= 2
    except ImportError:   # numpy 1.x
        from numpy.core.multiarray import _set_madvise_hugepage
    previous = _set_madvise_hugepage(False)
    try:
        yield
    finally:
        _set_madvise_hugepage(previous)


# The Ruge–Stüben level of pyamg's ruge_stuben_solver (classical strength, RS splitting, direct
# or classical interpolation) built from its compiled kernels: the same C/F splitting and P,
# without its Python-level copies of values that neither the splitting nor the interpolation
# reads (docs/MEASUREMENTS.md, "The amg set-up on pyamg's kernels").

def _strength(A: sp.csr_matrix, theta: float, norm: str) -> sp.csr_matrix:
    """The classical strength graph of A with its diagonal, holding A's values (pyamg's
    classical_strength_of_connection, unscaled). norm 'abs': |a_ij| ≥ θ max_k≠i |a_ik|;
    'min': −a_ij ≥ θ max_k≠i (−a_ik) (negative couplings only)."""
    core = _pyamg()
    kernel = core.classical_strength_of_connection_min if norm == "min" else core.classical_strength_of_connection_abs
    n = A.shape[0]
    Sp = np.empty(n + 1, dtype=A.indptr.dtype)
    Sj = np.empty(A.nnz, dtype=A.indices.dtype)
    Sx = np.empty(A.nnz, dtype=np.float64)
    kernel(n, theta, A.indptr, A.indices, A.data, Sp, Sj, Sx)
    return sp.csr_matrix((Sx[:Sp[-1]], Sj[:Sp[-1]], Sp), shape=A.shape)


def _rs_split(S: sp.csr_matrix) -> np.ndarray:
    """Ruge–Stüben C/F splitting (pyamg's split.RS) of the strength graph S: True = C point."""
    core = _pyamg()
    n = S.shape[0]
    rows = np.repeat(np.arange(n, dtype=S.indptr.dtype), np.diff(S.indptr))
    off = S.indices != rows
    # the row lengths less each row's diagonal (n counts, not nnz); a pattern (int8 values) to transpose
    indptr = np.zeros(n + 1, dtype=S.indptr.dtype)
    np.cumsum(np.diff(S.indptr) - np.bincount(rows[~off], minlength=n).astype(S.indptr.dtype), out=indptr[1:])
    G = sp.csr_matrix((np.ones(int(indptr[-1]), dtype=np.int8), S.indices[off], indptr), shape=S.shape)
    T = G.T.tocsr()
    splitting = np.empty(n, dtype=S.indptr.dtype)
    core.rs_cf_splitting(n, G.indptr, G.indices, T.indptr, T.indices, np.zeros(n, dtype=S.indptr.dtype), splitting)
    return splitting.astype(bool)


def _rs_interpolation(A: sp.csr_matrix, S: sp.csr_matrix, is_c: np.ndarray, kind: str) -> sp.csr_matrix:
    """pyamg's direct or (modified) classical interpolation from A, its strength graph S (A's
    values on it, :func:`_strength`; its explicit zeros are dropped in place) and the splitting."""
    core = _pyamg()
    n = A.shape[0]
    splitting = is_c.astype(S.indptr.dtype)
    S.eliminate_zeros()
    C = S.copy() if kind == "classical" else S   # classical drops strong F–F connections in C
    if kind == "classical":
        core.remove_strong_FF_connections(n, C.indptr, C.indices, C.data, splitting)
        C.eliminate_zeros()
    first = core.rs_classical_interpolation_pass1 if kind == "classical" else core.rs_direct_interpolation_pass1
    P_indptr = np.empty_like(A.indptr)
    first(n, C.indptr, C.indices, splitting, P_indptr)
    P_indices = np.empty(P_indptr[-1], dtype=P_indptr.dtype)
    P_data = np.empty(P_indptr[-1], dtype=np.float64)
    if kind == "classical":
        core.rs_classical_interpolation_pass2(n, A.indptr, A.indices, A.data, C.indptr, C.indices, C.data,
                                              splitting, P_indptr, P_indices, P_data, True)
    else:
        core.rs_direct_interpolation_pass2(n, A.indptr, A.indices, A.data, C.indptr, C.indices, C.data,
                                           splitting, P_indptr, P_indices, P_data)
    return sp.csr_matrix((P_data, P_indices, P_indptr), shape=(n, int(is_c.sum())))


def auxiliary_m_matrix(A: sp.csr_matrix) -> sp.csr_matrix:
    """A with its positive off-diagonal entries lumped into the diagonal (row sums kept): an
    M-matrix-like stand-in for the coarsening and the interpolation weights. A itself when A
    has no positive off-diagonal (finite differences, P1 on Delaunay meshes)."""
    coo = A.tocoo()
    pos = (coo.row != coo.col) & (coo.data > 0)
    if not pos.any():
        return A
    lump = np.bincount(coo.row[pos], coo.data[pos], minlength=A.shape[0])
    B = sp.csr_matrix((np.where(pos, 0.0, coo.data), (coo.row, coo.col)), shape=A.shape)
    B = sp.csr_matrix(B + sp.diags(lump))
    B.eliminate_zeros()
    return B


def _relax_interpolation(B, P, is_c, sweeps, truncate):
    """Jacobi sweeps on the F rows of P towards B-harmonic (ideal) interpolation,
    P_F ← −D_F⁻¹((B_FF − D_FF) P_F + B_FC), C rows kept as identity (P stays ≥ 0 for an
    M-matrix B), each new row truncated at ``truncate`` × its largest entry, row sums kept (the
    fill of a sweep grows the V-cycle's coarse operators). Compiled (the core's
    relax_interpolation): one pass per sweep instead of scipy's four intermediates
    (docs/MEASUREMENTS.md, "The amg set-up's interpolation sweeps")."""
    index = B.indices.dtype
    ip, ix, data = _core.relax_interpolation(B.indptr, B.indices, B.data, np.ascontiguousarray(is_c, dtype=bool),
                                             P.indptr.astype(index, copy=False), P.indices.astype(index, copy=False),
                                             P.data, P.shape[1], int(sweeps), float(truncate))
    return sp.csr_matrix((data, ix, ip), shape=P.shape)


def _canonical(P) -> sp.csr_matrix:
    P = sp.csr_matrix(P, dtype=np.float64)
    P.eliminate_zeros()
    P.sort_indices()
    return P


def nonpositive_diagonal(M, what: str, unit: float = 1.0):
    """Why `what` (a matrix M, `unit` times the user's) cannot be a level: its first entry a_ii <= 0, or None."""
    d = M.diagonal()
    bad = np.flatnonzero(~(d > 0))
    return None if bad.size == 0 else f"{what} has a_ii = {d[bad[0]] / unit:.3g} <= 0 at row {bad[0]}"


def check_components(components, n: int) -> np.ndarray | None:
    """The ``components=`` option as one label per unknown (an int array of length n), or None
    for a scalar problem (None, 1, or a single label: the amg hierarchy is then exactly the
    scalar one). An int k: k components interleaved (unknown i is component i mod k, n a
    multiple of k). Raises TypeError/ValueError naming ``components``."""
    if components is None:
        return None
    if isinstance(components, (int, np.integer)) and not isinstance(components, (bool, np.bool_)):
        k = int(components)
        if not 1 <= k <= n or n % k:
            raise ValueError(f"components={k}: an int is the number of interleaved components (unknown i is "
                             f"component i mod k), which must be >= 1 and divide n = {n}")
        return None if k == 1 else np.arange(n) % k
    labels = np.asarray(components)
    if labels.dtype.kind not in "iu":
        raise TypeError(f"components must be None, an int (the number of interleaved components) or an "
                        f"integer array of n = {n} labels, got {type(components).__name__} of dtype {labels.dtype}")
    if labels.shape != (n,):
        raise ValueError(f"components must hold one label per unknown, shape ({n},), got shape {labels.shape}")
    return None if n == 0 or (labels == labels[0]).all() else labels.astype(np.int64)


def same_component(A: sp.csr_matrix, components) -> sp.csr_matrix:
    """A without its couplings between unknowns of different ``components`` (labels, one per row;
    the unknown-based AMG for systems): its strength, splitting and weights make each component's
    P by itself, block-diagonal by component and ≥ 0. A itself when components is None."""
    if components is None:
        return A
    keep = np.repeat(components, np.diff(A.indptr)) == components[A.indices]
    if keep.all():
        return A
    kept = np.zeros(A.nnz + 1, dtype=A.indptr.dtype)   # kept[k]: entries kept among A's first k
    np.cumsum(keep, out=kept[1:])
    indptr = kept[A.indptr]
    return sp.csr_matrix((A.data[keep], A.indices[keep], indptr), shape=A.shape)


def _auxiliary_level(A, theta, sweeps, truncate, unit):
    """One prolongation of A built on :func:`auxiliary_m_matrix`, or None when the splitting
    leaves no coarse (or no fine) point, or why the level is given up (a str)."""
    B = auxiliary_m_matrix(A)
    # the weights divide by its diagonal (and Newton needs it > 0 anyway)
    why = nonpositive_diagonal(B, "auxiliary M-matrix (its positive off-diagonals lumped into the diagonal)", unit)
    if why is not None:
        return why
    # norm='min': only negative couplings are strong ('abs' counts P2's positive ones: P < 0, many steps)
    S = _strength(B, theta, "min")
    is_c = _rs_split(S)
    if is_c.all() or not is_c.any():
        return None
    P = _rs_interpolation(B, S, is_c, "direct")
    return _canonical(_relax_interpolation(B, P, is_c, sweeps, truncate)), is_c


def _rs_levels(A, theta, max_coarse, max_levels, interpolation, components=None) -> list:
    """pyamg's ruge_stuben_solver's levels below A (classical strength θ, norm 'abs'; RS
    splitting; ``interpolation`` 'direct' or 'classical'): pairs (P_l, A_{l+1} = P_lᵀ A_l P_l),
    at most max_levels − 1 of them, until a level has at most max_coarse unknowns or the
    splitting leaves no coarse or no fine point. With ``components`` (labels of A's rows) each
    level is built on :func:`same_component` of its operator, a C point keeping its label."""
    out = []
    while len(out) < max_levels - 1 and A.shape[0] > max_coarse:
        A_c = same_component(A, components)
        S = _strength(A_c, theta, "abs")
        is_c = _rs_split(S)
        if is_c.all() or not is_c.any():
            break
        P = _rs_interpolation(A_c, S, is_c, interpolation)
        components = None if components is None else components[is_c]   # P's columns: the C points in order
        A = sp.csr_matrix(P.T.tocsr() @ A @ P)   # pyamg's order of the products
        A.sort_indices()   # pyamg's strength graph is sorted: RS breaks its ties in that order
        out.append((P, A))
    return out


def amg_prolongations(A, components=None, **opts) -> list:
    """Classical (Ruge–Stüben) AMG prolongations of A, finest first, built for nested iteration
    (the P of :func:`amg_levels`)."""
    return [P for P, _ in amg_levels(A, components, **opts)]


def amg_levels(A, components=None, **opts) -> list:
    """Classical (Ruge–Stüben) AMG levels of A, finest first, built for nested iteration: pairs
    (P_l, A_{l+1}) of a prolongation and the Galerkin operator A_{l+1} = P_lᵀ A_l P_l it makes,
    which the set-up forms anyway (the core takes them instead of forming them again).

    The first ``aux_levels`` levels: the coarsening (RS C/F splitting of the classical strength
    with ``theta``) and the direct-interpolation weights come from :func:`auxiliary_m_matrix` of
    the level's operator, so P ≥ 0 also when A is no M-matrix (P2/P3 finite elements); the
    weights are then improved by ``sweeps`` Jacobi sweeps on the F rows (exact for what the
    auxiliary matrix annihilates: constants), each truncated at ``truncate`` × the row maximum
    (row sums kept); the next operator is the true Galerkin product PᵀAP. Below: pyamg's
    ``ruge_stuben_solver`` (classical strength θ, classical interpolation).
    ``components`` (:func:`check_components`: None, an int k of interleaved components, or a label
    per unknown): a vector problem's unknowns, each level coarsened and interpolated by component
    (:func:`same_component`: strength only between unknowns of the same component), so P is
    block-diagonal by component and ≥ 0, exact for each component's constants (the translations
    of elasticity); the coarse operators are the true PᵀAP. None (or 1): the scalar hierarchy.
    Options (defaults): ``theta`` (0.25), ``max_coarse`` (10), ``max_levels`` (30), ``sweeps``
    (3), ``truncate`` (0.2), ``aux_levels`` (1). Works for nonsymmetric A (the strength reads
    A's rows). Returns a list of pairs of float64 canonical ``scipy.sparse.csr_matrix``, P_l of
    shape (n_l, n_{l+1}) and A_{l+1}; ``[]`` when A is already small enough to be the coarsest level.
    """
    return amg_levels_why(A, components, **opts)[0]


def amg_levels_why(A, components=None, **opts) -> tuple:
    """(:func:`amg_levels`, why the set-up gave up the next level: a str naming the level, the
    row and the non-positive diagonal entry that stopped it; None when it ended by its own rules
    (max_coarse, max_levels, a splitting without coarse or fine points))."""
    _pyamg()
    A = sp.csr_matrix(A, dtype=np.float64)
    if A.shape[0] != A.shape[1]:
        raise ValueError(f"A must be square, got shape {A.shape}")
    unknown = set(opts) - set(_RS_DEFAULTS)
    if unknown:
        raise TypeError(f"amg_prolongations got unknown options {sorted(unknown)}; known: {sorted(_RS_DEFAULTS)}")
    labels = check_components(components, A.shape[0])
    unit = units_factor(A)   # (a power of two: σA's levels are A's exactly; pyamg's kernels print at A's extremes)
    with _small_pages():
        levels, why = _levels(unit * A, labels, {**_RS_DEFAULTS, **opts}, unit)
    for _, Ac in levels:
        Ac.data /= unit
    return levels, why


def _levels(A, components, kw, unit) -> tuple:
    """amg_levels_why's (levels, why) of A (`unit` times the user's) with the labels `components` (or None) and
    the options kw (all given)."""
    out = []
    while len(out) < kw["aux_levels"] and A.shape[0] > kw["max_coarse"] and len(out) < kw["max_levels"] - 1:
        # by component on every level (on the first only: 12-48 CG iterations a solve; docs/MEASUREMENTS.md)
        level = _auxiliary_level(same_component(A, components), kw["theta"], kw["sweeps"], kw["truncate"], unit)
        if level is None or isinstance(level, str):
            why = None if level is None else f"the amg set-up gave up level {len(out) + 1}: level {len(out)}'s {level}"
            return out, why
        P, is_c = level
        components = None if components is None else components[is_c]
        A_fine, A = A, _canonical(P.T @ (A @ P))   # our own product: canonical in place, no copy
        out.append((P, A))
    if A.shape[0] <= kw["max_coarse"] or len(out) >= kw["max_levels"] - 1:
        return out, None
    # A first coarse operator denser than A costs more per V-cycle and Newton step than the finest
    # level: folded into the next (P_0 P_1, nonnegative), whose levels use direct interpolation.
    # "denser": the core's fold density (also the PETSc engine's; docs/MEASUREMENTS.md, "The fold of a denser first coarse level")
    dense = len(out) == 1 and A.nnz > _core.newton_tuning["fold_density"] * A_fine.nnz
    out += [(_canonical(P), _canonical(Ac)) for P, Ac in
            _rs_levels(A, kw["theta"], kw["max_coarse"], kw["max_levels"] - len(out), "direct" if dense else "classical",
                       components)]
    if dense and len(out) > 1:   # (P_0 P_1)ᵀ A (P_0 P_1) = P_1ᵀ A_1 P_1 = A_2
        out[:2] = [(_canonical(out[0][0] @ out[1][0]), out[1][1])]
    return out, None


class Hierarchy:
    """The levels of nested iteration, finest first, built once: A_0 = A, the prolongations P_l
    (n_l × n_{l+1}), the restrictions R_l = P_lᵀ and the Galerkin operators A_{l+1} = R_l A_l P_l.

    ``Hierarchy(A, prolongations)`` checks the prolongations (as ``hierarchy=[...]`` does) and forms
    the operators; ``Hierarchy.amg(A, components=None, **options)`` is the ``hierarchy='amg'`` set-up
    (:func:`amg_levels`). Pass it as ``hierarchy=`` to :func:`nrmicp.solve` or :class:`nrmicp.Solver`
    with the same A: the set-up then forms nothing (a march of solves, or several Solvers on one A,
    pays the amg set-up once). ``print(h)`` shows each level's rows and nonzeros."""

    def __init__(self, A, prolongations):
        self._A = as_csr(A, "A")   # (square: as_csr's check)
        if isinstance(prolongations, str):
            raise TypeError(f"prolongations must be a list of sparse matrices, got the string {prolongations!r}: "
                            "Hierarchy.amg(A) builds the 'amg' levels")
        if not isinstance(prolongations, (list, tuple)):
            raise TypeError(f"prolongations must be a list of sparse matrices, got {type(prolongations).__name__}")
        Ps = resolve_hierarchy(list(prolongations), self._A) or []
        operators = [self._A]
        for P in Ps:
            operators.append(_canonical(P.T @ (operators[-1] @ P)))
        self._set(Ps, operators)

    @classmethod
    def amg(cls, A, components=None, **options) -> "Hierarchy":
        """The 'amg' hierarchy of A (classical Ruge–Stüben, :func:`amg_levels`; ``options`` as there)."""
        h = cls.__new__(cls)
        h._A = as_csr(A, "A")
        pairs = amg_levels(h._A, components, **options)
        h._set([P for P, _ in pairs], [h._A] + [Ac for _, Ac in pairs])
        return h

    def _set(self, prolongations, operators):
        self.prolongations, self.operators = tuple(prolongations), tuple(operators)
        self._fingerprint = _fingerprint(self._A)
        for level, M in enumerate(self.operators[1:], 1):   # the core would end the nest there: said now
            why = nonpositive_diagonal(M, f"coarse operator {level}")
            if why:
                _warn(f"Hierarchy: {why}; nested iteration will end at level {level - 1} (a matrix whose rows are "
                      "scaled apart: hierarchy='amg' equilibrates them first)", HierarchyWarning)
                break

    @property
    def restrictions(self) -> tuple:
        """R_l = P_lᵀ (CSR), finest first."""
        return tuple(sp.csr_matrix(P.T) for P in self.prolongations)

    @property
    def complexity(self) -> float:
        """The coarse operators' nonzeros over A's (what a V-cycle adds to a product with A)."""
        return sum(M.nnz for M in self.operators[1:]) / max(self._A.nnz, 1)

    def __len__(self) -> int:
        return len(self.operators)

    def __repr__(self) -> str:
        rows = self.operators[0].shape[0], self.operators[-1].shape[0]
        levels = f"{len(self)} level{'s' if len(self) > 1 else ''}"
        return f"Hierarchy({levels}, {rows[0]:,} -> {rows[1]:,} rows, complexity {self.complexity:.2f})"

    def __str__(self) -> str:
        lines = [f"  {l:5d} {M.shape[0]:12,d} {M.nnz:14,d}" for l, M in enumerate(self.operators)]
        return "\n".join([repr(self), "  level         rows       nonzeros", *lines])

    def check_fits(self, A: sp.csr_matrix, rows: tuple | None = None) -> None:
        """ValueError naming hierarchy unless it was built on A as A is now (the same pattern and values:
        its coarse operators are their Galerkin products); `rows` (lo, hi): A is those rows of it (a rank's)."""
        B = self._A if rows is None else self._A[rows[0]:rows[1]]
        if B.shape != A.shape or B.nnz != A.nnz or _fingerprint(A) != (self._fingerprint if rows is None else _fingerprint(B)):
            raise ValueError(f"hierarchy was built on another matrix than A, or on A before it changed (shape "
                             f"{B.shape}, {B.nnz} nonzeros, against A's {A.shape}, {A.nnz}): its coarse operators "
                             "are that matrix's; build Hierarchy(A, hierarchy.prolongations) for this A, or pass "
                             "the prolongations as a list")


def _fingerprint(A: sp.csr_matrix) -> int:
    """A checksum of A's pattern and values, whatever its index dtype (a Hierarchy's A may be changed in
    place after it is built; CRC-32, the cheapest of the checksums measured: docs/MEASUREMENTS.md)."""
    import zlib
    crc = 0
    for a, dtype in ((A.indptr, np.int64), (A.indices, np.int64), (A.data, np.float64)):
        crc = zlib.crc32(np.ascontiguousarray(a, dtype=dtype).view(np.uint8), crc)
    return crc


def hierarchy_kind(hierarchy) -> str:
    """The hierarchy= option's kind, both engines' one check: 'none', 'auto', 'amg' or 'levels' (a Hierarchy, or
    a list or tuple of prolongations); ValueError for another string, TypeError for another type, naming it."""
    takes = "hierarchy must be 'auto', 'amg', None, a Hierarchy or a list of prolongation matrices"
    if hierarchy is None:
        return "none"
    if isinstance(hierarchy, str):
        if hierarchy in ("auto", "amg"):
            return hierarchy
        raise ValueError(f"{takes}, got {hierarchy!r}")
    if isinstance(hierarchy, (Hierarchy, list, tuple)):
        return "levels"
    raise TypeError(f"{takes}, got {type(hierarchy).__name__}")


def resolve_hierarchy(hierarchy, A) -> list | None:
    """The ``hierarchy=`` option as a checked list of prolongations, or None.

    Accepts ``"amg"`` (→ :func:`amg_prolongations`), ``"auto"`` or None (no list: None), a :class:`Hierarchy` (its prolongations; that it
    was built on A is the Solver's check, Hierarchy.check_fits), a list or tuple of prolongation
    matrices P_0, P_1, … (P_l of shape (n_l, n_{l+1}) with n_0 = A's size and each level
    strictly coarser; finite; converted to canonical float64 CSR), or None. An empty list
    means no coarse level (a cold start). A level with no columns (no coarse unknowns) is dropped
    with the levels after it, with a ConversionWarning. Raises TypeError/ValueError naming ``hierarchy``
    and the offending level.
    """
    kind = hierarchy_kind(hierarchy)
    if kind in ("none", "auto"):   # ('auto' not building amg: the caller's rule, _newton.resolves_to_amg)
        return None
    if isinstance(hierarchy, Hierarchy):   # (its fit to A: checked once, by the Solver given it)
        return list(hierarchy.prolongations)
    if kind == "amg":
        return amg_prolongations(A)
    rows = A.shape[0]
    out = []
    for level, P in enumerate(hierarchy):
        name = f"hierarchy[{level}]"
        P = as_csr(P, name, square=False)
        n_fine, n_coarse = P.shape
        if n_fine != rows:
            where = "A's size" if level == 0 else f"the columns of hierarchy[{level - 1}]"
            raise ValueError(f"{name} has shape {P.shape}: its rows must match {where} ({rows})")
        if n_coarse == 0:
            _drop_empty(level, P.shape, len(hierarchy))
            return out
        if not n_coarse < n_fine:
            raise ValueError(f"{name} has shape {P.shape}: a prolongation maps a strictly "
                             f"coarser level (1 <= columns < rows)")
        out.append(P)
        rows = n_coarse
    return out


def _drop_empty(level: int, shape: tuple, count: int) -> None:
    """Warn that hierarchy[level] (of `shape`, no column) and the levels after it are dropped: a
    level without unknowns (a coarsening of a small or L-shaped mesh can leave none) has nothing
    to solve, and every level below it would be empty too."""
    after = count - level - 1
    also = f" and the {after} level(s) after it" if after else ""
    kept = f"the solve keeps hierarchy[:{level}]" if level else "no coarse level is left (a cold start)"
    _warn(f"hierarchy[{level}] has shape {shape}: a coarse level without unknowns; dropping it{also}: {kept}",
          ConversionWarning)
