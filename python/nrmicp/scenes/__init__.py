"""Test and benchmark scenes for nrmicp: each returns a :class:`Problem`.

A scene is one ICP(q, A, ζ): find z with

    w = A z + q ≥ 0,   g = z − ζ(z) ≥ 0,   gᵀ w = 0.

The principle is *simulate only the effects a scene calls for*, and pay only for them:

- a constant obstacle is a constant vector ζ (an ``ndarray``): nrmicp solves it as a
  shifted LCP and never calls back into Python;
- an affine ζ(z) = B z + c is an ``nrmicp.Affine(B, c)``, evaluated in C++;
- only a genuinely nonlinear ζ is a Python callable; it is vectorized numpy, called once
  per iteration, and writes into a buffer preallocated when the scene is built. **The array
  it returns is overwritten by the next call** — copy it if you keep it.

Scenes (one module per family):

=======================  ==========================================================
:func:`bai`               Bai's block-tridiagonal test matrices, LCP / ICP / affine ICP
                          with a solution known by construction
:func:`obstacle_1d`       membrane over a concave obstacle, closed-form solution
:func:`obstacle_2d`       membrane over a paraboloid obstacle on the unit square
:func:`obstacle_3d`       the same in 3D (7-point Laplacian): where factorizations get costly
:func:`convection_diffusion_obstacle`
                          upwind convection–diffusion with an obstacle: a nonsymmetric
                          M-matrix
:func:`p_matrix_cycling`  a P-matrix (not M, not H+) on which plain active-set Newton cycles
:func:`thermoforming_1d`  implicit obstacle: a mould that expands with a temperature
:func:`thermoforming_2d`  driven by the membrane (a quasi-variational inequality)
:func:`impulse_control`   1D impulse-control QVI: ζ(z)_i = max_{j≥i} z_j − cost
:func:`american_put`      one Rannacher/Crank–Nicolson step of an American put;
                          :func:`american_put_price` marches all steps with one Solver
:func:`fe_obstacle`       membrane over an off-centre obstacle, P1/P2/P3 finite elements
                          on nested refinements (scikit-fem, imported on use); its
                          ``prolongations()`` are the mesh hierarchy's interpolation
:func:`contact_disk_p1`   P1 elements on a Delaunay mesh of scattered points, no grid and
                          no mesh hierarchy (numpy/scipy only)
:func:`two_sided_membrane_1d`
                          string between two plates, a box problem lower ≤ z ≤ upper;
                          closed-form solution
:func:`two_sided_membrane_2d`
                          membrane between two plates on the unit square, both touched
:func:`elastic_contact`   plane-strain elastic block on a rigid floor (Signorini), vector
                          P1/P2 (scikit-fem): a few bounded unknowns, all others free
:func:`game_put`          one step of a game (Israeli) put: exercise payoff below,
                          cancellation payoff above; :func:`game_put_price` marches
=======================  ==========================================================

Box scenes carry ``Problem.upper`` (an upper bound, +inf where none) and/or a constant ζ with
-inf entries (free unknowns); ``Problem.solve`` and ``Problem.residual`` take them into account
(PATH's convention, ``nrmicp.solve(..., upper=)``), and :func:`solve_exact_box` is their
policy-iteration reference.

``z_exact`` is the exact solution *of the discrete problem* (what an iterative solver
should converge to), computed by construction or by a direct policy-iteration solver
(:func:`solve_exact_obstacle`); quantities of the continuous model, such as a sampled
closed-form solution or a price, live in ``reference``.

The registry (one meaning of each size name, for tests, the bench and benchmarks/):
``build(name, size)`` builds any scene of ``NAMES`` at a size of ``SIZES`` ("tiny", "small",
"medium", "large", "realistic"); ``catalog(size)`` builds them all; ``scaled_lcp(problem)`` is
a grid obstacle as the h²-scaled pure LCP the peer tables use.

Grid scenes record their grid (``Problem.grid``) and offer its geometric hierarchy for nested
iteration, ``Problem.prolongations()`` (linear / bilinear / trilinear interpolation, for
m = 2^k − 1 nodes per axis), to pass as ``hierarchy=``.

nrmicp itself is imported lazily (only where ``nrmicp.Affine`` or ``nrmicp.Solver`` is
needed), so these modules import and build their matrices without the compiled core.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Union

import numpy as np
import scipy.sparse as sp

__all__ = [
    "Problem",
    "bai",
    "obstacle_1d",
    "obstacle_2d",
    "obstacle_3d",
    "convection_diffusion_obstacle",
    "p_matrix_cycling",
    "thermoforming_1d",
    "thermoforming_2d",
    "impulse_control",
    "american_put",
    "american_put_price",
    "binomial_american_put",
    "fe_obstacle",
    "contact_disk_p1",
    "solve_exact_obstacle",
    "solve_exact_box",
    "two_sided_membrane_1d",
    "two_sided_membrane_2d",
    "two_sided_membrane_heated_2d",
    "elastic_contact",
    "game_put",
    "game_put_price",
    "binomial_game_put",
    "evaluate_zeta",
    "NAMES",
    "SIZES",
    "build",
    "catalog",
    "parameter",
    "scaled_lcp",
]

ZetaLike = Union[None, np.ndarray, Callable[[np.ndarray], np.ndarray], Any]


def evaluate_zeta(zeta: ZetaLike, z: np.ndarray) -> np.ndarray:
    """ζ(z) for every form a scene may use, as a fresh array (never a shared buffer).

    None → zeros; ndarray → the constant obstacle; ``nrmicp.Affine`` (recognized by its
    ``B`` and ``c`` attributes) → B z + c; callable → ``zeta(z)``.
    """
    z = np.asarray(z, dtype=np.float64)
    if zeta is None:
        return np.zeros_like(z)
    if isinstance(zeta, np.ndarray):
        return np.array(zeta, dtype=np.float64)
    if hasattr(zeta, "B") and hasattr(zeta, "c"):
        return np.asarray(zeta.B @ z + np.asarray(zeta.c), dtype=np.float64)
    if callable(zeta):
        return np.array(zeta(z), dtype=np.float64)
    raise TypeError(f"zeta must be None, an ndarray, nrmicp.Affine or a callable; got {type(zeta)!r}")


@dataclass(frozen=True, eq=False)
class Problem:
    """One ICP(q, A, ζ) scene.

    Attributes
    ----------
    name : str
        Short identifier, e.g. ``"obstacle_1d(n=255)"``.
    A : scipy.sparse.csr_matrix, float64, n × n
    q : ndarray, shape (n,)
    zeta : None | ndarray | nrmicp.Affine | callable
        None for an LCP, an ndarray for a constant obstacle, ``nrmicp.Affine`` for an
        affine map, a callable ``zeta(z) -> ndarray`` only when ζ is nonlinear.
    z_exact : ndarray or None
        Exact solution of this discrete problem when known.
    reference : dict
        Continuous-model quantities (closed-form solution, price, grid, ...); may be empty.
    description : str
        One line.
    models, omits : tuple of str
        The effects the scene models, and what it deliberately leaves out.
    lipschitz : float or None
        A Lipschitz constant of ζ in the ∞-norm when known (0 for a constant obstacle).
    solver_options : dict
        Options the scene needs from the solver, with the reason in the scene's docstring
        (e.g. impulse control needs ``z_update='solve'``: its ζ has Lipschitz constant 1, where
        the default explicit z-update does not converge). :meth:`solve` applies them.
    grid : tuple of int or None
        Nodes per axis (x first, the fastest in the ordering) when the unknowns are the
        interior nodes of a uniform tensor grid; None otherwise. :meth:`prolongations`
        builds the geometric hierarchy from it.
    upper : ndarray, callable or None
        An upper bound (+inf where there is none): the scene is the mixed complementarity
        problem ζ ≤ z ≤ upper (``nrmicp.solve``'s ``upper=``; ζ a constant that may hold -inf,
        where z is free below); a callable u(z) is an implicit upper bound (method 'newton').
        None: the ICP above.
    """

    name: str
    A: sp.csr_matrix
    q: np.ndarray
    zeta: ZetaLike
    z_exact: Optional[np.ndarray]
    reference: dict = field(default_factory=dict)
    description: str = ""
    models: tuple = ()
    omits: tuple = ()
    lipschitz: Optional[float] = None
    solver_options: dict = field(default_factory=dict)
    grid: Optional[tuple] = None
    upper: Optional[np.ndarray] = None

    @property
    def n(self) -> int:
        """Number of unknowns."""
        return self.A.shape[0]

    def zeta_at(self, z: np.ndarray) -> np.ndarray:
        """ζ(z) as a fresh array, whatever form ``zeta`` has."""
        return evaluate_zeta(self.zeta, z)

    def parts(self, z: np.ndarray) -> tuple:
        """(w, g) = (A z + q, z − ζ(z)) at z."""
        z = np.asarray(z, dtype=np.float64)
        return self.A @ z + self.q, z - self.zeta_at(z)

    def residual(self, z: np.ndarray) -> float:
        """Res(z) = ‖min(A z + q, z − ζ(z))‖₂, the paper's criterion (computed in numpy); with
        ``upper``, ‖mid(z − ζ, z − upper, A z + q)‖₂ (PATH's, which is the paper's without it)."""
        w, g = self.parts(z)
        if self.upper is None:
            return float(np.linalg.norm(np.minimum(w, g)))
        from .._bounds import residual_terms   # (crossed implicit bounds: its rule)

        upper = self.upper(z) if callable(self.upper) else self.upper
        return float(np.linalg.norm(residual_terms(np.asarray(z, dtype=float), w, g, upper)))

    def prolongations(self):
        """The scene's geometric hierarchy for ``hierarchy=`` (nested iteration), or None.

        Linear / bilinear / trilinear interpolation on the scene's grid, finest first (P_l of
        shape (n_l, n_{l+1})), halving every axis while the node counts are odd, so a grid
        of m = 2^k − 1 nodes per axis coarsens to a single node. None when the scene has no
        grid or its node counts are even (use ``hierarchy="amg"`` there). A scene with a mesh
        hierarchy of its own (finite elements) keeps a builder in ``reference["prolongations"]``.
        """
        if callable(self.reference.get("prolongations")):
            return self.reference["prolongations"]() or None
        if self.grid is None:
            return None
        from ._operators import grid_prolongations

        return grid_prolongations(self.grid) or None

    def solve(self, **options):
        """``nrmicp.solve(self.A, self.q, self.zeta, **self.solver_options, **options)``, with
        ``upper=self.upper`` when the scene has an upper bound."""
        import nrmicp

        bounds = {} if self.upper is None else {"upper": self.upper}
        return nrmicp.solve(self.A, self.q, self.zeta, **bounds, **{**self.solver_options, **options})


from ._exact import solve_exact_box, solve_exact_obstacle  # noqa: E402
from .bai import bai  # noqa: E402
from .obstacle import obstacle_1d, obstacle_2d, obstacle_3d  # noqa: E402
from .convection import convection_diffusion_obstacle  # noqa: E402
from .p_matrix import p_matrix_cycling  # noqa: E402
from .thermoforming import thermoforming_1d, thermoforming_2d  # noqa: E402
from .impulse import impulse_control  # noqa: E402
from .american import american_put, american_put_price, binomial_american_put  # noqa: E402
from .finite_elements import fe_obstacle  # noqa: E402  (scikit-fem is imported when a scene is built)
from .unstructured import contact_disk_p1  # noqa: E402
from .two_sided import two_sided_membrane_1d, two_sided_membrane_2d, two_sided_membrane_heated_2d  # noqa: E402
from .elastic_contact import elastic_contact  # noqa: E402  (scikit-fem is imported when a scene is built)
from .game import binomial_game_put, game_put, game_put_price  # noqa: E402

from ._registry import NAMES, SIZES, build, catalog, parameter, scaled_lcp  # noqa: E402
