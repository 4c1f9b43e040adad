"""Threads and signals: the C++ loop releases the GIL, gives thread-independent answers, and
stops promptly on Ctrl-C (SIGINT -> KeyboardInterrupt)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import scipy.sparse as sp

import nrmicp


def laplacian(m):
    T = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
    I = sp.identity(m)
    return sp.csr_matrix(sp.kron(I, T) + sp.kron(T, I))


def problems():
    rng = np.random.default_rng(0)
    out = []
    for m, method, kind in ((20, "nrmgs", "lcp"), (24, "nrm", "icp"), (16, "two_sweep", "obstacle"),
                            (22, "nrmsor", "affine")):
        A = sp.csr_matrix(laplacian(m) + 0.5 * sp.identity(m * m))
        n = m * m
        q = rng.uniform(-1, 1, n)
        c = rng.uniform(-0.5, 0.5, n)
        zeta = {"lcp": None, "icp": (lambda z, c=c: 0.05 * np.sin(z) + c), "obstacle": c,
                "affine": nrmicp.Affine(sp.csr_matrix(0.05 * sp.eye(n, k=1)), c)}[kind]
        opts = dict(method=method, accelerate="anderson" if kind == "icp" else "none")
        if method == "nrmsor":
            opts["alpha"] = 1.2
        out.append((A, q, zeta, opts))
    return out


def test_threads_give_the_serial_answers():
    probs = problems()
    serial = [nrmicp.solve(A, q, zeta, **o) for A, q, zeta, o in probs]
    for workers in (2, 4):
        with ThreadPoolExecutor(workers) as pool:
            futures = [pool.submit(nrmicp.solve, A, q, zeta, **o) for A, q, zeta, o in probs * 2]
            results = [f.result() for f in futures]
        for r, s in zip(results, serial * 2):
            assert r.success and s.success
            np.testing.assert_array_equal(r.z, s.z)
            assert r.nit == s.nit


def test_one_solver_shared_by_threads():
    A, q, zeta, o = problems()[0]
    rng = np.random.default_rng(1)
    qs = [rng.uniform(-1, 1, A.shape[0]) for _ in range(6)]
    serial = [nrmicp.Solver(A, method="nrm").solve(qq, z_update="solve").z for qq in qs]
    # a fresh Solver: the threads race on the lazy factorization of A (z_update="solve")
    s = nrmicp.Solver(A, method="nrm")
    with ThreadPoolExecutor(3) as pool:
        par = list(pool.map(lambda qq: s.solve(qq, z_update="solve").z, qs))
    for a, b in zip(par, serial):
        np.testing.assert_array_equal(a, b)


def _long_solve_args(m=150):
    A = laplacian(m)
    return A, -np.ones(m * m), dict(method="nrmj", tol=1e-300, stall_iterations=10**6)


def test_gil_is_released_during_the_solve():
    """While the worker thread is inside the C++ loop, this thread keeps running Python code.
    With the GIL held, this thread would only get it at the ~50 ms signal polls."""
    A, q, opts = _long_solve_args()
    # calibrate: a solve of roughly 0.5-1 s
    t0 = time.perf_counter()
    nrmicp.solve(A, q, maxiter=200, **opts)
    per_it = (time.perf_counter() - t0) / 200
    maxiter = int(min(20000, max(1000, 0.8 / per_it)))

    started = threading.Event()
    done = threading.Event()
    result = {}

    def worker():
        started.set()
        result["r"] = nrmicp.solve(A, q, maxiter=maxiter, **opts)
        done.set()

    th = threading.Thread(target=worker)
    th.start()
    started.wait()
    time.sleep(0.05)  # let the worker enter the C++ loop
    count = 0
    gaps = []
    last = time.perf_counter()
    while not done.is_set():
        count += 1
        now = time.perf_counter()
        gaps.append(now - last)
        last = now
    th.join()
    assert result["r"].status == nrmicp.Status.MAX_ITERATIONS
    # this thread made progress all along: many increments, and no long freezes
    assert count > 1000, count
    gaps.sort()
    median_gap = gaps[len(gaps) // 2]
    assert median_gap < 0.01, f"median gap between increments {median_gap:.4f} s: the GIL looks held"


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT delivery differs on Windows")
def test_sigint_stops_a_long_solve_promptly(tmp_path):
    script = tmp_path / "long_solve.py"
    script.write_text(textwrap.dedent("""
        import sys
        import numpy as np, scipy.sparse as sp, nrmicp
        m = 150
        T = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
        I = sp.identity(m)
        A = sp.csr_matrix(sp.kron(I, T) + sp.kron(T, I))
        print("start", flush=True)
        nrmicp.solve(A, -np.ones(m * m), method="nrmj", tol=1e-300, maxiter=10**8, stall_iterations=10**6)
        print("finished", flush=True)
    """))
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        assert proc.stdout.readline().strip() == "start"
        time.sleep(1.0)
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"the long solve ended on its own (exit {proc.returncode}): {out}{err}")
        t0 = time.perf_counter()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
        elapsed = time.perf_counter() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert elapsed < 5, f"took {elapsed:.1f} s to stop"
    assert proc.returncode != 0
    assert "KeyboardInterrupt" in err, err
    assert "finished" not in out
