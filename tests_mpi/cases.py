"""The MPI side of the distributed tests: run as ``mpirun -n P python cases.py CASE``; rank 0
prints one JSON line (every rank's outcome where the case is about agreement between ranks).
The serial answers come from nrmicp itself on rank 0 (single process); the checks of Res use
the plain numpy oracle of tests/reference_impl.py."""
import json
import os
import sys

import numpy as np
import scipy.sparse as sp
from petsc4py import PETSc

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
import nrmicp  # noqa: E402
from nrmicp import distributed as dist  # noqa: E402
from nrmicp.scenes.convection import convection_diffusion_obstacle  # noqa: E402
from nrmicp.scenes.obstacle import obstacle_2d, obstacle_3d  # noqa: E402
from problems import make_affine_icp, make_icp, make_lcp, make_obstacle_icp  # noqa: E402
from reference_impl import residual as oracle_residual  # noqa: E402
from nrmicp._mpi import flag_max as _flag_max  # noqa: E402

COMM = PETSc.COMM_WORLD
RANK, SIZE = COMM.getRank(), COMM.getSize()


def _kzr(f):
    """f(k, z, res) as nrmicp.solve's callback (scipy's rule: one parameter named intermediate_result)."""
    def callback(intermediate_result):
        return f(intermediate_result.nit, intermediate_result.z, intermediate_result.residual)
    return callback


def split(n, weights=None):
    """Row ranges of the ranks: even, or proportional to weights."""
    w = np.ones(SIZE) if weights is None else np.asarray(weights[:SIZE], dtype=float)
    cuts = np.concatenate([[0], np.round(np.cumsum(w) / w.sum() * n)]).astype(int)
    return int(cuts[RANK]), int(cuts[RANK + 1])


def mat(A, lo, hi):
    """A's rows lo:hi as this rank's block of an MPIAIJ Mat."""
    B = sp.csr_matrix(A[lo:hi])
    B.sort_indices()
    M = PETSc.Mat().createAIJ(size=((hi - lo, PETSc.DECIDE), (hi - lo, PETSc.DECIDE)),
                              csr=(B.indptr.astype(PETSc.IntType), B.indices.astype(PETSc.IntType), B.data),
                              comm=COMM)
    return M


def vec(M, arr):
    v = M.createVecLeft()
    lo, hi = v.getOwnershipRange()
    v.setArray(np.asarray(arr, dtype=float)[lo:hi])
    return v


def problems():
    """(name, A, q, serial zeta, distributed-zeta maker)."""
    out = []
    for name, pb in (("obstacle_2d", obstacle_2d(31, exact=False)), ("obstacle_3d", obstacle_3d(9, exact=False)),
                     ("convection", convection_diffusion_obstacle(31, exact=False))):
        A = sp.csr_matrix(pb.A)
        out.append((name, A, pb.q, pb.zeta, lambda M, lo, hi, c=pb.zeta: c[lo:hi]))
    lcp = make_lcp(16)
    out.append(("lcp", sp.csr_matrix(lcp.A), lcp.q, None, lambda M, lo, hi: None))
    aff = make_affine_icp(16, symmetric=False)
    B, c = sp.csr_matrix(aff.zeta.B), aff.zeta.c
    out.append(("affine", sp.csr_matrix(aff.A), aff.q, nrmicp.Affine(B, c),
                lambda M, lo, hi: nrmicp.Affine(mat(B, lo, hi), c[lo:hi])))
    icp = make_icp(16, c=0.1)
    s = icp.zeta(np.zeros(icp.A.shape[0]))  # zeta(z) = 0.1 sin(z) + s, entry-wise: each rank evaluates its rows
    out.append(("icp_callable", sp.csr_matrix(icp.A), icp.q, icp.zeta,
                lambda M, lo, hi: (lambda z, s=s[lo:hi]: 0.1 * np.sin(z) + s)))
    return out


SERIAL_METHOD = {"newton": "newton", "nrmj": "nrmj", "nrmgs": "nrmgs", "nrmsor": "nrmsor", "nrmaor": "nrmaor"}
OPTIONS = {"newton": {"hierarchy": "amg"}, "nrmj": {}, "nrmgs": {}, "nrmsor": {"alpha": 1.2}, "nrmaor": {"alpha": 1.1, "beta": 0.9}}


def case_agreement(weights=None):
    """Every member on every problem: max |z - z_serial|, Res by the oracle, status, steps."""
    rows = []
    for name, A, q, zeta, dzeta in problems():
        n = A.shape[0]
        lo, hi = split(n, weights)
        M = mat(A, lo, hi)
        serial = nrmicp.solve(A, q, zeta, method="newton", tol=1e-11, polish=True)
        oracle_zeta = None if zeta is None else (zeta if callable(zeta) else (lambda z, c=zeta: c))
        for method, kw in OPTIONS.items():
            tol = 1e-9 if method == "newton" else 1e-10
            qv, zv = vec(M, q), dzeta(M, lo, hi)
            before = _snapshot(M, qv, zv)
            r = dist.solve(M, qv, zv, method=method, tol=tol, maxiter=100000, **kw)
            untouched = _snapshot(M, qv, zv) == before
            z = dist.gather(r.z)
            if RANK == 0:
                rows.append({"problem": name, "method": method, "status": str(r.status), "nit": r.nit,
                             "err": float(np.max(np.abs(z - serial.z))), "res": oracle_residual(A, q, z, oracle_zeta),
                             "level_steps": r.get("level_steps"), "serial_res": float(serial.residual),
                             "untouched": untouched})
    return rows


def case_partition():
    """One problem, two partitions (even and 1:3:2): the answers agree."""
    out = {}
    for weights in (None, [1, 3, 2]):
        pb = obstacle_2d(31, exact=False)
        A = sp.csr_matrix(pb.A)
        lo, hi = split(A.shape[0], weights)
        zs = {}
        for method in ("newton", "nrmgs"):
            r = dist.solve(A[lo:hi], pb.q[lo:hi], pb.zeta[lo:hi], method=method, tol=1e-10 if method != "newton" else 1e-9,
                           maxiter=100000)
            zs[method] = dist.gather(r.z)
        out[str(weights)] = zs
    # a P-matrix where the active-set steps cycle: the fallback sweeps take over, as in the serial member
    from nrmicp.scenes.p_matrix import p_matrix_cycling
    pm = p_matrix_cycling(3)
    A = sp.csr_matrix(pm.A)
    lo, hi = split(A.shape[0])
    r = dist.solve(A[lo:hi], pm.q[lo:hi], None, hierarchy=None, tol=1e-10)
    z = dist.gather(r.z)
    if RANK == 0:
        serial = nrmicp.solve(A, pm.q, None, method="newton", tol=1e-10)
        out = {m: float(np.max(np.abs(out["None"][m] - out["[1, 3, 2]"][m]))) for m in ("newton", "nrmgs")}
        out["fallback"] = {"status": str(r.status), "path": r.path, "sweeps": r.fallback_sweeps,
                           "err": float(np.max(np.abs(z - serial.z))), "serial_path": serial.path}
        return out


def _bad(kind):
    """The inputs of one bad-input case, bad on the last rank only where that makes sense."""
    pb = obstacle_2d(15, exact=False)
    A = sp.csr_matrix(pb.A)
    n = A.shape[0]
    lo, hi = split(n)
    last = RANK == SIZE - 1
    M = mat(A, lo, hi)
    q = vec(M, pb.q)
    zeta = pb.zeta[lo:hi]
    kw = {}
    if kind == "layout":
        sizes = [n // SIZE + (1 if RANK == 0 else -1 if RANK == 1 else 0)] if SIZE > 1 else [n - 1]
        q = PETSc.Vec().createMPI((sizes[0], PETSc.DECIDE), comm=COMM)
        q.set(0.0)
    elif kind == "nonsquare":
        return A[lo:hi, :n - 1] if last else A[lo:hi], pb.q[lo:hi], zeta, kw
    elif kind == "zero_diagonal":   # (a stored zero: lil's assignment of 0 would drop the entry)
        D = A.copy()
        D.data[(D.indices == n - 1) & (np.arange(D.nnz) >= D.indptr[n - 1])] = 0.0
        return mat(D, lo, hi), q, zeta, kw
    elif kind in ("complex_A", "corrupt_A"):   # the last rank's scipy row block: complex / an index past n
        B = A[lo:hi].astype(complex) * (1 + 1j) if kind == "complex_A" else A[lo:hi].copy()
        if kind == "corrupt_A":
            B.indices[-1] = n + 5
        return B if last else A[lo:hi], pb.q[lo:hi], zeta, kw
    elif kind == "mixed_kinds":   # a scipy row block on the last rank, Mats elsewhere, one comm given (hung before;
        # without comm= each rank's default differs: A's own communicator against COMM_WORLD)
        return A[lo:hi] if last else M, pb.q[lo:hi], zeta, {"comm": COMM}
    elif kind == "nonfinite_A":   # the last rank's block holds a NaN in its first row
        B = sp.csr_matrix(A[lo:hi], copy=True)
        if last:
            B.data[0] = np.nan
        return B, pb.q[lo:hi], zeta, kw
    elif kind == "mat_as_zeta":   # a bare Mat (callable in petsc4py) where nrmicp.Affine(B, c) was meant
        return M, q, mat(A * 0.01, lo, hi), kw
    elif kind == "inf_in_A":   # an inf off the diagonal in the last rank's rows of a Mat (hung before: one rank raised)
        B = A.copy()
        if last:
            B.data[B.indptr[hi - 1]] = np.inf
        return mat(B, lo, hi), q, zeta, kw
    elif kind == "sbaij_A":   # a symmetric block Mat: not AIJ (nrmgs split its upper triangle only)
        return M.convert("sbaij"), q, zeta, kw
    elif kind == "callback_not_callable":
        kw = {"callback": 5}
    elif kind == "dense_A":   # a dense Mat: the engine reads AIJ rows
        return M.convert("dense"), q, zeta, kw
    elif kind == "layout_A":   # A's columns split unlike its rows (one more column on rank 0, one fewer on rank 1)
        cols = (hi - lo) + (1 if RANK == 0 else -1 if RANK == 1 else 0) if SIZE > 1 else hi - lo
        B = A[lo:hi]
        return PETSc.Mat().createAIJ(size=((hi - lo, n), (cols, n)), comm=COMM, csr=(
            B.indptr.astype(PETSc.IntType), B.indices.astype(PETSc.IntType), B.data)), pb.q[lo:hi], zeta, kw
    elif kind == "B_columns":   # zeta.B with A's rows but another column layout (one more column on rank 0)
        cols = [(hi - lo) + (1 if RANK == 0 else -1 if RANK == 1 else 0)] if SIZE > 1 else [hi - lo]
        B = PETSc.Mat().createAIJ(size=((hi - lo, n), (cols[0], n)), comm=COMM)
        B.setUp()
        B.assemble()
        return M, q, nrmicp.Affine(B, zeta), kw
    elif kind == "subnormal_diagonal":
        D = A.copy()
        D.data[(D.indices == n - 1) & (np.arange(D.nnz) >= D.indptr[n - 1])] = 5e-324
        return mat(D, lo, hi), q, zeta, kw
    elif kind == "nan_q":
        qa = pb.q[lo:hi].copy()
        if last:
            qa[-1] = np.nan
        return M, qa, zeta, kw
    elif kind == "zeta_raises":
        def zeta(z):
            if last:
                raise RuntimeError("zeta failed here")
            return np.zeros_like(z)
    elif kind == "callback_raises":   # the user's callback fails on the last rank in its second call
        def callback(intermediate_result):   # (nrmicp.solve's callbacks, as serially)
            if last and intermediate_result.nit >= 2:
                raise RuntimeError("callback failed here")
        kw = {"callback": callback}
    elif kind == "zeta_nan":
        def zeta(z):
            return np.full_like(z, np.nan if last else 0.0)
    elif kind == "bad_option":
        kw = {"tol": -1.0}
    elif kind == "crossing_bounds":   # upper below the obstacle on the last rank's last row
        upper = pb.zeta[lo:hi] + 1.0
        if last:
            upper[-1] = pb.zeta[hi - 1] - 1.0
        kw = {"upper": upper}
    elif kind == "z_update_solve":   # the core's refusal at set-up (the engine has no factorization of A)
        kw = {"z_update": "solve"}
    elif kind == "mms_icp":   # ... and during the solve: 'auto' is 'solve' for mms on an ICP
        kw = {"method": "mms"}
        def zeta(z):
            return 0.01 * np.sin(z)
    elif kind == "bad_method":
        kw = {"method": "sor"}
    elif kind == "q_length_affine":   # q one entry too long on the last rank beside an Affine ζ: ζ's product,
        # collective (PETSc Vecs), is made only after every rank's checks passed (hung when made among them)
        qa = np.append(pb.q[lo:hi], 0.0) if last else pb.q[lo:hi]
        return M, qa, nrmicp.Affine(mat(A * 0.01, lo, hi), zeta), kw
    elif kind == "array_hierarchy":   # (an array is no hierarchy: named, not numpy's ambiguous truth value)
        kw = {"hierarchy": np.eye(3)}
    return M, q, zeta, kw


def case_bad(kind, method):
    """Every rank's exception (type, message), and whether the inputs were left as they were."""
    A, q, zeta, kw = _bad(kind)
    before = _snapshot(A, q, zeta)
    try:
        dist.solve(A, q, zeta, **{"method": method, "tol": 1e-8, "maxiter": 200, **kw})
        outcome = ["no exception", ""]
    except Exception as exc:  # noqa: BLE001 - the outcome is the test's subject
        outcome = [type(exc).__name__, str(exc)]
    same = _snapshot(A, q, zeta) == before
    outcomes = _allgather_text(json.dumps(outcome + [same]))
    if RANK == 0:
        return [json.loads(t) for t in outcomes]


def case_no_rows():
    """A whose last rank owns no rows: Newton refuses it on every rank (its driver decides per rank's rows;
    before, a hang or a false error), the stationary members solve it (each rank's exception or status)."""
    pb = obstacle_2d(15, exact=False)
    A = sp.csr_matrix(pb.A)
    n = A.shape[0]
    lo, hi = (n, n) if RANK == SIZE - 1 else split(n, [1] * (SIZE - 1) + [0])
    M = mat(A, lo, hi)
    q = vec(M, pb.q)
    out = {}
    # nrm factorizes each rank's block (none here: an empty one), and with omega2 given on an ICP its z_update
    # 'auto' is 'explicit' on every rank (the rank without rows holds an empty omega2: it resolved 'solve', a hang)
    icp = (lambda z, psi=pb.zeta[lo:hi]: psi + 0.1 * np.sin(z))
    # (nrmgs_default: the default rule, whose Res_E a rank without rows weighs with an empty D: it skipped the
    # measure's reduction, a hang)
    for method, zeta in (("newton", pb.zeta[lo:hi]), ("newton_amg", pb.zeta[lo:hi]), ("nrmgs", pb.zeta[lo:hi]),
                         ("nrmgs_default", pb.zeta[lo:hi]), ("nrm_omega2", pb.zeta[lo:hi]), ("nrm_omega2_icp", icp)):
        try:
            extra = {"hierarchy": "amg"} if method == "newton_amg" else {"omega2": float(A[0, 0])} if "omega2" in method else {}
            extra.update({} if method == "nrmgs_default" else {"tol": 1e-8})
            r = dist.solve(M, q, zeta, method=method.split("_")[0], maxiter=20000, **extra)
            z = dist.gather(r.z)   # (rank 0's; the error there)
            ref = nrmicp.solve(A, pb.q, (lambda z: pb.zeta + 0.1 * np.sin(z)) if method.endswith("icp") else pb.zeta,
                               method="newton", tol=1e-10).z
            outcome = [str(r.status), float(np.max(np.abs(z - ref))) if RANK == 0 else 0.0]
        except Exception as exc:  # noqa: BLE001 - the outcome is the test's subject
            outcome = [type(exc).__name__, str(exc)]
        got = _allgather_text(json.dumps(outcome))
        out[method] = [json.loads(t) for t in got] if RANK == 0 else None
    # a stationary solve that does not converge asks A's dominance margin for its advice, and method='auto'
    # for its choice: a reduction every rank takes part in (the rank without rows skipped a collective: a hang)
    for method, extra in (("nrmgs_short", {"maxiter": 5}), ("auto", {})):
        try:
            r = dist.solve(M, q, pb.zeta[lo:hi], method=method.split("_")[0], tol=1e-8, **extra)
            outcome = [str(r.status), "stationary members need" in r.message]
        except Exception as exc:  # noqa: BLE001 - the outcome is the test's subject
            outcome = [type(exc).__name__, str(exc)]
        got = _allgather_text(json.dumps(outcome))
        out[method] = [json.loads(t) for t in got] if RANK == 0 else None
    return out


def _snapshot(*objs):
    out = []
    for o in objs:
        if isinstance(o, PETSc.Mat) and "baij" in o.getType():
            out.append(o.getSize())
        elif isinstance(o, PETSc.Mat) and "dense" in o.getType():
            out.append(o.getDenseArray().tolist())
        elif isinstance(o, PETSc.Mat):
            out.append([a.tolist() for a in o.getValuesCSR()])
        elif isinstance(o, PETSc.Vec):
            out.append(o.getArray().tolist())
        elif sp.issparse(o):   # (its arrays: a corrupt one has no toarray)
            out.append([str(a.tolist()) for a in (o.data, o.indices, o.indptr)])
        elif isinstance(o, np.ndarray):
            out.append(np.nan_to_num(o, nan=1e300).tolist())
        elif isinstance(o, nrmicp.Affine):
            out.append(_snapshot(o.B, np.asarray(o.c)))
    return out


def _allgather_text(text, width=4096):
    """Each rank's text on rank 0 (through a PETSc scatter: no mpi4py needed)."""
    buf = np.zeros(width)
    raw = text.encode()[:width]
    buf[:len(raw)] = np.frombuffer(raw, dtype=np.uint8)
    v = PETSc.Vec().createMPI((width, PETSc.DECIDE), comm=COMM)
    v.setArray(buf)
    full = dist.gather(v)
    if RANK == 0:
        rows = full.reshape(SIZE, width)
        return [bytes(r[r > 0].astype(np.uint8)).decode() for r in rows]


#: The fuzz's stationary members beyond OPTIONS (nrm with Omega2 = diag(A), "diag": its Omega2 = I does not
#: converge as a multisplitting where diag(A) is far from 1).
MORE_MEMBERS = {"nrm": {"omega2": "diag"}, "nrmm": {}, "mms": {}, "two_sweep": {}}


def _fuzz_options(extra, method, A, lo, hi):
    """The member's options, and for the stationary members some of the serial loop's drawn by `extra`
    (Anderson, phi, theta, the history, the stall window); this rank's rows of a diagonal."""
    kw = dict({**OPTIONS, **MORE_MEMBERS}[method])
    if kw.get("omega2") == "diag":
        kw["omega2"] = A.diagonal()[lo:hi]
    if method == "newton":
        return kw
    if extra.random() < 0.3:
        kw.update(accelerate="anderson", anderson_m=int(extra.integers(1, 6)))
    if extra.random() < 0.2 and method not in ("mms", "two_sweep"):
        kw["phi"] = float(extra.uniform(0.0, 1.0))
    if method == "two_sweep" and extra.random() < 0.5:
        kw["theta"] = float(extra.uniform(0.7, 1.0))
    kw.update(record_history=bool(extra.random() < 0.5), stall_iterations=int(extra.integers(50, 200)))
    return kw


def _aggregation(rng, n):
    """Random valid prolongations P_l (n_l x n_{l+1}, n_{l+1} < n_l): each coarse unknown aggregates
    fine ones with positive weights."""
    Ps, rows = [], n
    while rows > 2 and rng.random() < 0.7:
        cols = int(rng.integers(1, rows))
        agg = np.r_[np.arange(cols), rng.integers(0, cols, rows - cols)]
        rng.shuffle(agg)
        Ps.append(sp.csr_matrix((rng.uniform(0.5, 1.5, rows), (np.arange(rows), agg)), shape=(rows, cols)))
        rows = cols
    return Ps


def _fuzz_jacobian(form):
    """ζ′ of ψ + 0.1 sin z on this rank's rows: a LinearOperator or a sparse diagonal."""
    from scipy.sparse.linalg import LinearOperator

    def jacobian(z):
        d = 0.1 * np.cos(z)
        if form == "diagonal":
            return sp.diags(d)
        return LinearOperator((len(z), len(z)), matvec=lambda v: d * np.ravel(v), dtype=float)
    return jacobian


def case_fuzz(examples):
    """Random small problems (np = 2): M-matrix LCPs and obstacles, P-matrix LCPs; every member
    against serial nrmicp and the numpy oracle; a callback on every member, bounds on every member, the
    stationary members with some of the serial loop's options. `rng` draws what it drew before the
    stationary members took these options (the same Newton problems); `extra` draws the rest."""
    seed = int(os.environ.get("NRMICP_FUZZ_SEED", "2026"))
    rng, extra = np.random.default_rng(seed), np.random.default_rng(seed + 1)
    jacobians = np.random.default_rng(seed + 2)   # (drawn last: the problems above unchanged)
    levels = np.random.default_rng(seed + 3)   # newton's scipy prolongations or nrmicp.Hierarchy
    rows = []
    for k in range(examples):
        n = int(rng.integers(5, 60))
        R = sp.random(n, n, density=min(1.0, 4.0 / n), random_state=int(rng.integers(1 << 30)))
        R.data[:] = -np.abs(R.data)
        R.setdiag(0.0)
        if rng.random() < 0.5:
            R = (R + R.T) / 2
        A = sp.csr_matrix(R + sp.diags(np.abs(R).sum(axis=1).A.ravel() + rng.uniform(0.1, 2.0, n)))
        q = rng.normal(size=n) * 10 ** rng.uniform(-1, 2)
        zeta = None if rng.random() < 0.5 else rng.normal(size=n)
        method = str(rng.choice(list(OPTIONS)))
        if method != "newton" and extra.random() < 0.4:
            method = str(extra.choice(list(MORE_MEMBERS)))
        lo, hi = split(n, rng.uniform(0.2, 1.0, SIZE).tolist())
        polish = bool(rng.random() < 0.3) and method == "newton"
        # bounds (some rows free above) and a callback (every rank's is called)
        upper = None
        draw = rng if method == "newton" else extra
        if draw.random() < 0.4:
            upper = (np.zeros(n) if zeta is None else zeta) + draw.uniform(0.0, 2.0, n)
            upper[draw.random(n) < 0.3] = np.inf
        kw = _fuzz_options(extra, method, A, lo, hi)
        calls = []
        local_upper = None if upper is None else upper[lo:hi]
        if upper is not None and method == "newton" and extra.random() < 0.3:   # an implicit upper u(z) ≥ upper
            base, local_base = upper.copy(), upper[lo:hi].copy()
            upper = lambda z, b=base: b + 0.05 * (1.0 + np.sin(z))  # noqa: E731
            local_upper = lambda z, b=local_base: b + 0.05 * (1.0 + np.sin(z))  # noqa: E731
        local_zeta = None if zeta is None else zeta[lo:hi]
        if method == "newton" and zeta is not None and upper is None and jacobians.random() < 0.5:
            # a callable ζ = ψ + 0.1 sin z with ζ′ as an operator of this rank's rows or a diagonal
            zeta, local_zeta = (lambda z, p=zeta: p + 0.1 * np.sin(z)), (lambda z, p=zeta[lo:hi]: p + 0.1 * np.sin(z))
            kw["zeta_jacobian"] = _fuzz_jacobian(str(jacobians.choice(["operator", "diagonal"])))
        if method == "newton" and levels.random() < 0.4:   # the whole prolongations on every rank
            Ps = _aggregation(levels, n)
            kw["hierarchy"] = nrmicp.Hierarchy(A, Ps) if levels.random() < 0.5 else Ps
        r = dist.solve(A[lo:hi], q[lo:hi], local_zeta, method=method, tol=1e-9,
                       maxiter=100000, polish=polish and not callable(upper), upper=local_upper,
                       callback=lambda zk: calls.append(len(zk)) and False, **kw)
        z = dist.gather(r.z)
        if RANK == 0:
            serial = nrmicp.solve(A, q, zeta, upper=upper, method="newton", tol=1e-11, polish=not callable(upper))
            g = z - (0.0 if zeta is None else (zeta(z) if callable(zeta) else zeta))
            u = upper(z) if callable(upper) else upper
            m = np.minimum(A @ z + q, g) if upper is None else np.minimum(g, np.maximum(z - u, A @ z + q))
            rows.append({"n": n, "method": method, "status": str(r.status), "err": float(np.max(np.abs(z - serial.z))),
                         "res": float(np.linalg.norm(m)), "bounded": upper is not None, "implicit": callable(upper), "called": bool(calls) and set(calls) == {hi - lo},
                         "options": sorted(k for k in kw if k != "omega2"), "scale": float(np.max(np.abs(q))),
                         "hierarchy": type(kw.get("hierarchy")).__name__})
    return rows


def case_boomeramg():
    """The nesting hierarchy's BoomerAMG takes -nrmicp_hierarchy_ options, and nothing of ours or the
    user's stays in the options database after a solve."""
    pb3 = obstacle_3d(7, exact=False)
    lo, hi = split(pb3.A.shape[0])
    r = dist.solve(sp.csr_matrix(pb3.A)[lo:hi], pb3.q[lo:hi], pb3.zeta[lo:hi], method="newton", tol=1e-9,
                   hierarchy="amg")
    hier = PETSc.Options("nrmicp_hierarchy_")
    hier["pc_hypre_boomeramg_max_levels"] = 3
    r3 = dist.solve(sp.csr_matrix(pb3.A)[lo:hi], pb3.q[lo:hi], pb3.zeta[lo:hi], method="newton", tol=1e-9,
                    hierarchy="amg")
    hier.delValue("pc_hypre_boomeramg_max_levels")
    return {"status": str(r.status), "levels": len(r.level_steps), "levels_3": len(r3.level_steps),
            "status_3": str(r3.status),
            "left_all": sorted(k for k in PETSc.Options().getAll() if k.startswith("nrmicp"))}


def case_dense():
    """The 'amg' hierarchy's rule (nrmicp/petsc/hierarchy.hpp) against hypre's classical hierarchy with the
    rule's strong threshold (any -nrmicp_hierarchy_ option replaces the rule: one classical set-up): each
    one's first coarse operator, its rows and its nonzeros over A's."""
    from nrmicp import _petsc
    from nrmicp.scenes.finite_elements import fe_obstacle
    out = {}
    for name, pb in (("3d", obstacle_3d(15, exact=False)), ("2d", obstacle_2d(63, exact=False)),
                     ("p1", fe_obstacle("P1", 3))):
        A = sp.csr_matrix(pb.A)
        M = mat(A, *split(A.shape[0]))
        hier = PETSc.Options("nrmicp_hierarchy_")
        hier["pc_hypre_boomeramg_strong_threshold"] = _petsc.hierarchy_strong_threshold
        classical = _petsc.amg_levels(M.handle)
        hier.delValue("pc_hypre_boomeramg_strong_threshold")
        chosen = _petsc.amg_levels(M.handle)
        out[name] = {"classical": classical["nonzeros"][0] / A.nnz, "classical_rows": classical["rows"][0],
                     "chosen": chosen["nonzeros"][0] / A.nnz, "chosen_rows": chosen["rows"][0],
                     "levels": len(chosen["rows"]) + 1}
    return out


def case_floor():
    """tol far below Res's rounding level: the Newton member stops at the floor, says so and
    names it (the serial member's rule and message), on the obstacle and an affine ICP."""
    out = {}
    pb = obstacle_2d(63, exact=False)
    aff = make_affine_icp(16, symmetric=False)
    B, c = sp.csr_matrix(aff.zeta.B), aff.zeta.c
    for name, A, q, zeta, dzeta in (
            ("obstacle", sp.csr_matrix(pb.A), pb.q, pb.zeta, lambda M, lo, hi: pb.zeta[lo:hi]),
            ("affine", sp.csr_matrix(aff.A), aff.q, nrmicp.Affine(B, c),
             lambda M, lo, hi: nrmicp.Affine(mat(B, lo, hi), c[lo:hi]))):
        lo, hi = split(A.shape[0])
        M = mat(A, lo, hi)
        r = dist.solve(M, vec(M, q), dzeta(M, lo, hi), method="newton", tol=1e-17, hierarchy="amg")
        z = dist.gather(r.z)
        if RANK == 0:
            serial = nrmicp.solve(A, q, zeta, method="newton", tol=1e-17, hierarchy="amg")
            out[name] = {"status": str(r.status), "message": r.message, "res": float(r.residual), "nit": r.nit,
                         "serial_status": str(serial.status), "err": float(np.max(np.abs(z - serial.z)))}
    return out


def case_overshoot():
    """P3 finite elements (no M-matrix): the nested start's contact set is far too small and the
    full first steps overshoot; damped (the serial member's rule), the finest steps stay few."""
    from nrmicp.scenes.finite_elements import fe_obstacle
    pb = fe_obstacle("P3", 2, exact=False)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    r = dist.solve(A[lo:hi], pb.q[lo:hi], pb.zeta[lo:hi], method="newton", tol=1e-9, hierarchy="amg")
    z = dist.gather(r.z)
    if RANK == 0:
        serial = nrmicp.solve(A, pb.q, pb.zeta, method="newton", tol=1e-11)
        return {"status": str(r.status), "levels": r.level_steps, "err": float(np.max(np.abs(z - serial.z)))}


def case_sweeps():
    """A cold start (hierarchy=None) on the 2D obstacle, m = 63: without the projected Gauss–Seidel
    sweeps after each step its steps peel the contact set a layer at a time (24 steps); with them,
    on each rank's rows, they free several layers a step."""
    pb = obstacle_2d(63, exact=False)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    r = dist.solve(A[lo:hi], pb.q[lo:hi], pb.zeta[lo:hi], method="newton", hierarchy=None, tol=1e-9)
    z = dist.gather(r.z)
    if RANK == 0:
        serial = nrmicp.solve(A, pb.q, pb.zeta, method="newton", hierarchy=None, tol=1e-11)
        return {"status": str(r.status), "levels": r.level_steps, "serial_steps": serial.level_steps[0],
                "err": float(np.max(np.abs(z - serial.z))),
                "res": float(oracle_residual(A, pb.q, z, pb.zeta))}



def case_one_sided_contact():
    """A box problem whose rows at a nonzero bound lie on one rank only (z pushed up to its upper bound
    0.3 on the first rows, held at 0 on the rest): the Newton step moves those bounds' columns to the
    right-hand side with a product with A, which every rank must take part in (it deadlocked when each
    rank decided by its own rows); cold and nested."""
    n = 29
    A = sp.diags([-np.ones(n - 1), 2.5 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr")
    q = np.where(np.arange(n) < 6, -1.0, 1.0)
    upper = np.full(n, 0.3)
    lo, hi = split(n)
    out = {}
    for h in (None, "amg"):
        r = dist.solve(A[lo:hi], q[lo:hi], None, upper=upper[lo:hi], method="newton", hierarchy=h, tol=1e-10)
        z = dist.gather(r.z)
        if RANK == 0:
            w = A @ z + q
            out[str(h)] = {"status": str(r.status), "at_upper": int(np.sum(z >= 0.3 - 1e-12)),
                           "violation": float(max(-z.min(), z.max() - 0.3, 0.0)),
                           "sign": float(max(-w[z <= 1e-12].min(initial=0), w[z >= 0.3 - 1e-12].max(initial=0),
                                             np.abs(w[(z > 1e-12) & (z < 0.3 - 1e-12)]).max(initial=0)))}
    return out


def case_implicit_upper():
    """An implicit upper bound on the PETSc engine (the one driver's outer fixed point): a membrane
    pushed up under a ceiling u(z) = 0.25 + 0.1 sin z (callable, this rank's rows) and u(z) = 0.1 z +
    0.25 (Affine with a PETSc B), against nrmicp.solve with the same bound; a stationary member refused."""
    pb = obstacle_2d(31, exact=False)
    A = sp.csr_matrix(pb.A)
    n = A.shape[0]
    lo, hi = split(n)
    q = pb.q - 40.0
    B = sp.csr_matrix(0.1 * sp.eye(n))
    uppers = {"callable": (lambda z: 0.25 + 0.1 * np.sin(z), lambda z: 0.25 + 0.1 * np.sin(z)),
              "affine": (nrmicp.Affine(B, np.full(n, 0.25)), dist_affine(B, 0.25, lo, hi))}
    out = {}
    for name, (serial_u, local_u) in uppers.items():
        r = dist.solve(A[lo:hi], q[lo:hi], pb.zeta[lo:hi], upper=local_u, method="newton", hierarchy="amg", tol=1e-10)
        z = dist.gather(r.z)
        if RANK == 0:
            s = nrmicp.solve(A, q, pb.zeta, upper=serial_u, method="newton", tol=1e-10)
            u = B @ z + 0.25 if name == "affine" else 0.25 + 0.1 * np.sin(z)
            out[name] = {"status": str(r.status), "serial_status": str(s.status), "res": float(r.residual),
                         "err": float(np.max(np.abs(z - s.z))), "at_upper": int(np.sum(z >= u - 1e-12)),
                         "above": float(np.max(z - u))}
    D = A + sp.diags(A.diagonal())   # row-dominant by half its diagonal: 'auto' alone would take nrmgs
    r = dist.solve(D[lo:hi], q[lo:hi], pb.zeta[lo:hi], upper=uppers["callable"][1], tol=1e-10)
    if RANK == 0:   # (an implicit upper is newton's: 'auto' takes it, as nrmicp.solve's 'auto' does)
        out["auto"] = [r.method, nrmicp.solve(D, q, pb.zeta, upper=uppers["callable"][0], tol=1e-10).method]
    try:
        dist.solve(A[lo:hi], q[lo:hi], pb.zeta[lo:hi], upper=uppers["callable"][1], method="nrmgs")
        out["nrmgs"] = "solved"
    except ValueError as exc:
        out["nrmgs"] = str(exc)
    return out


def _blocks(n):
    """Every rank's row range of split(n)."""
    cuts = np.concatenate([[0], np.round(np.arange(1, SIZE + 1) / SIZE * n)]).astype(int)
    return [(int(cuts[r]), int(cuts[r + 1])) for r in range(SIZE)]


def case_jacobian():
    """ζ's Jacobian on the PETSc engine (semismooth Newton on the whole ICP, the one driver's): the 2D
    obstacle with ζ = ψ + 0.2 sin z, ζ′ a LinearOperator of this rank's rows and a diagonal matrix, and a
    nonlocal ζ = ψ + 0.3 M z (M the 5-point averaging stencil as a PETSc Mat: ζ and ζ′'s products
    communicate) with ζ′ an operator; each cold and nested (BoomerAMG), against nrmicp.solve with the same
    ζ′ (cold: the same decisions). Then a ζ′ that couples rows as a sparse matrix, and an operator of the
    wrong shape on the last rank only: refused on every rank."""
    from scipy.sparse.linalg import LinearOperator, aslinearoperator
    pb = obstacle_2d(31, exact=False)
    A = sp.csr_matrix(pb.A)
    n = A.shape[0]
    lo, hi = split(n)
    m, psi = hi - lo, np.asarray(pb.zeta, dtype=float)
    M = sp.csr_matrix((sp.diags(A.diagonal()) - A) / A.diagonal().max())
    Mb = sp.csr_matrix(sp.block_diag([M[a:b, a:b] for a, b in _blocks(n)]))   # M within each rank's rows
    free = np.arange(n) % 31 < 2   # the grid's first two columns

    def shifted(z, p, f):
        return np.where(f, z - 10.0, p + 0.2 * np.sin(z))
    Mp = mat(M, lo, hi)
    x, y = Mp.createVecs()

    def mv(v):   # this rank's rows of M v (collective)
        x.setArray(v)
        Mp.mult(x, y)
        return y.getArray().copy()

    def diag(k, d):
        return LinearOperator((k, k), matvec=lambda v: d * np.ravel(v), dtype=float)
    problems = {
        "sin operator": (lambda z: psi + 0.2 * np.sin(z), lambda z: diag(n, 0.2 * np.cos(z)),
                         lambda z: psi[lo:hi] + 0.2 * np.sin(z), lambda z: diag(m, 0.2 * np.cos(z))),
        "sin diagonal": (lambda z: psi + 0.2 * np.sin(z), lambda z: sp.diags(0.2 * np.cos(z)),
                         lambda z: psi[lo:hi] + 0.2 * np.sin(z), lambda z: sp.diags(0.2 * np.cos(z))),
        "nonlocal operator": (lambda z: psi + 0.3 * (M @ z), lambda z: aslinearoperator(0.3 * M),
                              lambda z: psi[lo:hi] + 0.3 * mv(z),
                              lambda z: LinearOperator((m, m), matvec=lambda v: 0.3 * mv(np.ravel(v)), dtype=float)),
        # a coupling sparse ζ′ of a row-local ζ (ζ_i of z_i and its grid neighbours on the rank): its product
        "local coupling matrix": (lambda z: psi + 0.3 * (Mb @ np.sin(z)), lambda z: sp.csr_matrix(0.3 * Mb @ sp.diags(np.cos(z))),
                                  lambda z: psi[lo:hi] + 0.3 * (Mb[lo:hi, lo:hi] @ np.sin(z)),
                                  lambda z: sp.csr_matrix(0.3 * Mb[lo:hi, lo:hi] @ sp.diags(np.cos(z)))),
        # a diagonal ζ′ with entries 1 (rows ζ_i = z_i − 10, never active: free rows): no LCP system, its product
        "sin diagonal at 1": (lambda z: shifted(z, psi, free), lambda z: sp.diags(np.where(free, 1.0, 0.2 * np.cos(z))),
                              lambda z: shifted(z, psi[lo:hi], free[lo:hi]),
                              lambda z: sp.diags(np.where(free[lo:hi], 1.0, 0.2 * np.cos(z))))}
    out = {}
    for name, (zeta, jac, local_zeta, local_jac) in problems.items():
        for hierarchy in (None, "amg"):
            calls = []
            r = dist.solve(A[lo:hi], pb.q[lo:hi], local_zeta, method="newton", hierarchy=hierarchy, tol=1e-10,
                           zeta_jacobian=lambda z: calls.append(1) or local_jac(z))
            z = dist.gather(r.z)
            if RANK == 0:
                s_calls = []
                s = nrmicp.solve(A, pb.q, zeta, method="newton", hierarchy=hierarchy, tol=1e-10,
                                 zeta_jacobian=lambda z: s_calls.append(1) or jac(z))
                g = z - zeta(z)
                out[f"{name} {hierarchy}"] = {
                    "status": str(r.status), "serial_status": str(s.status), "path": r.path,
                    "calls": len(calls), "serial_calls": len(s_calls), "nit": r.nit, "serial_nit": s.nit,
                    "err": float(np.max(np.abs(z - s.z)) / np.max(np.abs(s.z))),
                    "oracle_res": float(oracle_residual(A, pb.q, z, zeta)), "res": float(r.residual),
                    "min_g": float(g.min()), "min_w": float((A @ z + pb.q).min()),
                    "gw": float(np.max(np.abs(np.minimum(A @ z + pb.q, g)))),
                    "matrix_free": int(r.counters.get("matrix_free_iterations", 0))}
    last = RANK == SIZE - 1
    bad_jacobians = {
        "wrong shape on the last rank": lambda z: diag(m + last, np.zeros(m + last)),
        "complex operator": lambda z: LinearOperator((m, m), matvec=lambda v: 1j * v, dtype=complex),
        "a string": lambda z: "J",
        "matvec of the wrong length on the last rank": lambda z: LinearOperator(
            (m, m), matvec=lambda v: np.zeros(m + 1) if last else 0 * v, dtype=float),
        "matvec NaN on the last rank": lambda z: diag(m, np.full(m, np.nan if last else 0.1)),
        "not callable": np.eye(m)}
    refused = {}
    for name, bad in bad_jacobians.items():
        try:
            dist.solve(A[lo:hi], pb.q[lo:hi], problems["nonlocal operator"][2], method="newton", hierarchy=None,
                       zeta_jacobian=bad)
            refused[name] = ["no exception", ""]
        except Exception as exc:  # noqa: BLE001 - the outcome is the test's subject
            refused[name] = [type(exc).__name__, str(exc)]
    out["refused"] = _allgather_text(json.dumps(refused))
    return out


def case_solver():
    """distributed.Solver: set up once, solved for a march of loads (x0 the last answer) by newton
    ('amg') and nrmgs, against serial nrmicp.solve; the set-up reported by the first solve of each
    scaling only; misplaced options and a closed Solver refused on every rank."""
    pb = obstacle_2d(31, exact=False)
    A = sp.csr_matrix(pb.A)
    n = A.shape[0]
    lo, hi = split(n)
    out = {}
    for method, kw in (("newton", {"hierarchy": "amg"}), ("nrmgs", {})):
        rows = []
        with dist.Solver(A[lo:hi], method=method, **kw) as solver:
            z_last = None
            for k, load in enumerate((0.0, 5.0, 10.0)):
                q = pb.q - load
                tol = {} if k < 2 else {"tol": 1e-9}   # the default rule twice, then the paper's tol (a second core)
                x0 = None if z_last is None else z_last[lo:hi]
                r = solver.solve(q[lo:hi], pb.zeta[lo:hi], x0=x0, **tol)
                z = z_last = _gather(r.z.getArray(readonly=True), n)   # (every rank's rows, on every rank)
                if RANK == 0:
                    s = nrmicp.solve(A, q, pb.zeta, method="newton", tol=1e-12)
                    rows.append({"status": r.status.name, "err": float(np.max(np.abs(z - s.z))),
                                 "setup": float(r.timings["setup"]), "res": float(oracle_residual(A, q, z, pb.zeta))})
        out[method] = rows

    def refused(make):
        try:
            make()
            return ["no exception", ""]
        except Exception as exc:  # noqa: BLE001 - the outcome is the test's subject
            return [type(exc).__name__, str(exc)]
    solver = dist.Solver(A[lo:hi], method="newton")
    out["x0 at set-up"] = refused(lambda: dist.Solver(A[lo:hi], x0=np.zeros(hi - lo)))
    out["method per solve"] = refused(lambda: solver.solve(pb.q[lo:hi], pb.zeta[lo:hi], method="nrmgs"))
    solver.close()
    out["closed"] = refused(lambda: solver.solve(pb.q[lo:hi], pb.zeta[lo:hi]))
    return out


def case_jacobian_still_rows():
    """ζ′ on a block-diagonal ICP whose second block (the last rank's rows on 2 ranks) is all in contact
    with a constant obstacle, the first a 1D membrane under ζ = ψ + 2 sin z (a review's case): the last
    rank's rows stand still while the outer step after a Newton step is rejected on the first rank's, so
    a test on one rank's rows took the collective obstacle solve on one rank only (a hang). Against
    nrmicp.solve with the same ζ′."""
    m = 200
    h = 1.0 / (m + 1)
    L1 = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1]) / h**2
    A = sp.csr_matrix(sp.block_diag([L1, sp.identity(m) * 4.0]))
    n = 2 * m
    x = np.arange(1, m + 1) * h
    q = np.concatenate([np.full(m, 30.0), np.full(m, 5.0)])
    psi = np.concatenate([-0.3 - 0.1 * x, np.full(m, 0.25)])
    cc = np.where(np.arange(n) >= m, 0.0, 2.0)
    lo, hi = split(n)
    out = {}
    for form in ("diagonal", "operator"):
        def jacobian(z, a=lo, b=hi, form=form):
            d = cc[a:b] * np.cos(z)
            if form == "diagonal":
                return sp.diags(d)
            from scipy.sparse.linalg import LinearOperator
            return LinearOperator((b - a, b - a), matvec=lambda v: d * np.ravel(v), dtype=float)
        r = dist.solve(A[lo:hi], q[lo:hi], lambda z: psi[lo:hi] + cc[lo:hi] * np.sin(z), method="newton",
                       hierarchy=None, tol=1e-8, zeta_jacobian=jacobian)
        z = dist.gather(r.z)
        if RANK == 0:
            zeta = lambda v: psi + cc * np.sin(v)  # noqa: E731
            s = nrmicp.solve(A, q, zeta, method="newton", hierarchy=None, tol=1e-8,
                             zeta_jacobian=lambda v: sp.diags(cc * np.cos(v)))
            out[form] = {"status": r.status.name, "serial_status": s.status.name,
                         "numpy": float(np.max(np.abs(np.minimum(A @ z + q, z - zeta(z))))),
                         "serial_numpy": float(np.max(np.abs(np.minimum(A @ s.z + q, s.z - zeta(s.z)))))}
    return out


def dist_affine(B, c, lo, hi):
    """nrmicp.Affine(B, c) with B as a PETSc Mat in the split's row layout."""
    return nrmicp.Affine(mat(sp.csr_matrix(B), lo, hi), np.full(hi - lo, c))


def case_warm():
    """The next time step of the 2D obstacle (a load of 0.5) from the last solution: it replaces the
    nested start (no coarse level solved), as in the serial member; zeros nest, and ones (Res small,
    the active set far off) give way to the nested start after warm_steps."""
    pb = obstacle_2d(63, exact=False)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    first = dist.solve(A[lo:hi], pb.q[lo:hi], pb.zeta[lo:hi], method="newton", tol=1e-10, hierarchy="amg")
    q_next = pb.q + 0.5
    runs = {name: dist.solve(A[lo:hi], q_next[lo:hi], pb.zeta[lo:hi], method="newton", tol=1e-10, x0=x0,
                             hierarchy="amg")
            for name, x0 in (("warm", first.z), ("zeros", np.zeros(hi - lo)), ("ones", np.ones(hi - lo)))}
    zs = {name: dist.gather(r.z) for name, r in runs.items()}
    if RANK == 0:
        serial = nrmicp.solve(A, q_next, pb.zeta, method="newton", tol=1e-11)
        return {"first_levels": first.level_steps} | {
            name: {"status": str(r.status), "levels": r.level_steps, "nit": r.nit,
                   "err": float(np.max(np.abs(zs[name] - serial.z)))} for name, r in runs.items()}


def case_units():
    """The default rule (no tol, no rtol) on the 2D obstacle in three units (A and q scaled by
    1e-6, 1, 1e6) and with its rows in units of their own (scaled by 10^±8: the same answer): the same
    verdict and answer as the serial default, the paper's Res reported."""
    pb = obstacle_2d(31, exact=False)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    out = {}
    rows = 10.0 ** np.random.default_rng(5).uniform(-8, 8, A.shape[0])
    for s in (1e-6, 1.0, 1e6, rows):
        for method in ("newton", "nrmgs"):
            S = sp.diags(np.broadcast_to(s, A.shape[0]))
            r = dist.solve(sp.csr_matrix(S @ A)[lo:hi], (S @ pb.q)[lo:hi], pb.zeta[lo:hi], method=method, maxiter=100000)
            z = dist.gather(r.z)
            if RANK == 0:
                exact = nrmicp.solve(A, pb.q, pb.zeta, method="newton", tol=1e-12)
                out[f"{method} {'rows' if s is rows else f'{s:g}'}"] = {
                    "status": str(r.status), "criterion": r.criterion["measure"],
                    "err": float(np.max(np.abs(z - exact.z)) / np.max(np.abs(exact.z))),
                    # equal up to the rounding of w = Az + q at z (its summation order differs by rank)
                    "res_is_papers": bool(abs(r.residual - oracle_residual(S @ A, S @ pb.q, z, pb.zeta)) <=
                                          1e-6 * r.residual + 1e-15 * np.linalg.norm(abs(S @ A) @ abs(z) + abs(S @ pb.q)))}
    return out


def case_z_units():
    """z's units a power of two far from 1 (q, ψ scaled; A as is) with the PETSc engine's Krylov solves (hierarchy
    'amg') and the outer fixed point's Anderson: the steps and z / s of units 1 (the KSP's inner products of z's
    size left float's range: STAGNATED 5% off)."""
    pb = obstacle_2d(31, exact=False)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    out = {}
    for name, zeta in (("obstacle", lambda s: s * pb.zeta[lo:hi]),
                       ("outer", lambda s: (lambda z, p=pb.zeta[lo:hi]: s * (p + 0.2 * np.sin(z / s))))):
        runs = {}
        for s in (1.0, 2.0 ** -700, 2.0 ** 700):
            r = dist.solve(A[lo:hi], s * pb.q[lo:hi], zeta(s), method="newton", hierarchy="amg")
            runs[s] = (str(r.status), r.nit, dist.gather(r.z))
        if RANK == 0:
            ref = runs[1.0][2]
            out[name] = {f"{s:g}": {"status": st, "nit": nit, "nit_1": runs[1.0][1],
                                    "err": float(np.max(np.abs(z / s - ref)) / np.max(np.abs(ref)))}
                         for s, (st, nit, z) in runs.items()}
    return out


def _pmat(P, lo, hi, clo, chi):
    """P's fine rows lo:hi as this rank's block, its columns laid out as the coarse rows clo:chi."""
    B = sp.csr_matrix(P[lo:hi])
    B.sort_indices()
    return PETSc.Mat().createAIJ(size=((hi - lo, P.shape[0]), (chi - clo, P.shape[1])),
                                 csr=(B.indptr.astype(PETSc.IntType), B.indices.astype(PETSc.IntType), B.data),
                                 comm=COMM)


def engine_problems():
    """(name, A, q, serial zeta, this rank's zeta kind/c/fn, upper or None, prolongations or None)."""
    from nrmicp.scenes.two_sided import two_sided_membrane_2d as two_sided_2d
    out = []
    pb = obstacle_2d(63, exact=False)
    out.append(("obstacle_2d cold", pb.A, pb.q, pb.zeta, pb.zeta, None, None))
    out.append(("obstacle_2d nested", pb.A, pb.q, pb.zeta, pb.zeta, None, pb.prolongations()))
    cd = convection_diffusion_obstacle(31, exact=False)
    out.append(("convection nested", cd.A, cd.q, cd.zeta, cd.zeta, None, cd.prolongations()))
    ts = two_sided_2d(31)
    out.append(("two-sided nested", ts.A, ts.q, ts.zeta, ts.zeta, ts.upper, ts.prolongations()))
    icp = make_icp(16, c=0.1)
    out.append(("icp callable", icp.A, icp.q, icp.zeta, icp.zeta, None, None))
    lcp = make_lcp(16)
    out.append(("lcp", lcp.A, lcp.q, None, None, None, None))
    return out


def golden_problems():
    """The golden master's Newton cases (tests/golden/newton.py) that fit a PETSc matrix: its obstacle
    scenes with their own hierarchy or none, ζ none / constant / callable (an entry-wise callable: each
    rank evaluates its rows), tol 1e-8 and 1e-10. (name, A, q, zeta, zeta, upper, Ps, tol)."""
    from nrmicp import scenes
    built = {"obstacle_1d": scenes.obstacle_1d(127), "obstacle_2d_31": obstacle_2d(31, exact=False),
             "obstacle_2d_16": obstacle_2d(16, exact=False), "obstacle_3d": obstacle_3d(11, exact=False),
             "convection": convection_diffusion_obstacle(31, exact=False),
             "american_put": scenes.american_put(n_space=256, exact=False)}
    out = []
    for name, p in built.items():
        psi = np.asarray(p.zeta, dtype=float)
        zetas = {"none": (None, p.q + p.A @ psi), "const": (psi, p.q),
                 "callable": (lambda z, psi=psi: psi.copy(), p.q)}
        for hname, Ps in (("none", None), ("geom", p.prolongations() or None)):
            if hname == "geom" and Ps is None:
                continue
            for zname, (zeta, q) in zetas.items():
                for tol in (1e-8, 1e-10):
                    out.append((f"{name}/{hname}/{zname}/tol{tol}", p.A, q, zeta, zeta, None, Ps, tol))
    return out


def case_rounds():
    """What the serial layer's rounds decide on the PETSc engine as in nrmicp.solve: w under an extreme
    default-rule σ (A's diagonal 1e-300), polish within free rows' bounds, the callback's k counting on over
    re-solves, the note of a Jacobian given up under the default rule (one rank: a nonlocal ζ)."""
    out = {}
    s = 1e-300
    A = sp.csr_matrix(sp.diags([-0.1 * s, s, -0.1 * s], [-1, 0, 1], shape=(4, 4)))
    q = np.array([-s, 1e10, -s, 1.0])
    lo, hi = split(4)
    for m in ("newton", "nrmgs"):
        r = dist.solve(A[lo:hi], q[lo:hi], method=m)
        z, w = dist.gather(r.z), dist.gather(r.w)
        if RANK == 0:
            out[f"w_{m}"] = {"w": w.tolist(), "numpy": (A @ z + q).tolist(), "serial": nrmicp.solve(A, q, method=m).w.tolist()}
    pb = obstacle_2d(31, exact=False)
    A, c = sp.csr_matrix(pb.A), pb.zeta.copy()
    c[::3] = -np.inf
    lo, hi = split(A.shape[0])
    r = dist.solve(A[lo:hi], pb.q[lo:hi], c[lo:hi], method="newton", hierarchy=None, polish=True, tol=1e-13)
    ks = []
    rc = dist.solve(A[lo:hi], pb.q[lo:hi], pb.zeta[lo:hi], method="newton", hierarchy=None, tol=1e-12,
                    record_history=True, callback=lambda intermediate_result: ks.append(intermediate_result.nit))
    zf = dist.gather(r.z)
    if RANK == 0:
        serial = nrmicp.solve(A, pb.q, c, method="newton", hierarchy=None, polish=True, tol=1e-13)
        out["free"] = {"status": str(r.status), "message": r.message, "polished": r.polished,
                       "serial_status": str(serial.status), "serial_message": serial.message,
                       "serial_polished": serial.polished, "err": float(np.max(np.abs(zf - serial.z))),
                       "res": r.residual}
        out["callback"] = {"ks": ks, "history": rc.history["iteration"].tolist(), "iterations": rc.iterations}
    import logging   # verbose: the Newton member's progress lines, rank 0's only
    lines = []
    handler = logging.Handler()
    handler.emit = lambda record: lines.append(record.getMessage())
    logger = logging.getLogger("nrmicp")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    rv = dist.solve(A[lo:hi], pb.q[lo:hi], pb.zeta[lo:hi], method="newton", hierarchy=None, tol=1e-9, verbose=1)
    logger.removeHandler(handler)
    others = _flag_max(COMM, float(len(lines)) if RANK > 0 else 0.0)
    if RANK == 0:
        out["verbose"] = {"status": str(rv.status), "lines": lines, "others": others}
    if SIZE == 1:
        from test_wrong_jacobian import averaging_problem
        A, q, zeta, jacs = averaging_problem(24)
        r = dist.solve(sp.csr_matrix(A), q, zeta, method="newton", zeta_jacobian=jacs["negated"], hierarchy=None)
        serial = nrmicp.solve(A, q, zeta, method="newton", zeta_jacobian=jacs["negated"], hierarchy=None)
        out["jacobian"] = {"path": r.path, "message": r.message, "serial_path": serial.path, "serial_message": serial.message}
    return out


def case_shared_hierarchy():
    """One nrmicp.Hierarchy (or its prolongations as scipy matrices) given to nrmicp.solve and to
    distributed.solve: the same levels on both engines, so the same decisions (level steps) and z."""
    pb = obstacle_2d(63, exact=False)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    out = {}
    for name, h in (("geometric", nrmicp.Hierarchy(A, pb.prolongations())), ("amg", nrmicp.Hierarchy.amg(A))):
        for form, given in (("Hierarchy", h), ("list", list(h.prolongations))):
            r = dist.solve(A[lo:hi], pb.q[lo:hi], pb.zeta[lo:hi], method="newton", hierarchy=given, tol=1e-9)
            z = dist.gather(r.z)
            if RANK == 0:
                s = nrmicp.solve(A, pb.q, pb.zeta, method="newton", hierarchy=h, tol=1e-9, scale=None)
                out[f"{name} {form}"] = {"steps": r.level_steps, "serial_steps": s.level_steps, "status": str(r.status),
                                         "serial_status": str(s.status), "err": float(np.max(np.abs(z - s.z)))}
    other = nrmicp.Hierarchy(2 * A, pb.prolongations())   # built on another A: refused, as serially
    try:
        dist.solve(A[lo:hi], pb.q[lo:hi], pb.zeta[lo:hi], method="newton", hierarchy=other)
        refused = "solved"
    except ValueError as exc:
        refused = str(exc)
    texts = _allgather_text(refused)
    return {"levels": out, "another A": texts} if RANK == 0 else None


def case_hazards():
    """Failures on one rank only where the others would wait: a hierarchy that differs between the ranks,
    a progress line (verbose) or the final line that raises on rank 0 only. Every rank's outcome."""
    import logging
    pb = obstacle_2d(31, exact=False)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    Ps = pb.prolongations()
    outcomes = {}

    def run(name, **kw):
        try:
            r = dist.solve(A[lo:hi], pb.q[lo:hi], pb.zeta[lo:hi], method="newton", tol=1e-9, **kw)
            outcomes[name] = ["ok", str(r.status)]
        except Exception as exc:  # noqa: BLE001 - the outcome is the test's subject
            outcomes[name] = [type(exc).__name__, str(exc)]
    run("levels differ", hierarchy=Ps if RANK == 0 else Ps[:1])
    # the last rank's diagonal block [[1, 2], [2, 1]]: its Cholesky of Omega2 + A fails there only; every rank
    # raises that rank's own message, not the others' "another process refused its part"
    B = sp.csr_matrix(sp.block_diag([np.array([[4.0, -1.0], [-1.0, 4.0]])] * (SIZE - 1) + [np.array([[1.0, 2.0], [2.0, 1.0]])]))
    try:
        dist.solve(B[2 * RANK:2 * RANK + 2], -np.ones(2), method="nrm", inner="cholmod")
        outcomes["block refused"] = ["ok", ""]
    except Exception as exc:  # noqa: BLE001
        outcomes["block refused"] = [type(exc).__name__, str(exc)]
    run("values differ", hierarchy=Ps if RANK == 0 else [2.0 * Ps[0]] + Ps[1:])

    class Boom(logging.Filter):
        def __init__(self, final):
            super().__init__()
            self.final = final

        def filter(self, record):
            if RANK == 0 and ("iteration" in record.getMessage()) != self.final:
                raise RuntimeError("the logger failed on rank 0")
            return True
    logger = logging.getLogger("nrmicp")
    logger.addHandler(logging.NullHandler())
    logger.setLevel(logging.INFO)
    for final in (False, True):
        boom = Boom(final)
        logger.addFilter(boom)
        run(f"verbose {'final' if final else 'progress'}", hierarchy=None, verbose=1)
        logger.removeFilter(boom)
    run("after", hierarchy=Ps)   # the ranks still agree
    texts = _allgather_text(json.dumps(outcomes))
    if RANK == 0:
        return [json.loads(t) for t in texts]


def case_engine(which="engine"):
    """The one Newton driver on the PETSc engine (nrmicp._petsc) against the serial member with the
    same prolongations: status, finest steps, z."""
    from nrmicp import _core, _petsc
    rows = []
    problems = ([(*p, 1e-9) for p in engine_problems()] if which == "engine" else golden_problems())
    for name, A, q, zeta, zl, upper, Ps, tol in problems:
        A = sp.csr_matrix(A)
        n = A.shape[0]
        lo, hi = split(n)
        M = mat(A, lo, hi)
        mats, f = [], (lo, hi)
        for P in Ps or []:
            c = split(P.shape[1])
            mats.append(_pmat(sp.csr_matrix(P), *f, *c))
            f = c
        o = _core.Options()
        o.method = _core.Method.newton
        o.tol = tol
        it = _core.SolveOptions()
        it.tol, it.maxiter = tol, 200
        if zeta is None:
            kind, c, fn = _core.ZetaKind.none, None, None
        elif callable(zeta):
            from nrmicp._zeta import CheckedZeta
            kind, c, fn = _core.ZetaKind.functor, None, CheckedZeta(lambda z, lo=lo, hi=hi: zl(_full(z, lo, hi, n))[lo:hi], hi - lo)
        else:
            kind, c, fn = _core.ZetaKind.constant, np.array(zeta[lo:hi], dtype=float), None
        up = None if upper is None else np.array(upper[lo:hi], dtype=float)
        core = _petsc.Newton(M.handle, o, [P.handle for P in mats])
        r = core.solve(np.array(q[lo:hi], dtype=float), kind, c, fn, None, None, it, upper=up)
        z = _gather(r["z"], n)
        out = {"case": name, "status": int(r["status"]), "steps": list(r["newton"].level_steps), "inner": core.inner}
        if RANK == 0:
            s = nrmicp.solve(A, q, zeta=zeta, upper=upper, method="newton", hierarchy=list(Ps) if Ps else None,
                             tol=tol, maxiter=200, scale=None)
            out.update(serial_status=int(s.status), serial_steps=list(s.level_steps),
                       err=float(np.max(np.abs(z - s.z)) / max(np.max(np.abs(s.z)), 1e-300)),
                       res=float(oracle_residual(A, q, z, zeta) if upper is None else s.residual),
                       serial_res=float(s.residual), tol=tol)
        rows.append(out)
    return rows


def _full(z_local, lo, hi, n):
    """This rank's rows in a length-n vector (an entry-wise ζ reads only them)."""
    z = np.zeros(n)
    z[lo:hi] = z_local
    return z


def _gather(local, n):
    """Every rank's rows, on every rank."""
    v = PETSc.Vec().createMPI((len(local), n), comm=COMM)
    v.setArray(local)
    sc, out = PETSc.Scatter.toAll(v)
    sc.scatter(v, out, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
    return out.getArray().copy()



def case_options():
    """distributed.solve's options from nrmicp.solve's table: each refused one's message (per member),
    an unknown name's, and what the supported ones deliver (one rank)."""
    import nrmicp._options as table
    jac = lambda z: sp.eye(len(z))  # noqa: E731
    refused_newton = {"scale": True, "components": 2, "inner": "cg"}
    # options of the stationary members only: the core's Options.check refuses them for newton, naming them;
    # zeta_jacobian without a callable zeta, nrmicp.solve's check
    checked_newton = {"accelerate": "anderson", "phi": 0.5, "theta": 0.5, "z_update": "explicit", "zeta_jacobian": jac}
    refused_stationary = {"scale": True, "components": 2, "polish": True}
    A = sp.diags([-1.0, 4.0, -1.0], [-1, 0, 1], shape=(8, 8), format="csr")
    L = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(8, 8), format="csr")
    q = np.linspace(-1.0, 1.0, 8)

    def outcome(method="newton", zeta=None, **kw):
        try:
            dist.solve(A, q, zeta, method=method, **kw)
            return ["no exception", ""]
        except Exception as exc:  # noqa: BLE001 - the outcome is the test's subject
            return [type(exc).__name__, str(exc)]

    def delivered(method, **kw):
        seen = []
        r = dist.solve(A, q, method=method, tol=1e-12, maxiter=500, stall_iterations=7, record_history=True,
                       callback=lambda zk: seen.append(len(zk)) and False, gamma=2.0, **kw)
        z = dist.gather(r.z)
        w = A @ z + q
        return {"success": bool(r.success), "res": float(r.residual), "calls": len(seen),
                "history": len(r.history["residual"]) if r.history is not None else -1,
                "polished": "polished" in r, "min_z": float(z.min()), "min_w": float(w.min()), "zw": float(abs(z @ w))}
    stationary = {"nrmgs anderson": dict(method="nrmgs", accelerate="anderson", anderson_m=3),
                  "nrmaor phi": dict(method="nrmaor", alpha=1.1, beta=0.5, phi=0.5),
                  "two_sweep theta": dict(method="two_sweep", theta=0.9),
                  "nrm inner": dict(method="nrm", inner="eigen_lu", omega2=4.0),
                  "nrmm verbose": dict(method="nrmm", verbose=1),
                  "mms": dict(method="mms"), "nrmj explicit": dict(method="nrmj", z_update="explicit")}
    return {"unsupported": sorted(table.distributed_refusals("newton")),
            "unsupported_stationary": sorted(table.distributed_refusals("nrmgs")),
            "other": sorted(refused_newton), "other_stationary": sorted(refused_stationary),
            "table": list(table.names()),
            "refused": {name: outcome(**{name: value}) for name, value in refused_newton.items()},
            "checked": {name: outcome(**{name: value}) for name, value in checked_newton.items()},
            "refused_stationary": {name: outcome("nrmgs", **{name: value}) for name, value in refused_stationary.items()},
            "jacobian_stationary": outcome("nrmgs", lambda z: 0 * z, zeta_jacobian=jac),
            "auto_solve": outcome("nrm", lambda z: 0 * z, tol=1e-10),   # nrm, Omega2 = I, an ICP: 'auto' means 'solve'
            "solve_stationary": outcome("nrmgs", z_update="solve"),   # the engine's core refuses it, naming it
            "unknown": outcome(tolerance=1e-8),
            "supported": delivered("newton", polish=True),
            "supported_stationary": {name: delivered(**kw) for name, kw in stationary.items()},
            "auto": [dist.solve(A, q).method, nrmicp.solve(A, q).method],
            # a Laplacian's rows are not dominant: newton, unless an option of the stationary members is given
            "auto_laplacian": {str(kw): [dist.solve(L, q, **kw).method, nrmicp.solve(L, q, **kw).method]
                               for kw in ({}, {"accelerate": "anderson"}, {"z_update": "explicit"})}}


#: The stationary members of the paper's family, with parameters that differ from the defaults; nrm with
#: Omega2 = diag(A) ("diag"): its default Omega2 = I converges serially (M = A) but not as a multisplitting of
#: Bai's matrices (diag 8: M = the diagonal blocks, |Omega2 - A| large; docs/DISTRIBUTED.md).
FAMILY = {"nrm": {"omega2": "diag"}, "nrmm": {}, "nrmaor": {"alpha": 1.1, "beta": 0.9}, "nrmsor": {"alpha": 1.2}, "nrmgs": {},
          "nrmj": {}}


def family_problems():
    """(name, A, q, zeta as nrmicp.solve takes it, this rank's zeta maker, upper or None): an LCP, a
    constant and a callable ζ, and bounds (upper, and rows free below) — n = 64."""
    lcp, icp, obs = make_lcp(8), make_icp(8, c=0.1), make_obstacle_icp(8)
    s = icp.zeta(np.zeros(lcp.A.shape[0]))   # ζ(z) = 0.1 sin(z) + s, entry-wise
    c = obs.zeta.c.copy()
    c[::7] = -np.inf                         # rows free below (the box form's lo' = -inf)
    upper = np.where(np.arange(len(c)) % 3 == 0, obs.zeta.c + 0.5, np.inf)
    c1, u1 = _bounded_on_rank_0(obs.zeta.c, upper)
    return [("lcp", lcp.A, lcp.q, None, lambda lo, hi: None, None),
            ("constant", obs.A, obs.q, obs.zeta.c, lambda lo, hi: obs.zeta.c[lo:hi], None),
            ("callable", icp.A, icp.q, icp.zeta, lambda lo, hi: (lambda z, s=s[lo:hi]: 0.1 * np.sin(z) + s), None),
            ("bounds", obs.A, obs.q, c, lambda lo, hi: c[lo:hi], upper),
            ("bounds_on_rank_0", obs.A, obs.q, c1, lambda lo, hi: c1[lo:hi], u1)]


def _bounded_on_rank_0(c, upper):
    """(ζ, upper) of a problem whose bounds lie in its first quarter of rows (rank 0's on up to 3 ranks):
    a row free below and upper bounds there, none on the other ranks' rows (each core then decides alike)."""
    c, upper = c.copy(), upper.copy()
    c[3] = -np.inf
    upper[len(c) // 4:] = np.inf
    return c, upper


def _box_residual(A, q, z, zeta, upper):
    """‖mid(z − ζ, z − u, Az + q)‖₂ in numpy (the paper's Res without upper)."""
    w = sp.csr_matrix(A) @ z + q
    g = z - (0.0 if zeta is None else (zeta(z) if callable(zeta) else zeta))
    u = np.inf if upper is None else upper
    return float(np.linalg.norm(np.minimum(g, np.maximum(z - u, w))))


def case_family():
    """Every stationary member of the family on every problem of family_problems, distributed and
    serial (the same options): status, nit, z's relative difference, Res by numpy."""
    rows = []
    for name, A, q, zeta, dzeta, upper in family_problems():
        A = sp.csr_matrix(A)
        lo, hi = split(A.shape[0])
        for method, kw in FAMILY.items():
            kw = dict(kw, method=method, tol=1e-10, maxiter=20000, z_update="explicit")
            omega2 = A.diagonal() if kw.get("omega2") == "diag" else None
            mine = dict(kw, omega2=None if omega2 is None else omega2[lo:hi])
            r = dist.solve(A[lo:hi], q[lo:hi], dzeta(lo, hi), upper=None if upper is None else upper[lo:hi], **mine)
            z = dist.gather(r.z)
            if RANK == 0:
                s = nrmicp.solve(A, q, zeta, upper=upper, **dict(kw, omega2=omega2))
                rows.append({"problem": name, "method": method, "status": str(r.status), "nit": r.nit,
                             "serial_status": str(s.status), "serial_nit": s.nit,
                             "err": float(np.max(np.abs(z - s.z)) / np.max(np.abs(s.z))),
                             "res": _box_residual(A, q, z, zeta, upper), "reported": float(r.residual)})
    return rows


def case_hooks():
    """The serial loop's options on PETSc: Anderson with the history and a callback, a callback that
    stops on one rank only, the two-sweep member's theta, phi, verbose, rtol, stall_iterations."""
    pb = make_lcp(8)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    out = {}

    def run(name, **kw):
        calls = []
        cb = kw.pop("callback", _kzr(lambda k, z, res: calls.append((k, res)) and False))
        r = dist.solve(A[lo:hi], pb.q[lo:hi], tol=kw.pop("tol", 1e-10), callback=cb, **kw)
        z = dist.gather(r.z)
        if RANK == 0:
            h = r.history
            out[name] = {"status": str(r.status), "nit": r.nit, "iterations": r.iterations, "calls": len(calls),
                         "last_call": calls[-1][0] if calls else None, "counters": r.counters,
                         "history": None if h is None else [int(h["iteration"][-1]), len(h["residual"])],
                         "history_res": None if h is None else [float(v) for v in h["residual"][:3]],
                         "call_res": [float(c[1]) for c in calls[:3]],
                         "res": _box_residual(A, pb.q, z, None, None), "reported": float(r.residual),
                         "target": r.criterion["target"]}
    run("plain", method="nrmgs")
    run("anderson", method="nrmgs", accelerate="anderson", anderson_m=3, record_history=True)
    run("stop_on_one_rank", method="nrmgs", callback=_kzr(lambda k, z, res: RANK == SIZE - 1 and k == 3))

    def stop_iteration(k, z, res):
        if RANK == SIZE - 1 and k == 3:
            raise StopIteration
    run("stop_iteration_on_one_rank", method="nrmgs", callback=_kzr(stop_iteration))
    run("two_sweep_theta", method="two_sweep", theta=0.8)
    run("phi", method="nrmgs", phi=0.5)
    run("verbose", method="nrmj", verbose=1)
    run("rtol", method="nrmsor", alpha=1.2, tol=None, rtol=1e-8)
    run("stall", method="nrm", omega2=0.1, maxiter=100000, stall_iterations=5, tol=1e-300)
    if RANK == 0:
        out["serial_anderson_nit"] = nrmicp.solve(A, pb.q, method="nrmgs", accelerate="anderson", anderson_m=3,
                                                  tol=1e-10).nit
        out["serial_rtol_tol"] = nrmicp.solve(A, pb.q, method="nrmsor", alpha=1.2, rtol=1e-8).criterion["target"]
    return out


def case_nonpositive_diagonal():
    """A with a stored zero, a negative and (for the hierarchy alone) a NaN diagonal entry: distributed refuses
    every member on every rank naming the first such row (the engine's smoothers, CG and splittings divide by
    a_ii), a stationary member with hierarchy='amg' first by the serial rule; the C++ 'amg' set-up gives the
    hierarchy up there (no level, no crash of hypre's)."""
    from nrmicp import _petsc
    n = 3000
    d = np.full(n, 2.0)
    d[1700] = -1.0
    A = sp.diags([np.full(n - 1, -1.0), d, np.full(n - 1, -1.0)], [-1, 0, 1], format="csr")
    A.data[A.indptr[3] + 1] = 0.0   # a stored zero at A[3, 3]
    q = -np.ones(n)
    lo, hi = split(n)
    out = {}
    for method, hierarchy in (("newton", "amg"), ("newton", None), ("nrm", "auto"), ("nrmgs", "amg")):
        try:
            dist.solve(A[lo:hi], q[lo:hi], method=method, hierarchy=hierarchy, omega2=1.0 if method == "nrm" else None)
            out[f"{method} {hierarchy}"] = None
        except ValueError as exc:
            out[f"{method} {hierarchy}"] = str(exc)
    levels = {}
    for name, value in (("zero", 0.0), ("nan", np.nan)):
        B = A.copy()
        B.data[B.indptr[3] + 1] = value
        levels[name] = _petsc.amg_levels(mat(B, lo, hi).handle)["rows"]
    out["levels"] = levels
    if RANK == 0:
        try:
            nrmicp.solve(A, q, method="nrmgs", hierarchy="amg")
        except ValueError as exc:
            out["serial_stationary"] = str(exc)
    return out


def case_bounds_on_rank_0():
    """Newton with a free row and upper bounds on rank 0's rows only (the others' +inf: none there) against
    the serial solve: status, level steps, z, Res by numpy."""
    obs = make_obstacle_icp(16)
    A = sp.csr_matrix(obs.A)
    c, upper = _bounded_on_rank_0(obs.zeta.c, np.where(np.arange(A.shape[0]) % 3 == 0, obs.zeta.c + 0.5, np.inf))
    lo, hi = split(A.shape[0])
    r = dist.solve(A[lo:hi], obs.q[lo:hi], c[lo:hi], upper=upper[lo:hi], method="newton", tol=1e-10)
    z = dist.gather(r.z)
    if RANK == 0:
        s = nrmicp.solve(A, obs.q, c, upper=upper, method="newton", tol=1e-10)
        return {"status": str(r.status), "serial_status": str(s.status), "res": _box_residual(A, obs.q, z, c, upper),
                "err": float(np.max(np.abs(z - s.z)) / np.max(np.abs(s.z)))}


def case_base_exception():
    """A callback that raises KeyboardInterrupt, or calls sys.exit, on the last rank only: every rank raises it."""
    pb = obstacle_2d(15, exact=False)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    out = {}
    for name, exc in (("KeyboardInterrupt", KeyboardInterrupt()), ("SystemExit", SystemExit(3))):
        def callback(zk, exc=exc):
            if RANK == SIZE - 1:
                raise exc
        try:
            dist.solve(A[lo:hi], pb.q[lo:hi], pb.zeta[lo:hi], method="newton", callback=callback)
            got = "no exception"
        except BaseException as e:  # noqa: BLE001 - the outcome is the test's subject
            got = f"{type(e).__name__}: {e}"
        out[name] = _allgather_text(got)
    return out if RANK == 0 else None


def case_upper_all_inf():
    """upper=+inf on every rank's rows is no upper bound, as serially: a callable ζ with its Jacobian converges
    (the core refused a Jacobian with bounds) and polish runs."""
    from scipy.sparse.linalg import aslinearoperator
    pb = obstacle_2d(31, exact=False)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    psi = pb.zeta[lo:hi]
    r = dist.solve(mat(A, lo, hi), pb.q[lo:hi], lambda z: psi + 0.2 * np.sin(z), upper=np.inf, method="newton",
                   tol=1e-9, zeta_jacobian=lambda z: aslinearoperator(sp.diags(0.2 * np.cos(z))), polish=True)
    return {"status": str(r.status), "polished": r.polished}


def case_reason_alike():
    """A given prolongation whose coarse operator has a zero a_ii in the last rank's rows: result.hierarchy's
    reason is the same words on every rank (it named the row on one and 'another process' on the others)."""
    import warnings
    pb = obstacle_2d(15, exact=False)
    A = sp.csr_matrix(pb.A)
    n = A.shape[0]
    lo, hi = split(n)
    m = n // 2
    P = sp.csr_matrix((np.ones(n), np.minimum(np.arange(n) // 2, m - 1), np.arange(n + 1)), shape=(n, m + 1))
    with warnings.catch_warnings():   # (column m is empty: (P^T A P)[m, m] = 0)
        warnings.simplefilter("ignore")
        r = dist.solve(mat(A, lo, hi), pb.q[lo:hi], pb.zeta[lo:hi], method="newton", hierarchy=[P], tol=1e-8)
    reasons = _allgather_text(json.dumps(r.hierarchy))
    if RANK == 0:
        return [json.loads(t) for t in reasons]


_HINTS = ("uses the paper's Omega2 = I", "the stationary members need O(h^-2) iterations",
          "may lie below what zeta itself resolves")


def case_hints():
    """A solve that did not converge says on PETSc what it says serially (_api.failure_hint): the nrm and
    member hints of a stationary member on an h^-2-scaled A, the outer fixed point's default-target hint."""
    pb = obstacle_2d(15, exact=False)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    psi = np.asarray(pb.zeta)
    scenes = {"nrm": (psi, dict(method="nrm", maxiter=5)),
              "outer": (lambda z: psi + 0.2 * np.sin(z), dict(method="newton", maxiter=1, hierarchy=None))}
    out = {}
    for name, (zeta, kw) in scenes.items():
        serial = nrmicp.solve(A, pb.q, zeta, **kw)
        local = zeta[lo:hi] if name == "nrm" else (lambda z: psi[lo:hi] + 0.2 * np.sin(z))
        r = dist.solve(mat(A, lo, hi), pb.q[lo:hi], local, **kw)
        out[name] = [str(serial.status), str(r.status), [h for h in _HINTS if h in serial.message],
                     [h for h in _HINTS if h in r.message]]
    return out


def case_rows_apart():
    """Random M-matrix LCPs whose rows lie 10^±8 apart (and the same times 1e-150), Newton's LU on the reduced
    systems (no hierarchy): PETSc's absolute zero-pivot test took the small rows' pivots for zeros (STAGNATED
    on one rank where serial nrmicp converges; a review's fuzz)."""
    out = {}
    for seed in range(6):
        rng = np.random.default_rng(seed)
        n = 174
        R = sp.random(n, n, density=4.0 / n, random_state=seed)
        R.data[:] = -np.abs(R.data)
        R.setdiag(0.0)
        M = sp.csr_matrix(R + sp.diags(np.abs(R).sum(axis=1).A.ravel() + rng.uniform(0.1, 2.0, n)))
        rows, q0 = 10.0 ** rng.uniform(-8, 8, n), rng.normal(size=n) * 10
        lo, hi = split(n)
        for s in (1.0, 1e-150):
            A, q = sp.csr_matrix(sp.diags(s * rows) @ M), s * rows * q0
            r = dist.solve(A[lo:hi], q[lo:hi], method="newton", hierarchy=None, rtol=1e-8)
            z = dist.gather(r.z)
            if RANK == 0:
                ref = nrmicp.solve(A, q, method="newton", hierarchy=None, rtol=1e-8)
                out[f"{seed} {s:g}"] = {"status": str(r.status), "serial": str(ref.status),
                                        "err": float(np.max(np.abs(z - ref.z)) / max(np.max(np.abs(ref.z)), 1e-300))}
    return out


#: Arguments one rank passes otherwise than the others (rank 0's, the others'): each took the ranks down different
#: branches of the core (a hang) before the agreement check of distributed.Solver and its solve.
DIFFERING = {"tol": ({"tol": 1e-4}, {"tol": 1e-12}), "maxiter": ({"maxiter": 1}, {"maxiter": 1000}),
             "rtol": ({"rtol": 1e-2}, {"rtol": 1e-10}), "stall_iterations": ({"stall_iterations": 3}, {}),
             "verbose": ({"verbose": 1}, {}), "method": ({"method": "nrmgs"}, {"method": "newton"}),
             "hierarchy": ({"hierarchy": "amg"}, {"hierarchy": None}), "accelerate": ({"accelerate": "anderson"}, {}),
             "record_history": ({"record_history": True}, {}), "callback": ({"callback": lambda zk: False}, {}),
             "zeta_jacobian": ({"zeta_jacobian": lambda z: sp.eye(len(z))}, {}), "x0": ({"x0": "zeros"}, {}),
             "zeta": ({"zeta": None}, {}), "upper": ({"upper": 10.0}, {})}
#: ... and arguments of each rank's own rows, which may differ (a diagonal's entries, x0's): solved.
ALIKE_ENOUGH = {"omega2": ({"omega2": "diag", "method": "nrmgs"}, {"omega2": "1.1 diag", "method": "nrmgs"}),
                "x0": ({"x0": "zeros"}, {"x0": "ones"})}


def case_differing():
    """Each DIFFERING argument: (exception type, message) on every rank, through one mpirun."""
    pb = obstacle_2d(15, exact=False)
    A = sp.csr_matrix(pb.A)
    lo, hi = split(A.shape[0])
    out = {"refused": {}, "solved": {}}
    for name, (mine, others), group in [(*kv, "refused") for kv in DIFFERING.items()] + \
            [(*kv, "solved") for kv in ALIKE_ENOUGH.items()]:
        kw = {"zeta": pb.zeta[lo:hi], "method": "newton", "tol": 1e-8, **(mine if RANK == 0 else others)}
        if "omega2" in kw:   # Ω2 = a multiple of A's (constant) diagonal, another on each rank
            kw["omega2"] = (1.1 if kw["omega2"] == "1.1 diag" else 1.0) * A[0, 0]
        if kw.get("x0") in ("zeros", "ones"):
            kw["x0"] = np.full(hi - lo, float(kw["x0"] == "ones"))
        if name == "zeta_jacobian":   # (a Jacobian is for a callable zeta: on every rank)
            kw["zeta"] = lambda z, psi=pb.zeta[lo:hi]: psi + 0.1 * np.sin(z)
        try:
            r = dist.solve(A[lo:hi], pb.q[lo:hi], **kw)
            outcome = ["no exception", str(r.status)]
        except Exception as exc:  # noqa: BLE001 - the outcome is the test's subject
            outcome = [type(exc).__name__, str(exc)]
        got = _allgather_text(json.dumps(outcome))
        out[group][name] = [json.loads(t) for t in got] if RANK == 0 else None
    try:   # a callback whose return has no truth value on one rank (the core's cast failed there alone: a hang)
        dist.solve(A[lo:hi], pb.q[lo:hi], pb.zeta[lo:hi], method="nrmgs", tol=1e-8,
                   callback=lambda zk: np.ones(2) if RANK == 0 else None)
        outcome = ["no exception", ""]
    except Exception as exc:  # noqa: BLE001 - the outcome is the test's subject
        outcome = [type(exc).__name__, str(exc)]
    got = _allgather_text(json.dumps(outcome))
    out["callback_return"] = [json.loads(t) for t in got] if RANK == 0 else None
    return out


if __name__ == "__main__":
    name, args = sys.argv[1], sys.argv[2:]
    result = {"agreement": lambda: case_agreement(), "partition": case_partition,
              "bad": lambda: case_bad(args[0], args[1]), "boomeramg": case_boomeramg, "dense": case_dense,
              "floor": case_floor, "overshoot": case_overshoot, "sweeps": case_sweeps,
              "warm": case_warm, "one_sided_contact": case_one_sided_contact, "implicit_upper": case_implicit_upper, "jacobian": case_jacobian, "jacobian_still_rows": case_jacobian_still_rows, "solver": case_solver, "units": case_units, "z_units": case_z_units, "engine": lambda: case_engine(*args), "options": case_options, "rounds": case_rounds, "shared_hierarchy": case_shared_hierarchy, "hazards": case_hazards,
              "fuzz": lambda: case_fuzz(int(args[0])), "family": case_family, "hooks": case_hooks, "no_rows": case_no_rows,
              "nonpositive_diagonal": case_nonpositive_diagonal,
              "upper_all_inf": case_upper_all_inf, "bounds_on_rank_0": case_bounds_on_rank_0,
              "base_exception": case_base_exception,
              "reason_alike": case_reason_alike, "hints": case_hints, "differing": case_differing,
              "rows_apart": case_rows_apart}[name]()
    if RANK == 0:
        print("RESULT " + json.dumps(result), flush=True)
