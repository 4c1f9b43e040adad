"""A P-matrix LCP on which the plain active-set (Newton-min) iteration cycles.

Not a physical model: a test of globalization. For an M-matrix the primal–dual active-set
method — Newton on min(w, z) = 0, which is what ``method="newton"`` does on an LCP — stops
after finitely many steps from any start. For a P-matrix the LCP still has a unique
solution, but the plain iteration can cycle (Ben Gharbia & Gilbert 2012 show it for n ≥ 3).
The 4 × 4 block

    M = [[1, 0, 3, 0],
         [3, 1, 0, 0],
         [0, 3, 1, 2],
         [3, 0, 0, 1]],   q = (1, −2, −3, 2)

has positive off-diagonal entries, every principal minor positive (a P-matrix), and is
neither an M-matrix nor an H+-matrix (its comparison matrix has a negative entry in its
inverse). The solution is z* = (0, 2, 0, 0), w* = (1, 0, 3, 2), strictly complementary.
The active-set iteration (active = {z_i < w_i}) cycles with period 3 through the active sets
{0, 3}, {2, 3}, {0, 2} from 14 of the 16 starting active sets, among them the cold start
z = 0 (active = {q > 0} = {0, 3}) and "all active"; only "none active" and the solution's
own set {0, 2, 3} reach z*. The stationary NRM members solve it in 1–3 iterations.

The scene stacks ``blocks`` copies along the diagonal, block k scaled by s_k = 1 + k/blocks
(q_k = s_k q, so z*_k = s_k z*): the cycle is the same in every block.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from . import Problem
from ._operators import as_csr

CYCLING_BLOCK = np.array([[1.0, 0.0, 3.0, 0.0],
                          [3.0, 1.0, 0.0, 0.0],
                          [0.0, 3.0, 1.0, 2.0],
                          [3.0, 0.0, 0.0, 1.0]])
CYCLING_Q = np.array([1.0, -2.0, -3.0, 2.0])
CYCLING_Z = np.array([0.0, 2.0, 0.0, 0.0])


def p_matrix_cycling(blocks: int = 1) -> Problem:
    """Block-diagonal LCP of ``blocks`` copies of the cycling 4 × 4 P-matrix block (see the
    module docstring); n = 4·blocks, ζ ≡ 0, ``z_exact`` known by construction."""
    if blocks < 1:
        raise ValueError(f"blocks must be >= 1, got {blocks}")
    s = 1.0 + np.arange(blocks) / blocks
    A = as_csr(sp.kron(sp.identity(blocks), sp.csr_matrix(CYCLING_BLOCK)))
    q = np.kron(s, CYCLING_Q)
    return Problem(
        name=f"p_matrix_cycling(blocks={blocks})", A=A, q=q, zeta=None,
        z_exact=np.kron(s, CYCLING_Z),
        reference={"block": CYCLING_BLOCK.copy(), "scales": s},
        description=f"P-matrix (not M, not H+) LCP on which plain active-set Newton cycles, n={4 * blocks}",
        models=("P-matrix LCP with positive off-diagonal entries and a unique solution",),
        omits=("any physical model: a globalization test",),
        lipschitz=0.0)
