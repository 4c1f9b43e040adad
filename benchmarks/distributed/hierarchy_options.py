"""Which nesting hierarchy for nrmicp.distributed's Newton member (hierarchy='amg'): BoomerAMG / GAMG
options against finest steps, the hierarchy's set-up, total CPU and operator complexity, per scene and
rank count, one invocation for all (compare rows of one run only: the machine is shared).

    python benchmarks/distributed/hierarchy_options.py [--scenes 2d 3d p1 p2] [--ranks 1 2]
        [--configs NAME ...] [--python MPI_PYTHON] [--before PYTHONPATH] [--out rows.jsonl]

Each config is a set of PETSc options given as the user gives them (-nrmicp_hierarchy_...: with any, the
hierarchy is one set-up with them); 'rule' is what the build does with none, 'before' (with --before) the
rule of another build. The hierarchy's set-up is timed alone (outside the solve's CPU where the core
builds it, inside where an older build's Python did); complexity: its coarse operators' nonzeros over A's. The scenes (2D / 3D obstacle, P1 / P2
finite-element obstacle, n about 10⁶ / 10⁶ / 5·10⁵ / 5·10⁵) are built once into a temporary folder.
np 1 rows also run serial nrmicp.solve(method='newton') in the same process.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.abspath(__file__)
SCENES = {"2d": ("obstacle_2d", 1023), "3d": ("obstacle_3d", 99), "p1": ("P1", 6), "p2": ("P2", 5)}
_B = "pc_hypre_boomeramg_"
CONFIGS = {
    "rule": {},   # the build's own rule (with --before: the rule of the build given there, as "before")
    "classical": {_B + "agg_nl": 0},   # (any option under the prefix: one set-up with the user's options)
    "classical_truncfactor0.2": {_B + "truncfactor": 0.2},
    "hmis_exti_pmax4": {_B + "coarsen_type": "HMIS", _B + "interp_type": "ext+i", _B + "P_max": 4},
    "pmis_exti_pmax4": {_B + "coarsen_type": "PMIS", _B + "interp_type": "ext+i", _B + "P_max": 4},
    "hmis_exti_pmax4_agg": {_B + "coarsen_type": "HMIS", _B + "interp_type": "ext+i", _B + "P_max": 4,
                            _B + "agg_nl": 1, _B + "agg_num_paths": 2},
    "gamg": {"pc_type": "gamg"},
}


def scene(name, folder):
    """(A, q, psi) of a scene, built once into `folder` (npz)."""
    import numpy as np
    import scipy.sparse as sp
    path = os.path.join(folder, f"{name}.npz")
    if not os.path.exists(path):
        kind, size = SCENES[name]
        if kind.startswith("obstacle"):
            from nrmicp.scenes import obstacle
            pb = getattr(obstacle, kind)(size, exact=False)
        else:
            from nrmicp.scenes.finite_elements import fe_obstacle
            pb = fe_obstacle(kind, size, exact=False)
        A = sp.csr_matrix(pb.A)
        np.savez(path, indptr=A.indptr, indices=A.indices, data=A.data, q=pb.q, psi=np.asarray(pb.zeta, dtype=float))
    d = np.load(path)
    n = len(d["q"])
    return sp.csr_matrix((d["data"], d["indices"], d["indptr"]), shape=(n, n)), d["q"], d["psi"]


def worker(name, config, folder):
    """One distributed solve (and at np 1 the serial one); rank 0 prints RESULT json."""
    import petsc4py
    petsc4py.init([])
    from petsc4py import PETSc
    from nrmicp import distributed as dist
    A, q, psi = scene(name, folder)
    comm = PETSc.COMM_WORLD
    rank, size = comm.getRank(), comm.getSize()
    n = A.shape[0]
    lo, hi = rank * n // size, (rank + 1) * n // size
    B = A[lo:hi]
    M = PETSc.Mat().createAIJ(size=((hi - lo, PETSc.DECIDE), (hi - lo, PETSc.DECIDE)),
                              csr=(B.indptr.astype(PETSc.IntType), B.indices.astype(PETSc.IntType), B.data), comm=comm)
    opts = PETSc.Options("nrmicp_hierarchy_")
    for k, v in CONFIGS[config].items():
        opts[k] = v
    probe = {}
    if hasattr(dist, "_prolongations"):   # a build whose hierarchy is Python's: timed around its set-up
        built = dist._prolongations

        def timed(Am, hierarchy, c):
            t = time.process_time()
            Ps, As, keep = built(Am, hierarchy, c)
            probe["hierarchy_setup"] = dist._flag_max(c, time.process_time() - t)
            nz = lambda X: X.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"]  # noqa: E731
            probe["complexity"] = sum(nz(C) for C in As) / nz(Am)
            return Ps, As, keep
        dist._prolongations = timed
    else:   # the core's: one more set-up, timed alone (outside the solve's CPU)
        from nrmicp import _petsc
        t = time.process_time()
        levels = _petsc.amg_levels(M.handle)
        probe["hierarchy_setup"] = dist._flag_max(comm, time.process_time() - t)
        probe["complexity"] = sum(levels["nonzeros"]) / A.nnz
    comm.barrier()
    cpu = time.process_time()
    r = dist.solve(M, q[lo:hi], psi[lo:hi], method="newton", hierarchy="amg", tol=1e-8)
    cpu = dist._flag_max(comm, time.process_time() - cpu)
    out = {"scene": name, "n": n, "np": size, "config": config, "finest": r.nit, "levels": len(r.level_steps),
           "level_steps": r.level_steps, "cpu": cpu, "seconds": r.timings["total"], "res": r.residual,
           "status": str(r.status), "inner": r.inner, **probe}
    out.update({k: r.hierarchy[k] for k in ("hierarchy_setup", "complexity") if k in r.hierarchy})
    out["setup"] = r.timings["setup"]
    if size == 1 and config == "rule":
        import nrmicp
        c0 = time.process_time()
        rs = nrmicp.solve(A, q, psi, method="newton", tol=1e-8)
        out["serial"] = {"cpu": time.process_time() - c0, "finest": rs.nit, "setup": rs.timings["setup"],
                         "status": str(rs.status)}
    if rank == 0:
        print("RESULT " + json.dumps(out, default=str), flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    ap.add_argument("--ranks", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--python", default=sys.executable)
    ap.add_argument("--folder", default=os.path.join(tempfile.gettempdir(), "nrmicp_hierarchy_scenes"))
    ap.add_argument("--out")
    ap.add_argument("--before", help="PYTHONPATH of another build: its rule is run too, as config 'before'")
    a = ap.parse_args()
    os.makedirs(a.folder, exist_ok=True)
    out = open(a.out, "a") if a.out else None
    print("| scene | np | config | finest steps (levels) | hierarchy set-up s | total CPU s | complexity | inner |")
    print("|---|---|---|---|---|---|---|---|")
    for name in a.scenes:
        for np_ in a.ranks:
            for config in (["before"] if a.before else []) + a.configs:
                path = a.before if config == "before" else os.environ.get("PYTHONPATH", "")
                cmd = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", str(np_), a.python, HERE, "--worker",
                       name, "rule" if config == "before" else config, a.folder]
                env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": path}
                p = subprocess.run(cmd, capture_output=True, text=True, env=env)
                lines = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
                if not lines:
                    print(f"| {name} | {np_} | {config} | failed: {p.stderr.strip().splitlines()[-1:]} |", flush=True)
                    continue
                r = dict(json.loads(lines[-1][7:]), config=config)
                if out:
                    print(json.dumps(r), file=out, flush=True)
                s = r.get("serial")
                print(f"| {name} | {np_} | {config} | {r['finest']} ({r['levels']}) | {r.get('hierarchy_setup', float('nan')):.2f} | "
                      f"{r['cpu']:.2f} | {r.get('complexity', float('nan')):.2f} | {r['inner']} |"
                      + (f" serial: {s['finest']} steps, {s['cpu']:.2f} s" if s else ""), flush=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        worker(*sys.argv[2:5])
    else:
        main()
