"""nrmicp.distributed against PETSc's SNES VI (vinewtonrsls), one invocation for both sides.

    python benchmarks/distributed/bench.py [--m2 1023] [--m3 99] [--dims 2 3] [--fe P2:5] [--ranks 1 2]
                                           [--cold-max-n 300000] [--out rows.jsonl]

For each scene (2D obstacle m², 3D obstacle m³, and with --fe the finite-element obstacle
nrmicp.scenes.fe_obstacle(element, refinements): no grid, so no grid-sequencing peer) and each rank
count it runs, under mpirun:
  ours   nrmicp.distributed.solve(method='newton', hierarchy='amg'), tol 1e-8 (this file, --worker)
  cold   vinewtonrsls from u = 0, CG + hypre BoomerAMG (vi_gridseq.c without grid sequencing)
  gs     vinewtonrsls with DMDA grid sequencing (vi_gridseq.c, -snes_grid_sequence k; it needs a grid)
and prints wall seconds (of the solve, slowest rank), finest-level Newton steps and Res, and the
MPI messages / bytes per rank and Newton step of ours (PETSc's -log_view, stage 'solve').
With --out, each row's raw measurements are also written to that file (JSON lines, replaced).
The C peer is compiled here with mpicc against the PETSc of pkg-config.
"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rows import petsc_rows  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def mpirun(np_):
    cmd = ["mpirun", "-n", str(np_), "--oversubscribe"]
    if os.geteuid() == 0:
        cmd.append("--allow-run-as-root")
    return cmd


def _scene(dim, m):
    """(A, q, ψ) of a worker's scene: dim 2 or 3 (grids, m a side, rows in grid order) or an element
    'P1'/'P2' (fe_obstacle, m refinements) renumbered by reverse Cuthill–McKee, so that the ranks'
    contiguous row blocks are compact pieces of the mesh (what a user's partition gives; the mesh's
    own numbering, vertices before edge midpoints, spreads every block over the whole mesh)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import reverse_cuthill_mckee
    from nrmicp.scenes.finite_elements import fe_obstacle
    from nrmicp.scenes.obstacle import obstacle_2d, obstacle_3d
    if dim not in ("P1", "P2"):
        pb = (obstacle_2d if dim == "2" else obstacle_3d)(m, exact=False)
        return sp.csr_matrix(pb.A), pb.q, pb.zeta
    pb = fe_obstacle(dim, m, exact=False)
    A = sp.csr_matrix(pb.A)
    p = reverse_cuthill_mckee(A, symmetric_mode=True)
    A = A[p][:, p]
    A.sort_indices()
    return A, pb.q[p], pb.zeta[p]


def worker(dim, m, log):
    """One solve by nrmicp.distributed; rank 0 prints RESULT json."""
    import petsc4py
    petsc4py.init(["bench", "-log_view", f":{log}"])
    from petsc4py import PETSc
    from nrmicp import distributed as dist
    comm = PETSc.COMM_WORLD
    A, q_all, psi = _scene(dim, m)
    n = A.shape[0]
    rank, size = comm.getRank(), comm.getSize()
    M, lo, hi = petsc_rows(A, comm)
    q = M.createVecLeft()
    q.setArray(q_all[lo:hi])
    import time
    comm.barrier()
    stage = PETSc.Log.Stage("solve")
    stage.push()
    cpu = time.process_time()
    r = dist.solve(M, q, psi[lo:hi], method="newton", hierarchy="amg", tol=1e-8)
    cpu = dist._flag_max(comm, time.process_time() - cpu)  # the slowest rank's CPU seconds
    stage.pop()
    serial = None
    if size == 1:  # the same problem by serial nrmicp in the same process (the layer's overhead)
        import nrmicp
        t0, c0 = time.perf_counter(), time.process_time()
        rs = nrmicp.solve(A, q_all, psi, method="newton", tol=1e-8)
        serial = {"seconds": time.perf_counter() - t0, "cpu": time.process_time() - c0, "finest": rs.nit,
                  "status": str(rs.status), "res": rs.residual}
    if rank == 0:
        print("RESULT " + json.dumps({"n": n, "serial": serial, "cpu": cpu, "seconds": r.timings["total"], "setup": r.timings["setup"],
                                      "finest": r.nit, "level_steps": r.level_steps, "res": r.residual,
                                      "status": str(r.status), "linear_solves": r.linear_solves,
                                      "inner_iterations": r.inner_iterations}), flush=True)


def stage_messages(log, name="solve"):
    """(messages, bytes) summed over ranks in stage `name` of a -log_view file."""
    text = open(log).read()
    sec = text.split("Summary of Stages:")[1].split("\n\n")[0]
    for line in sec.splitlines():
        parts = line.split()
        if len(parts) > 10 and parts[1].rstrip(":") == name:
            # time, flop, message count (all ranks), mean message length (bytes), reductions; each with a %
            nums = [float(p) for p in parts[2:] if re.match(r"^[0-9.e+-]+$", p)]
            return nums[2], nums[3] * nums[2], nums[4]
    raise RuntimeError(f"stage {name} not in {log}")


def run_ours(py, dim, m, np_):
    with tempfile.TemporaryDirectory() as tmp:
        log = os.path.join(tmp, "log.txt")
        out = subprocess.run(mpirun(np_) + [py, __file__, "--worker", str(dim), str(m), log],
                             capture_output=True, text=True, check=True).stdout
        res = json.loads([ln for ln in out.splitlines() if ln.startswith("RESULT ")][-1][7:])
        msgs, nbytes, reductions = stage_messages(log)
    res.update(messages=msgs, bytes=nbytes, reductions=reductions)
    return res


def run_peer(exe, dim, m, np_, sequence):
    """vi_gridseq: m interior nodes per direction (M = m + 2 points), cold or with k refinements."""
    M, k = m + 2, 0
    if sequence:
        while (M - 1) % 2 == 0 and (M - 1) // 2 + 1 >= 9:
            M, k = (M - 1) // 2 + 1, k + 1
    args = [exe, "-dim", str(dim), "-M", str(M), "-snes_grid_sequence", str(k), "-ksp_type", "cg", "-pc_type", "hypre",
            "-snes_atol", "1e-8", "-snes_rtol", "1e-50", "-snes_stol", "1e-50", "-snes_max_it", "100000",
            "-ksp_rtol", "1e-6"]
    out = subprocess.run(mpirun(np_) + args, capture_output=True, text=True, check=True).stdout
    _, mx, its, secs, cpu, res = [ln for ln in out.splitlines() if ln.startswith("RESULT ")][-1].split()[1:]
    return {"seconds": float(secs), "cpu": float(cpu), "finest": int(its), "res": float(res), "levels": k + 1,
            "M": int(mx)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--m2", type=int, default=1023)
    ap.add_argument("--m3", type=int, default=99)
    ap.add_argument("--dims", type=int, nargs="*", default=[2, 3], choices=[2, 3])
    ap.add_argument("--fe", nargs="*", default=[], metavar="ELEMENT:REFINEMENTS",
                    help="finite-element obstacles, e.g. P2:5 (n = 523,265)")
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--cold-max-n", type=int, default=300_000, help="run the cold peer only up to this n")
    ap.add_argument("--python", default=sys.executable)
    ap.add_argument("--out", help="write each row's raw measurements here (JSON lines; the file is replaced)")
    a = ap.parse_args()
    exe = os.path.join(tempfile.mkdtemp(), "vi_gridseq")
    flags = subprocess.run(["pkg-config", "--cflags", "--libs", "PETSc"], capture_output=True, text=True,
                           check=True).stdout.split()
    subprocess.run(["mpicc", "-O2", "-o", exe, os.path.join(HERE, "vi_gridseq.c")] + flags, check=True)
    rows = []
    out = open(a.out, "w") if a.out else None
    scenes = [(str(d), a.m2 if d == 2 else a.m3) for d in a.dims] + [(e, int(r)) for e, r in (f.split(":") for f in a.fe)]
    for dim, m in scenes:
        grid = dim in ("2", "3")
        for np_ in a.ranks:
            ours = run_ours(a.python, dim, m, np_)
            name = f"obstacle_{dim}d m={m}" if grid else f"fe_obstacle {dim} r={m}"
            row = {"scene": name, "n": ours["n"], "np": np_, "ours": ours,
                   "gs": run_peer(exe, int(dim), m, np_, True) if grid else None}
            row["cold"] = run_peer(exe, int(dim), m, np_, False) if grid and row["n"] <= a.cold_max_n else None
            rows.append(row)
            print(f"done: {row['scene']}, np {np_}", file=sys.stderr, flush=True)
            if out:   # row by row: partial results survive
                print(json.dumps(row), file=out, flush=True)
    if out:
        out.close()
    print("\nfinest steps, CPU s (slowest rank), wall s")
    print("\n| scene | n | np | serial nrmicp newton | ours (nrmicp.distributed) | vinewtonrsls cold | vinewtonrsls + grid sequencing |"
          " msgs/rank/step | bytes/rank/step | reductions/step |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        o, c, g = r["ours"], r["cold"], r["gs"]
        steps = sum(o["level_steps"])
        cold = f"{c['finest']}, {c['cpu']:.2f}, {c['seconds']:.2f}" if c else "not run (n > --cold-max-n)" if g else "no grid"
        gs = f"{g['finest']}, {g['cpu']:.2f}, {g['seconds']:.2f}" if g else "no grid"
        se = o["serial"]
        serial = f"{se['finest']}, {se['cpu']:.2f}, {se['seconds']:.2f}" if se else "–"
        print(f"| {r['scene']} | {r['n']:,} | {r['np']} | {serial} | {o['finest']}, {o['cpu']:.2f}, {o['seconds']:.2f} | {cold} | "
              f"{gs} | {o['messages'] / r['np'] / steps:.0f} | "
              f"{o['bytes'] / r['np'] / steps:.3g} | {o['reductions'] / steps:.0f} |")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        worker(sys.argv[2], int(sys.argv[3]), sys.argv[4])
    else:
        main()
