"""The result of a solve, and scipy's rule for what a callback receives: shared by the API
(_api.py) and the decoupled rows (_decoupled.py), which the API uses."""
from __future__ import annotations

import inspect
from typing import Any, Callable

import numpy as np
from scipy.optimize import OptimizeResult


class Result(OptimizeResult):
    """Result of a solve (a scipy ``OptimizeResult``).

    Attributes: ``z`` (the solution, or the best iterate when not converged), ``w`` (= Az + q),
    ``success``, ``status`` (:class:`Status`), ``message``, ``nit`` (iterations to reach ``z``),
    ``residual`` (Res(z) = ‖min(Az+q, z−ζ(z))‖₂, the paper's measure, whatever rule decided),
    ``criterion`` (what decided ``success``: ``measure`` "units" (the default rule, Res_E) or
    "paper", its ``target`` and its ``value`` at z), ``history`` (dict of arrays ``iteration``,
    ``seconds``, ``residual``: the deciding measure, as the callback's; None unless
    ``record_history``), ``timings`` (dict of wall-clock
    seconds of this call: ``total`` the whole call from entry to return, so for
    :func:`nrmicp.solve` the set-up included, for :meth:`Solver.solve` that call only (the
    constructor's seconds are :attr:`Solver.setup_timings`); ``setup`` the set-up done in the
    call (nrmicp.solve: the constructor's, the AMG hierarchy included; any call: what is set up
    on first use, e.g. the Newton member's reduced systems and their symbolic analysis) and
    ``iterations`` the iteration loop without it, disjoint parts of ``total``; ``factorization``
    the numeric factorizations, in ``setup`` + ``iterations`` (Newton: each step's, or the
    V-cycle's update with inner 'cg', and the fallback member's); ``zeta``, ``spmv`` (products
    with A and ζ's B; the AOR types' one-pass sweep, Newton's projected sweeps) and
    ``inner_solve`` (Newton: the reduced solves), parts of ``iterations``; docs/SPEC.md, "Timings"),
    ``method``, ``inner`` (the solver used for the left matrix), ``counters`` (dict name -> int:
    what the step kind counts beyond the iterations, e.g. ``anderson_rejections``, the
    accelerated steps replaced by the plain one; empty when it counts nothing).
    Method 'newton' adds ``hierarchy``: ``{"requested": levels requested (1 + the prolongations
    listed; for 'amg', the levels its set-up built plus one it gave up), "used": levels nested
    over (:attr:`Solver.levels`), "reason": why fewer are used (which level, what was wrong), or
    None}``; a shortened hierarchy also raises a :class:`nrmicp.HierarchyWarning` at set-up and is
    named in the message of a solve that does not converge.
    ``x`` is an alias of ``z`` (scipy's name for the solution).
    """

    @property
    def x(self) -> np.ndarray:
        """The solution z (scipy's ``OptimizeResult.x``)."""
        return self["z"]

    def __repr__(self) -> str:
        # scipy's formatter fails on an empty nested dict (max() of no keys): print it as {}
        if any(isinstance(v, dict) and not v for v in self.values()):
            return repr(Result({k: "{}" if isinstance(v, dict) and not v else v for k, v in self.items()}))
        return super().__repr__()


# Pickles name the public path, which survives moves between private modules.
Result.__module__ = "nrmicp"


def wants_result(callback: Callable[..., Any]) -> bool:
    """scipy's rule: a callback whose only parameter is named ``intermediate_result`` receives a
    :class:`Result`; any other the iterate alone."""
    try:
        params = set(inspect.signature(callback).parameters)
    except (TypeError, ValueError):  # a builtin without a signature: the plain form
        params = set()
    return params == {"intermediate_result"}
