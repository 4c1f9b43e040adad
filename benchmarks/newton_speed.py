#!/usr/bin/env python
"""Before/after timing of method="newton" on the 2D obstacle, alternating, in one run.

    OPENBLAS_NUM_THREADS=1 python benchmarks/newton_speed.py --before /path/to/site-packages-copy \
        --m 255 511 1023 [--psor-max-m 511]

`--before DIR`: a directory holding an older installed ``nrmicp`` package (e.g. a copy of the
venv's site-packages/nrmicp made before rebuilding); it is put first on PYTHONPATH for the
"before" runs, the current install is "after". Each case (m, hierarchy geometric / amg) runs
before and after alternately in fresh subprocesses (benchmarks/mesh_independent.py's child:
CPU seconds of the child, wall seconds, finest steps, linear solves, Res), then red-black PSOR
(the best stationary peer) for the ratio. Timings on a shared machine are noisy: compare within
a row.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
CHILD = os.path.join(HERE, "mesh_independent.py")


def run(peer, m, before=None, budget=600.0):
    env = dict(os.environ)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    if before:
        env["PYTHONPATH"] = before + os.pathsep + env.get("PYTHONPATH", "")
    cmd = [sys.executable, CHILD, "--child", json.dumps([peer, "2d", m, 1e-8, budget])]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd="/tmp", timeout=3 * budget)
    if out.returncode:
        return dict(status=f"failed: {out.stderr.strip().splitlines()[-1:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def show(label, m, r):
    print(f"m={m:5d} {label:18s} {r.get('status', '?'):10s} cpu {r.get('cpu_seconds', float('nan')):7.2f} s "
          f"wall {r.get('seconds', float('nan')):7.2f} s steps {r.get('steps')} solves {r.get('solves')} "
          f"Res {r.get('res', float('nan')):.1e} {r.get('note', '')}", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", required=True, help="directory holding the older nrmicp package")
    ap.add_argument("--m", type=int, nargs="+", default=[255, 511, 1023])
    ap.add_argument("--psor-max-m", type=int, default=1023)
    ap.add_argument("--repeat", type=int, default=1)
    a = ap.parse_args()
    for m in a.m:
        for peer in ("newton-geo", "newton-amg"):
            for _ in range(a.repeat):
                show(f"{peer} before", m, run(peer, m, a.before))
                show(f"{peer} after", m, run(peer, m))
        if m <= a.psor_max_m:
            show("psor", m, run("psor", m))


if __name__ == "__main__":
    main()
