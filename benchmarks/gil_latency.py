"""How freely another thread runs Python while a solve is in the C++ loop, and how fast Ctrl-C
stops a solve: latencies, so they are measured here and not asserted in tests/ (which check the
same properties without a clock, tests/test_concurrency.py).

    OPENBLAS_NUM_THREADS=1 python benchmarks/gil_latency.py [--m 150] [--maxiter 3000]
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import scipy.sparse as sp

import nrmicp


def laplacian(m):
    T = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
    I = sp.identity(m)
    return sp.csr_matrix(sp.kron(I, T) + sp.kron(T, I))


def gil_gaps(m, maxiter):
    """Gaps between increments of a Python counter in this thread while another solves."""
    A, q = laplacian(m), -np.ones(m * m)
    done, gaps = threading.Event(), []
    th = threading.Thread(target=lambda: (nrmicp.solve(A, q, method="nrmj", tol=1e-300, maxiter=maxiter,
                                                        stall_iterations=10**6), done.set()))
    th.start()
    last = time.perf_counter()
    while not done.is_set():
        now = time.perf_counter()
        gaps.append(now - last)
        last = now
    th.join()
    return np.array(gaps)


def sigint_latency(m):
    code = textwrap.dedent(f"""
        import numpy as np, scipy.sparse as sp, nrmicp
        m = {m}
        T = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
        A = sp.csr_matrix(sp.kron(sp.identity(m), T) + sp.kron(T, sp.identity(m)))
        print("start", flush=True)
        nrmicp.solve(A, -np.ones(m * m), method="nrmj", tol=1e-300, maxiter=10**8, stall_iterations=10**6)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.readline()
    time.sleep(1.0)  # well inside the loop
    t0 = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--m", type=int, default=150)
    ap.add_argument("--maxiter", type=int, default=3000)
    a = ap.parse_args()
    g = gil_gaps(a.m, a.maxiter)
    print(f"GIL: {g.size} increments beside a {a.maxiter}-iteration solve (n = {a.m * a.m}); "
          f"median gap {np.median(g) * 1e6:.2f} us, max {g.max() * 1e3:.2f} ms")
    print(f"Ctrl-C: the solve stopped {sigint_latency(a.m) * 1e3:.1f} ms after SIGINT")


if __name__ == "__main__":
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    main()
