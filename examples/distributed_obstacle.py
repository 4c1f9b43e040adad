# mpirun -n 2 python examples/distributed_obstacle.py   (each rank builds and passes its own rows)
import numpy as np
from petsc4py import PETSc
from nrmicp import distributed
from nrmicp.scenes.obstacle import obstacle_2d

pb = obstacle_2d(127, exact=False)                      # membrane over a paraboloid, n = 16,129
comm = PETSc.COMM_WORLD
n, rank, size = pb.A.shape[0], comm.getRank(), comm.getSize()
lo, hi = rank * n // size, (rank + 1) * n // size      # this rank's rows
res = distributed.solve(pb.A.tocsr()[lo:hi], pb.q[lo:hi], zeta=pb.zeta[lo:hi], method="newton", tol=1e-8)
z = distributed.gather(res.z)                           # numpy on rank 0, None elsewhere
if rank == 0:
    print(res.status, "finest steps", res.nit, "per level", res.level_steps, f"Res {res.residual:.1e}",
          f"min(z - psi) {np.min(z - pb.zeta):.1e}", f"{res.timings['total']:.2f} s on {size} ranks")
