"""A QVI on the PETSc engine: ζ = ψ + 0.2 sin z on the 2D obstacle scene (m² unknowns), method 'newton',
hierarchy 'amg' (BoomerAMG distributed, pyamg serially), tol 1e-8; with ζ′ = diag(0.2 cos z) as a
LinearOperator of each rank's rows (semismooth Newton on the whole ICP) and without it (the outer fixed
point); serial nrmicp on the same problem in the np = 1 process. One invocation, under mpirun:

    python benchmarks/distributed/qvi.py [--m 511 1023] [--ranks 1 2]

Prints per size and rank count: calls of ζ′, outer steps, linear solves, status, wall and CPU seconds of
the solve (the slowest rank's CPU); docs/DISTRIBUTED.md, "A QVI with ζ′ on the PETSc engine".
"""
import argparse
import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rows import petsc_rows  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def _solve(solve, A, q, zeta, jacobian):
    """(result, wall s, CPU s, calls of ζ′)."""
    calls = []
    extra = {} if jacobian is None else {"zeta_jacobian": lambda z: calls.append(1) or jacobian(z)}
    t0, c0 = time.perf_counter(), time.process_time()
    r = solve(A, q, zeta, method="newton", hierarchy="amg", tol=1e-8, **extra)
    return r, time.perf_counter() - t0, time.process_time() - c0, len(calls)


def _row(r, wall, cpu, calls):
    return {"calls": calls, "outer": int(r.outer_iterations), "solves": int(r.linear_solves), "status": r.status.name,
            "res": float(r.residual), "wall": wall, "cpu": cpu}


def worker(m):
    """Both solves by nrmicp.distributed (and serially on one rank); rank 0 prints RESULT json."""
    import numpy as np
    import scipy.sparse as sp
    from scipy.sparse.linalg import LinearOperator
    from petsc4py import PETSc
    import nrmicp
    from nrmicp import distributed as dist
    from nrmicp.scenes.obstacle import obstacle_2d
    comm = PETSc.COMM_WORLD
    pb = obstacle_2d(m, exact=False)
    A, n = sp.csr_matrix(pb.A), pb.n
    rank, size = comm.getRank(), comm.getSize()
    M, lo, hi = petsc_rows(A, comm)
    psi = np.asarray(pb.zeta, dtype=float)

    def problem(lo, hi):
        p = psi[lo:hi]

        def jacobian(z):
            d = 0.2 * np.cos(z)
            return LinearOperator((hi - lo, hi - lo), matvec=lambda v: d * np.ravel(v), dtype=float)
        return (lambda z: p + 0.2 * np.sin(z)), jacobian

    zeta, jacobian = problem(lo, hi)
    out = {"n": n, "ranks": size}
    for name, jac in (("with", jacobian), ("without", None)):
        comm.barrier()
        r, wall, cpu, calls = _solve(dist.solve, M, pb.q[lo:hi], zeta, jac)
        row = _row(r, wall, cpu, calls)
        row["cpu"] = dist._flag_max(comm, cpu)   # the slowest rank's
        out[name] = row
    if size == 1:
        zeta, jacobian = problem(0, n)
        for name, jac in (("serial with", jacobian), ("serial without", None)):
            out[name] = _row(*_solve(nrmicp.solve, A, pb.q, zeta, jac))
    if rank == 0:
        print("RESULT " + json.dumps(out), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--m", type=int, nargs="+", default=[511, 1023], help="grid sides (n = m^2)")
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--python", default=sys.executable)
    args = ap.parse_args()
    print("| n | ranks | ζ′: calls / linear solves | ζ′: status | ζ′: wall / CPU s | no ζ′: outer steps / linear solves "
          "| no ζ′: status | no ζ′: wall / CPU s |")
    print("|---|---|---|---|---|---|---|---|")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    for m in args.m:
        for np_ in args.ranks:
            cmd = ["mpirun", "-n", str(np_), "--oversubscribe"] + (["--allow-run-as-root"] if os.geteuid() == 0 else [])
            out = subprocess.run(cmd + [args.python, __file__, "--worker", str(m)], capture_output=True, text=True,
                                 check=True, env=env).stdout
            d = json.loads([ln for ln in out.splitlines() if ln.startswith("RESULT ")][-1][7:])
            rows = [("serial", d["serial with"], d["serial without"])] if np_ == 1 else []
            rows.append((str(np_), d["with"], d["without"]))
            for label, w, o in rows:
                print(f"| {d['n']:,} | {label} | {w['calls']} / {w['solves']} | {w['status']}, {w['res']:.1e} | "
                      f"{w['wall']:.2f} / {w['cpu']:.2f} | {o['outer']} / {o['solves']} | {o['status']}, {o['res']:.1e} | "
                      f"{o['wall']:.2f} / {o['cpu']:.2f} |", flush=True)


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--worker":
        worker(int(sys.argv[2]))
    else:
        main()
