"""An elastic block pressed onto a rigid curved floor (Signorini contact), plane strain, scikit-fem:
a box problem in which most unknowns are free.

Model: linear elasticity (Young's modulus E, Poisson ratio ν, plane strain) on the block
Ω = (0, 2) × (0, 1). The top edge is pushed down by ``indent``, u = (0, −indent) there (Dirichlet:
it also fixes the rigid motions); the sides are traction free; below the bottom edge lies a rigid
floor y = −g(x), g(x) = ``curvature``·(x − ``centre``)², which touches the undeformed block at
x = ``centre``. Frictionless Signorini conditions on the bottom edge: u_y ≥ −g (no penetration),
contact force ≥ 0, and zero where there is a gap.

Discretization: conforming vector P1 or P2 elements on a uniform refinement of the two squares
(nested meshes), the Dirichlet degrees of freedom removed; the contact condition is imposed at the
bottom edge's nodes (vertices, and edge midpoints for P2). As a mixed complementarity problem in
z = the displacement degrees of freedom (``nrmicp.solve(A, q, zeta=lower)``):

    A = the stiffness matrix (SPD, no M-matrix: its x–y couplings have both signs),
    q = K_ID u_D (the pushed top edge's contribution; no body force),
    ζ = −g at the bottom edge's u_y, −inf on every other degree of freedom (free unknowns),

so w = A z + q is the floor's nodal contact force on the block: ≥ 0 at contact, 0 elsewhere.
Of n unknowns about √n are bounded; all the others are free.

Sizes: refinements r give n = 2·2^r·(2^{r+1} + 1) for P1 (16,512 / 65,792 / 262,656 at r = 6 / 7 /
8); P2 at r has the unknowns of P1 at r + 1. ``Problem.prolongations()`` returns the mesh
hierarchy's nested interpolation (each component by itself), to pass as ``hierarchy=``. Without it,
``Problem.solver_options`` = ``{"components": 2}`` (``Problem.solve`` passes it) tells the default
'amg' hierarchy that the two components interleave: 'amg' by component takes 3-4 finest Newton steps
and about 2 CG iterations a solve, plain scalar 'amg' 4-8 and 23-96 (README "Bounds and free unknowns").

scikit-fem is imported when a scene is built (a test and benchmark dependency, as for fe_obstacle).

Left out: friction, large deformations, a deformable floor, the floor's curvature in the normal
direction (the contact normal is taken vertical: small slopes).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from . import Problem
from ._exact import exact_box_if_small
from .finite_elements import _probes, _skfem

__all__ = ["elastic_contact", "elastic_contact_interpolation"]

_ELEMENTS = ("P1", "P2")


def _check(element, refinements):
    if element not in _ELEMENTS:
        raise ValueError(f"element must be one of {_ELEMENTS}, got {element!r}")
    if not isinstance(refinements, (int, np.integer)) or isinstance(refinements, bool) or not 0 <= refinements <= 9:
        raise ValueError(f"refinements must be an int in 0..9, got {refinements!r}")


def _mesh(refinements: int):
    skfem = _skfem()
    mesh = skfem.MeshTri.init_tensor(np.linspace(0.0, 2.0, 3), np.linspace(0.0, 1.0, 2))
    return mesh.refined(refinements) if refinements else mesh


def _scalar(element: str):
    skfem = _skfem()
    return {"P1": skfem.ElementTriP1, "P2": skfem.ElementTriP2}[element]()


def _basis(element: str, refinements: int):
    """The vector basis (its degrees of freedom interleave the components: 2k is u_x, 2k + 1 u_y of
    the scalar basis' k-th) and the indices of the free, i.e. non-Dirichlet, degrees of freedom."""
    skfem = _skfem()
    basis = skfem.Basis(_mesh(refinements), skfem.ElementVector(_scalar(element)))
    top = basis.get_dofs(lambda x: np.isclose(x[1], 1.0))
    return basis, top, basis.complement_dofs(top.all())


def elastic_contact_interpolation(element: str, refinements: int) -> list:
    """The nested interpolation of the mesh hierarchy, finest first: P_l maps the unknowns after
    ``refinements − l − 1`` refinements to those after ``refinements − l`` (shape (n_l, n_{l+1})),
    each displacement component interpolated by itself (the scalar interpolation ⊗ I₂)."""
    _check(element, refinements)
    skfem = _skfem()
    out = []
    for r in range(refinements, 0, -1):
        fine, coarse = (skfem.Basis(_mesh(k), _scalar(element)) for k in (r, r - 1))
        Ps = _probes(coarse, fine.doflocs)
        Ps.data[np.abs(Ps.data) < 1e-12] = 0.0        # rounding of the barycentric look-up
        Pv = sp.kron(Ps, sp.identity(2), format="csr")  # the interleaved components
        P = sp.csr_matrix(Pv[_basis(element, r)[2]][:, _basis(element, r - 1)[2]], dtype=np.float64)
        P.eliminate_zeros()
        P.sort_indices()
        out.append(P)
    return out


def _parts(element, refinements, indent, E, nu):
    """(basis, free dofs, A, q, bottom edge's u_y dofs)."""
    skfem = _skfem()
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    basis, top, free = _basis(element, refinements)
    K = skfem.asm(linear_elasticity(*lame_parameters(E, nu)), basis).tocsr()   # λ, μ of plane strain
    u_D = np.zeros(basis.N)
    u_D[top.all("u^2")] = -indent
    fixed = top.all()
    A = sp.csr_matrix(K[free][:, free], dtype=np.float64)
    A.eliminate_zeros()
    A.sort_indices()
    q = np.asarray(K[free][:, fixed] @ u_D[fixed], dtype=np.float64)
    bottom = basis.get_dofs(lambda x: np.isclose(x[1], 0.0)).all("u^2")
    return basis, free, A, q, bottom


def elastic_contact(element: str = "P1", refinements: int = 6, indent: float = 0.05, curvature: float = 0.5,
                    centre: float = 0.9, E: float = 1.0, nu: float = 0.3, exact=None) -> Problem:
    """The block pressed by ``indent`` onto the floor y = −``curvature``·(x − ``centre``)² (module
    docstring), vector ``element`` ('P1' or 'P2') on ``refinements`` uniform refinements.

    ``reference``: the coordinates ``x``, ``y`` and ``component`` (0: u_x, 1: u_y) of each unknown,
    ``contact`` (the indices of the bounded unknowns), ``prolongations``. ``z_exact`` by policy
    iteration (:func:`solve_exact_box`) when ``exact`` is True (default: n ≤ 20,000).
    ``solver_options``: ``components=2`` (the interleaved displacement components, for 'amg').
    """
    _check(element, refinements)
    if not (indent > 0 and curvature > 0 and E > 0 and -1.0 < nu < 0.5):
        raise ValueError(f"need indent > 0, curvature > 0, E > 0, -1 < nu < 0.5; got indent={indent}, "
                         f"curvature={curvature}, E={E}, nu={nu}")
    basis, free, A, q, bottom = _parts(element, refinements, indent, E, nu)
    contact = np.searchsorted(free, bottom)            # free is sorted; the bottom u_y are free dofs
    x, y = basis.doflocs[:, free]
    lower = np.full(A.shape[0], -np.inf)
    lower[contact] = -curvature * (x[contact] - centre) ** 2
    return Problem(
        name=f"elastic_contact({element}, r={refinements})", A=A, q=q, zeta=lower,
        z_exact=exact_box_if_small(A, q, lower, None, exact),
        reference={"x": x, "y": y, "component": free % 2, "contact": contact, "element": element,
                   "refinements": refinements, "prolongations": lambda: elastic_contact_interpolation(element,
                                                                                                     refinements)},
        description=f"elastic block pressed {indent} onto a curved rigid floor, plane strain, Signorini contact on "
                    f"the bottom edge, vector {element} on a {refinements}x refined mesh (free unknowns)",
        models=("linear elasticity, plane strain", "frictionless Signorini contact with a rigid floor",
                f"conforming vector {element} finite elements"),
        omits=("friction", "large deformations", "a deformable floor", "the floor's slope in the contact normal"),
        lipschitz=0.0, solver_options={"components": 2})
