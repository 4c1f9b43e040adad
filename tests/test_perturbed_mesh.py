"""P1 elements on a randomly perturbed triangulation of the unit square: the stiffness matrix is SPD but no
M-matrix (obtuse triangles give positive off-diagonals). The Newton member's projected sweeps after each step
(Globalized::kSmoothingSweeps) moved its active set back there, a 2-cycle that ended the solve STAGNATED at
n = 261,121 (Res 5.7e-8 against 8.3e-10); on a cycle the sweeps now stop and the steps go on without them.
Checked in numpy: the complementarity conditions, and the error against the plain primal-dual active-set
iteration (exact solves, no sweeps) run here to a settled set."""
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

import nrmicp


def perturbed_p1(m: int, seed: int = 0):
    """(A, q, ψ): −Δ by P1 elements on the (m + 1)² grid, interior nodes moved by up to 0.35 h, each square cut
    along a random diagonal; the load 8 (lumped mass) pushes the membrane onto ψ = 0.05 − |x − ½|²/2."""
    rng = np.random.default_rng(seed)
    x = np.linspace(0, 1, m + 1)
    P = np.c_[np.meshgrid(x, x)[0].ravel(), np.meshgrid(x, x)[1].ravel()]
    inner = (P[:, 0] > 0) & (P[:, 0] < 1) & (P[:, 1] > 0) & (P[:, 1] < 1)
    P[inner] += 0.35 / m * rng.uniform(-1, 1, (inner.sum(), 2))
    idx = np.arange((m + 1) ** 2).reshape(m + 1, m + 1)
    a, b, c, d = (idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel())
    flip = (rng.random(a.size) < 0.5)[:, None]
    T = np.r_[np.where(flip, np.c_[a, b, d], np.c_[a, b, c]), np.where(flip, np.c_[a, d, c], np.c_[b, d, c])]
    p = P[T]
    B = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=2)
    area = np.abs(B[:, 0, 0] * B[:, 1, 1] - B[:, 0, 1] * B[:, 1, 0]) / 2
    grads = np.einsum("ij,ejk->eik", np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]]), np.linalg.inv(B))
    Ke = np.einsum("eik,ejk->eij", grads, grads) * area[:, None, None]
    n = len(P)
    A = sp.csr_matrix((Ke.ravel(), (np.repeat(T, 3, axis=1).ravel(), np.tile(T, (1, 3)).ravel())), shape=(n, n))
    mass = np.bincount(T.ravel(), np.repeat(area / 3, 3), n)
    ii = np.flatnonzero(inner)
    A = sp.csr_matrix(A[ii][:, ii])
    A.sum_duplicates()
    xy = P[ii]
    return A, 8.0 * mass[ii], 0.05 - 0.5 * ((xy[:, 0] - 0.5) ** 2 + (xy[:, 1] - 0.5) ** 2)


def active_set_reference(A, q, psi, z):
    """The primal-dual active-set iteration from z with exact solves, to a settled set."""
    d = A.diagonal()
    active = (z - psi) <= (A @ z + q) / d
    for _ in range(50):
        y, free = psi.copy(), ~active
        y[free] = splu(sp.csc_matrix(A[free][:, free])).solve(-(q[free] + A[free][:, active] @ psi[active]))
        new = (y - psi) <= (A @ y + q) / d
        if np.array_equal(new, active):
            return y
        active = new
    raise AssertionError("the reference did not settle")


def test_newton_converges_on_p1_elements_of_a_perturbed_mesh():
    A, q, psi = perturbed_p1(512)
    assert (A - sp.diags(A.diagonal())).max() > 0   # no M-matrix
    r = nrmicp.solve(A, q, psi)
    assert r.success and r.path == "newton", r.message
    w = A @ r.z + q
    scale = np.max(abs(A) @ np.abs(r.z) + np.abs(q))   # (w's terms: their rounding is eps times this)
    assert np.all(r.z >= psi - 1e-12) and np.all(w >= -1e-10 * scale)
    assert np.max(np.abs(np.minimum(w, r.z - psi))) < 1e-10 * scale
    ref = active_set_reference(A, q, psi, r.z)
    assert np.max(np.abs(r.z - ref)) < 1e-8 * np.max(np.abs(ref))
