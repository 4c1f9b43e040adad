"""distributed.Solver against distributed.solve on a march of loads (each step's x0 the last answer):
the 3D obstacle scene (m³ unknowns), method 'newton', hierarchy 'amg' (BoomerAMG), the default stop;
wall seconds of the march, the slowest rank's CPU. One invocation, under mpirun:

    python benchmarks/distributed/march.py [--m 63] [--steps 5] [--ranks 1 2]

(docs/DISTRIBUTED.md, "A march with distributed.Solver").
"""
import argparse
import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rows import petsc_rows  # noqa: E402


def worker(m, steps):
    """Both marches; rank 0 prints RESULT json."""
    import scipy.sparse as sp
    from petsc4py import PETSc
    from nrmicp import distributed as dist
    from nrmicp.scenes.obstacle import obstacle_3d
    comm = PETSc.COMM_WORLD
    pb = obstacle_3d(m, exact=False)
    A, n = sp.csr_matrix(pb.A), pb.n
    rank, size = comm.getRank(), comm.getSize()
    M, lo, hi = petsc_rows(A, comm)
    psi = pb.zeta[lo:hi]

    def march(solve):
        comm.barrier()
        t0, c0, z, statuses = time.perf_counter(), time.process_time(), None, []
        for k in range(steps):
            r = solve(pb.q[lo:hi] - 2.0 * k, psi, x0=z)
            z = r.z.getArray().copy()
            statuses.append(r.status.name)
        return {"wall": time.perf_counter() - t0, "cpu": dist._flag_max(comm, time.process_time() - c0),
                "statuses": statuses}
    out = {"n": n, "ranks": size,
           "solve": march(lambda q, zeta, x0: dist.solve(M, q, zeta, x0=x0, method="newton", hierarchy="amg"))}
    with dist.Solver(M, method="newton", hierarchy="amg") as solver:
        out["Solver"] = march(solver.solve)
    if rank == 0:
        print("RESULT " + json.dumps(out), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--m", type=int, nargs="+", default=[63])
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--python", default=sys.executable)
    args = ap.parse_args()
    print("| n | ranks | steps | distributed.solve each step: wall / CPU s | one distributed.Solver: wall / CPU s | ratio (wall) |")
    print("|---|---|---|---|---|---|")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    for m in args.m:
        for np_ in args.ranks:
            cmd = ["mpirun", "-n", str(np_), "--oversubscribe"] + (["--allow-run-as-root"] if os.geteuid() == 0 else [])
            out = subprocess.run(cmd + [args.python, __file__, "--worker", str(m), str(args.steps)],
                                 capture_output=True, text=True, check=True, env=env).stdout
            d = json.loads([ln for ln in out.splitlines() if ln.startswith("RESULT ")][-1][7:])
            a, b = d["solve"], d["Solver"]
            assert set(a["statuses"]) == set(b["statuses"]) == {"CONVERGED"}, d
            print(f"| {d['n']:,} | {np_} | {args.steps} | {a['wall']:.2f} / {a['cpu']:.2f} | {b['wall']:.2f} / {b['cpu']:.2f} | "
                  f"{a['wall'] / b['wall']:.2f} |", flush=True)


if __name__ == "__main__":
    if len(sys.argv) > 3 and sys.argv[1] == "--worker":
        worker(int(sys.argv[2]), int(sys.argv[3]))
    else:
        main()
