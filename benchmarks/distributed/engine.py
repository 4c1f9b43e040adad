"""The one Newton driver on its two engines, same problem and prolongations: the serial member
(Eigen/SuiteSparse, nrmicp.solve) against the PETSc engine (nrmicp._petsc), finest steps and seconds.

    mpirun -n P python benchmarks/distributed/engine.py [m]     (2D obstacle, n = m², m = 2^k − 1)
"""
import sys
import time

import numpy as np
import scipy.sparse as sp
from petsc4py import PETSc

import nrmicp
from nrmicp import _core, _petsc
from nrmicp.scenes.obstacle import obstacle_2d

COMM = PETSc.COMM_WORLD
RANK, SIZE = COMM.getRank(), COMM.getSize()


def split(n):
    cuts = np.round(np.linspace(0, n, SIZE + 1)).astype(int)
    return int(cuts[RANK]), int(cuts[RANK + 1])


def mat(M, lo, hi, clo, chi):
    B = sp.csr_matrix(M[lo:hi])
    B.sort_indices()
    return PETSc.Mat().createAIJ(size=((hi - lo, M.shape[0]), (chi - clo, M.shape[1])),
                                 csr=(B.indptr.astype(PETSc.IntType), B.indices.astype(PETSc.IntType), B.data), comm=COMM)


def main(m):
    pb = obstacle_2d(m, exact=False)
    A, q, psi, Ps = sp.csr_matrix(pb.A), pb.q, pb.zeta, pb.prolongations()
    n = A.shape[0]
    lo, hi = split(n)
    M = mat(A, lo, hi, lo, hi)
    mats, f = [], (lo, hi)
    for P in Ps:
        c = split(P.shape[1])
        mats.append(mat(sp.csr_matrix(P), *f, *c))
        f = c
    o = _core.Options()
    o.method, o.tol = _core.Method.newton, 1e-8
    it = _core.SolveOptions()
    it.tol, it.maxiter = 1e-8, 200
    COMM.barrier()
    t0 = time.perf_counter()
    core = _petsc.Newton(M.handle, o, [P.handle for P in mats])
    r = core.solve(np.array(q[lo:hi]), _core.ZetaKind.constant, np.array(psi[lo:hi]), None, None, None, it)
    COMM.barrier()
    t_petsc = time.perf_counter() - t0
    if RANK == 0:
        t0 = time.perf_counter()
        s = nrmicp.solve(A, q, zeta=psi, method="newton", hierarchy=list(Ps), tol=1e-8, scale=None)
        t_serial = time.perf_counter() - t0
        print(f"2D obstacle n={n} np={SIZE}: serial {s.level_steps[0]} finest steps {t_serial:.2f} s ({s.inner}); "
              f"PETSc engine {r['newton'].level_steps[0]} finest steps {t_petsc:.2f} s ({core.inner}); "
              f"ratio {t_petsc / t_serial:.2f}; Res {s.residual:.2e} / {r['residual']:.2e}; levels {list(s.level_steps)} / {list(r['newton'].level_steps)}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 255)
