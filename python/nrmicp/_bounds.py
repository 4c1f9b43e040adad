"""Bounds: ``upper`` and the lower bound ζ's -inf entries (the mixed complementarity problem,
PATH's and PETSc's convention). The rules of what a bounded problem may be, its residual and the
``active_mask`` of a result live here once; the algorithms are in C++: the Newton member's
(detail/box.hpp) and every stationary member's box form, m(x) = 2 mid(lo', x, hi') − x in place of
|x| (detail/modulus.hpp)."""
from __future__ import annotations

import numpy as np

from . import _core
from ._inputs import as_constant

ZetaKind = _core.ZetaKind


def as_upper(upper, n: int, implicit: bool):
    """``upper=`` -> None (no upper bound) or a float64 vector that may hold +inf (no bound there).
    An `implicit` upper bound (Affine, callable) is refused naming ``upper``."""
    if upper is None:
        return None
    if implicit:
        raise TypeError("upper must be a constant (a number or a length-n vector, +inf where z has no upper "
                        "bound); an implicit upper bound (Affine or callable) is not supported")
    u = as_constant(upper, n, "upper", infinite=1)
    return None if np.all(u == np.inf) else u


def as_lower(zeta, n: int) -> np.ndarray:
    """A constant ζ that may hold -inf (z free below there) -> float64 vector."""
    return as_constant(zeta, n, "zeta", infinite=-1)


def is_bounded(c, upper) -> bool:
    """An upper bound, or a constant lower bound c with a -inf entry: the mixed problem."""
    return upper is not None or (c is not None and bool(np.any(c == -np.inf)))


def check(kind, c, upper, method: str, jacobian) -> None:
    """Refuses what bounds cannot go with, naming the argument: lower > upper (both named, the first
    index; a constant ζ), an Affine or callable ζ with ``upper`` on a method other than 'newton' (the
    outer fixed point solves it; its inner problems take the box), a zeta_jacobian. Every method
    takes bounds with ζ None or constant: each stationary member's box form converges where its LCP
    form does (m is 1-Lipschitz as |·| is: detail/modulus.hpp)."""
    if upper is not None:
        lower = np.zeros_like(upper) if c is None or kind != ZetaKind.constant else c
        bad = lower > upper
        if kind in (ZetaKind.none, ZetaKind.constant) and np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"the lower bound exceeds upper at index {i}: zeta[{i}] = {lower[i]:g} > upper[{i}] = "
                             f"{upper[i]:g} (no z lies between them)")
    if kind not in (ZetaKind.none, ZetaKind.constant) and method != "newton":
        raise ValueError(f"an Affine or callable zeta with upper is solved by method 'newton' (the outer fixed point); "
                         f"method {method!r} takes bounds with zeta None or constant only")
    if jacobian is not None:
        raise ValueError("zeta_jacobian with upper is not supported: the semismooth Newton step on the whole ICP has "
                         "no box; leave zeta_jacobian out (the outer fixed point then solves it)")


def residual_terms(z, w, g, upper):
    """mid(z − ζ, z − u, w) = min(g, max(z − u, w)) componentwise (g = z − ζ): the paper's min(w, g)
    when there is no upper bound."""
    if upper is None:
        return np.minimum(w, g)
    with np.errstate(invalid="ignore"):
        return np.minimum(g, np.maximum(z - upper, w))


def term_rounding(tw, z, w, g, upper):
    """Row by row, the rounding error (over eps) of the term residual_terms takes: tw (the row of
    |A||z| + |q|) where it is w, |z| + |ζ| where it is g = z − ζ, |z| + |u| where it is z − u; the larger
    of tw and g's on a tie w = g (the core's term_rounding, detail/box.hpp)."""
    with np.errstate(invalid="ignore", over="ignore"):
        tg = np.abs(z) + np.abs(z - g)
        t = np.where(w < g, tw, np.where(g < w, tg, np.maximum(tw, tg)))
        if upper is not None:
            zu = z - upper
            t = np.where(zu > w, np.where(g < zu, tg, np.abs(z) + np.abs(upper)), t)
    return t


def active_mask(z, w, g, upper) -> np.ndarray:
    """scipy's ``active_mask`` (as in ``lsq_linear``): -1 where z is at its lower bound ζ (g = z − ζ
    <= w), +1 at its upper bound (z − u >= w), 0 strictly between (w = 0 at a solution)."""
    mask = np.zeros(len(z), dtype=np.int8)
    with np.errstate(invalid="ignore"):
        if upper is not None:
            mask[z - upper >= w] = 1
        mask[(g <= w) & (mask == 0)] = -1
    return mask
