"""Obstacle problem with scikit-fem and nrmicp: pass your mesh hierarchy's own nested
interpolation as ``hierarchy=`` (when you have one), or let nrmicp build an algebraic one.

    pip install scikit-fem nrmicp
    python examples/scikit_fem_hierarchy.py

Membrane over an off-centre obstacle on a disk-like polygon, P2 elements, u = 0 on the boundary:
find u ≥ ψ with −Δu ≥ f, (−Δu − f)(u − ψ) = 0; nodal obstacle, Dirichlet rows removed.
"""
import time

import numpy as np
import nrmicp
from skfem import Basis, ElementTriP2, LinearForm, MeshTri, asm
from skfem.models.poisson import laplace

levels = 3                                   # uniform refinements of the starting polygon
# .refined() keeps the boundary where it is, so the meshes are nested (init_circle(k) would
# project new boundary nodes onto the circle: then coarse functions no longer live on the fine mesh)
meshes = [MeshTri.init_circle(3).refined(k) for k in range(levels + 1)]
bases = [Basis(m, ElementTriP2()) for m in meshes]
interior = [b.complement_dofs(b.get_dofs()) for b in bases]

# the finest problem, as ICP(q, A, ζ): A = stiffness, q = −load, ζ = ψ at the degrees of freedom
fine, I = bases[-1], interior[-1]
A = asm(laplace, fine)[I][:, I].tocsr()
q = -asm(LinearForm(lambda v, w: -1.0 * v), fine)[I]          # f = −1
x, y = fine.doflocs[:, I]
psi = 0.1 - (x - 0.3) ** 2 - (y - 0.2) ** 2

# The nested interpolation, finest first: P_l evaluates the coarse finite-element function at
# the fine interior nodes; shape (n_l, n_{l+1}). Dirichlet columns are dropped (their value is 0).
# (scikit-fem's probes() locates points with memory ~ points x cells: fine up to n ~ 3e4; for
# larger meshes, nrmicp.scenes.finite_elements.fe_interpolation shows a nearest-cells search.)
Ps = []
for k in range(levels, 0, -1):
    f_basis, c_basis = bases[k], bases[k - 1]
    P = c_basis.probes(f_basis.doflocs[:, interior[k]]).tocsr()[:, interior[k - 1]]
    P.data[np.abs(P.data) < 1e-12] = 0.0     # rounding of the point location
    P.eliminate_zeros()
    Ps.append(P)

for name, hierarchy in [("mesh hierarchy", Ps), ("algebraic (amg)", "amg")]:
    t = time.process_time()
    res = nrmicp.solve(A, q, psi, method="newton", hierarchy=hierarchy, tol=1e-9)
    print(f"{name:16s} n = {A.shape[0]}: {res.message}; finest-level steps {res.level_steps[0]}, "
          f"{res.linear_solves} linear solves, {time.process_time() - t:.2f} CPU s, Res {res.residual:.1e}")
    print(f"{'':16s} contact at {np.sum(np.isclose(res.z, psi, atol=1e-10))} nodes")
