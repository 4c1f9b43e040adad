"""Bounds: ``upper`` and the lower bound ζ's -inf entries (the mixed complementarity problem,
PATH's and PETSc's convention). The rules of what a bounded problem may be, its residual and the
``active_mask`` of a result live here once; the algorithms are in C++: the Newton member's
(detail/box.hpp; an implicit upper bound u(z) by its outer fixed point, detail/outer_fixed_point.hpp)
and every stationary member's box form, m(x) = 2 mid(lo', x, hi') − x in place of |x|
(detail/modulus.hpp)."""
from __future__ import annotations

import numpy as np

from . import _core
from ._inputs import WholeRows
from ._scaling import ScaledCallable, scale_matrix
from ._zeta import CheckedZeta

ZetaKind = _core.ZetaKind


class CheckedUpper(CheckedZeta):
    """A callable upper bound u(z) for one solve: on a read-only copy of z, its output checked as
    ζ's is (CheckedZeta: shape, dtype) and then for values: a number or +inf (no bound on that row),
    never NaN or -inf. The core calls ``fn`` itself, so the value check is part of ``fn``."""

    what = "upper(z)"
    finite = False   # (+inf: no bound on that row; NaN and -inf refused by _call)

    def __init__(self, user, n: int):
        super().__init__(self._call, n)
        self.user = user

    def _call(self, z):
        u = self.output(self.user(z))
        bad = np.isnan(u) | (u == -np.inf)
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"upper(z) returned {u[i]} at index {i}; upper(z) must hold numbers or +inf (no upper "
                             "bound on that row), never NaN or -inf")
        return u


class ImplicitUpper:
    """An upper bound that depends on z: u(z) = Bz + c (an Affine, evaluated in C++) or a callable
    (a CheckedUpper). ``at(z)`` evaluates it in numpy (Res and active_mask of a returned z)."""

    def __init__(self, kind, B=None, c=None, fn=None):
        self.kind, self.B, self.c, self.fn = kind, B, c, fn

    def at(self, z) -> np.ndarray:
        if self.kind == ZetaKind.affine:
            with np.errstate(invalid="ignore"):   # (+inf in c: no bound on that row)
                return self.B @ z + self.c
        return self.fn(z)

    def core(self, index_dtype, dc=None) -> tuple:
        """The core's argument (make_zeta's: kind, c, B-indptr, B-indices, B-data, fn), in the scaled
        variables y = z / dc when `dc` is given: u'(y) = D_c⁻¹ u(D_c y)."""
        if self.kind == ZetaKind.affine:
            B, c = (self.B, self.c) if dc is None else (scale_matrix(self.B, 1.0 / dc, dc), self.c / dc)
            return (self.kind, c, B.indptr.astype(index_dtype, copy=False), B.indices.astype(index_dtype, copy=False),
                    B.data, None)
        fn = self.fn if dc is None or np.all(dc == 1.0) else CheckedZeta(ScaledCallable(self.fn, dc), self.fn.n)
        fn.what, fn.finite = "upper(z)", False   # (its values checked by the CheckedUpper it calls)
        return (self.kind, None, None, None, None, fn)


def as_upper(upper, n: int, affine: tuple | None = None, read=None):
    """``upper=`` -> None (no upper bound), a float64 vector that may hold +inf (no bound there), or an
    ImplicitUpper: `affine` (B, c) of an Affine upper, or a callable. Errors name ``upper``. `read`: how
    B and vectors are read (_inputs.WholeRows(n) unless given)."""
    if upper is None or isinstance(upper, ImplicitUpper):   # (the latter already checked: a re-solve)
        return upper
    read = read or WholeRows(n)
    if affine is not None:
        B = read.matrix(affine[0], "upper.B")
        return ImplicitUpper(ZetaKind.affine, B=B, c=read.vector(affine[1], "upper.c", infinite=1))
    if callable(upper):
        return ImplicitUpper(ZetaKind.functor, fn=CheckedUpper(upper, n))
    u = read.vector(upper, "upper", infinite=1)
    return None if np.all(u == np.inf) else u


def upper_at(upper, z):
    """The upper bound's vector at z (None: none)."""
    return upper.at(z) if isinstance(upper, ImplicitUpper) else upper


def core_upper(upper, index_dtype, dc=None):
    """``upper`` as the core takes it (None, a vector, or ImplicitUpper.core's tuple), scaled by dc when given."""
    if isinstance(upper, ImplicitUpper):
        return upper.core(index_dtype, dc)
    return upper if upper is None or dc is None else upper / dc


def is_bounded(c, upper) -> bool:
    """An upper bound, or a constant lower bound c with a -inf entry: the mixed problem."""
    return upper is not None or (c is not None and bool(np.any(c == -np.inf)))


def check(kind, c, upper, method: str, jacobian) -> None:
    """Refuses what bounds cannot go with, naming the argument: lower > upper (both named, the first
    index; a constant ζ and a constant upper), an Affine or callable ζ or ``upper`` with bounds on a
    method other than 'newton' (the outer fixed point solves it; its inner problems take the box
    frozen at each outer step's z), a zeta_jacobian. Every method takes constant bounds: each
    stationary member's box form converges where its LCP form does (m is 1-Lipschitz as |·| is:
    detail/modulus.hpp). Where an implicit bound crosses at the answer the core's message says so."""
    implicit = isinstance(upper, ImplicitUpper)
    if upper is not None and not implicit:
        lower = np.zeros_like(upper) if c is None or kind != ZetaKind.constant else c
        bad = lower > upper
        if kind in (ZetaKind.none, ZetaKind.constant) and np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"the lower bound exceeds upper at index {i}: zeta[{i}] = {lower[i]:g} > upper[{i}] = "
                             f"{upper[i]:g} (no z lies between them)")
    if implicit and method != "newton":
        raise ValueError(f"an Affine or callable upper (an implicit upper bound) is solved by method 'newton' (the "
                         f"outer fixed point); method {method!r} takes a constant upper only")
    if kind not in (ZetaKind.none, ZetaKind.constant) and method != "newton":
        raise ValueError(f"an Affine or callable zeta with upper is solved by method 'newton' (the outer fixed point); "
                         f"method {method!r} takes bounds with zeta None or constant only")
    if jacobian is not None:
        raise ValueError("zeta_jacobian with upper is not supported: the semismooth Newton step on the whole ICP has "
                         "no box; leave zeta_jacobian out (the outer fixed point then solves it)")


def residual_terms(z, w, g, upper):
    """mid(z − ζ, z − u, w) = min(g, max(z − u, w)) componentwise (g = z − ζ, u the upper bound's
    vector at z: upper_at): the paper's min(w, g) when there is no upper bound. Where the bounds
    cross (ζ > u, i.e. z − u > g: an implicit bound), max(z − u, ζ − z), the larger violation of the
    two (the core's rule, detail/box.hpp bounded_residual: Res vanishes only where both hold)."""
    if upper is None:
        return np.minimum(w, g)
    with np.errstate(invalid="ignore"):
        above = z - upper
        terms = np.minimum(g, np.maximum(above, w))
        cross = above > g
        return np.where(cross, np.maximum(above, -g), terms) if np.any(cross) else terms


def active_mask(z, w, g, upper) -> np.ndarray:
    """scipy's ``active_mask`` (as in ``lsq_linear``): -1 where z is at its lower bound ζ (g = z − ζ
    <= w), +1 at its upper bound (z − u >= w), 0 strictly between (w = 0 at a solution)."""
    mask = np.zeros(len(z), dtype=np.int8)
    with np.errstate(invalid="ignore"):
        if upper is not None:
            mask[z - upper >= w] = 1
        mask[(g <= w) & (mask == 0)] = -1
    return mask
