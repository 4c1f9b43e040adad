"""What this machine gives from np 1 to np 2 without nrmicp: PETSc and hypre alone on the 2D and 3D
Laplacians of benchmarks/distributed/bench.py (the same A and row blocks), beside which nrmicp.distributed's
own scaling is read (docs/DISTRIBUTED.md, "What was reached and what was not").

    python benchmarks/distributed/petsc_alone.py [--m2 1023] [--m3 99] [--ranks 1 2]

Per scene and rank count, CPU seconds of the slowest rank, min of 3 (OPENBLAS_NUM_THREADS=1):
  matmult  100 products A x (PETSc MatMult)
  setup    BoomerAMG's set-up with PETSc's PCHYPRE defaults (KSPSetUp of CG + PCHYPRE)
  solve    that CG + BoomerAMG solve of A x = 1 to rtol 1e-8
  whole    setup + solve of one repetition: one linear solve as a user pays it
and each one's ratio np 1 / np k. The load average is printed before and after (a shared machine).
"""
import argparse
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rows import petsc_rows  # noqa: E402

HERE = os.path.abspath(__file__)
PARTS = ("matmult", "setup", "solve")


def worker(dims: int, m: int) -> None:
    """The timings of one scene on this communicator; rank 0 prints one line 'RESULT part seconds ...'."""
    from petsc4py import PETSc
    from nrmicp import scenes
    comm = PETSc.COMM_WORLD
    pb = scenes.obstacle_2d(m, exact=False) if dims == 2 else scenes.obstacle_3d(m, exact=False)
    M, _, _ = petsc_rows(pb.A.tocsr(), comm)
    b, x = M.createVecLeft(), M.createVecRight()
    b.set(1.0)
    best = {}
    for _ in range(3):
        times = _once(PETSc, comm, M, b, x)
        times["whole"] = times["setup"] + times["solve"]
        for part, t in times.items():
            best[part] = min(best.get(part, float("inf")), _slowest(PETSc, comm, t))
    if comm.getRank() == 0:
        print("RESULT " + " ".join(f"{k} {v:.4f}" for k, v in best.items()), flush=True)


def _once(PETSc, comm, M, b, x) -> dict:
    """Each part's CPU seconds on this rank, once."""
    comm.barrier()
    t = time.process_time()
    for _ in range(100):
        M.mult(b, x)
    out = {"matmult": time.process_time() - t}
    ksp = PETSc.KSP().create(comm)
    ksp.setOperators(M)
    ksp.setType("cg")
    ksp.getPC().setType("hypre")
    ksp.getPC().setHYPREType("boomeramg")
    ksp.setTolerances(rtol=1e-8)
    comm.barrier()
    t = time.process_time()
    ksp.setUp()
    out["setup"] = time.process_time() - t
    x.set(0.0)
    t = time.process_time()
    ksp.solve(b, x)
    out["solve"] = time.process_time() - t
    ksp.destroy()
    return out


def _slowest(PETSc, comm, t: float) -> float:
    v = PETSc.Vec().createMPI((1, PETSc.DECIDE), comm=comm)
    v.setValue(v.getOwnershipRange()[0], t)
    v.assemble()
    out = v.max()[1]
    v.destroy()
    return out


def run(ranks: int, dims: int, m: int) -> dict:
    """One scene's parts under mpirun -n ranks."""
    cmd = ["mpirun", "-n", str(ranks), "--oversubscribe"] + (["--allow-run-as-root"] if os.geteuid() == 0 else [])
    cmd += ["-x", "OPENBLAS_NUM_THREADS", sys.executable, HERE, "--worker", str(dims), str(m)]
    out = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, OPENBLAS_NUM_THREADS="1"),
                         check=True).stdout
    line = next(ln for ln in out.splitlines() if ln.startswith("RESULT "))
    words = line.split()[1:]
    return {words[i]: float(words[i + 1]) for i in range(0, len(words), 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m2", type=int, default=1023)
    ap.add_argument("--m3", type=int, default=99)
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--worker", type=int, nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(*args.worker)
        return
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    print(f"{'scene':<14}{'ranks':>6}" + "".join(f"{p:>16}" for p in PARTS + ("whole",)))
    for dims, m in ((2, args.m2), (3, args.m3)):
        first = None
        for ranks in args.ranks:
            parts = run(ranks, dims, m)
            first = first or parts
            cells = "".join(f"{parts[p]:>8.3f} ({first[p] / parts[p]:.2f}x)" for p in PARTS + ("whole",))
            print(f"{f'{dims}D n={m ** dims:,}':<14}{ranks:>6}{cells}", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
