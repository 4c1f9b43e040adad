"""The distributed benchmarks' partition: each rank's contiguous block of A's rows as an MPIAIJ Mat."""


def petsc_rows(A, comm):
    """(M, lo, hi): rows lo:hi of the scipy matrix A on this rank (an even split), as a PETSc Mat."""
    from petsc4py import PETSc
    n = A.shape[0]
    rank, size = comm.getRank(), comm.getSize()
    lo, hi = rank * n // size, (rank + 1) * n // size
    B = A[lo:hi]
    M = PETSc.Mat().createAIJ(size=((hi - lo, PETSc.DECIDE), (hi - lo, PETSc.DECIDE)),
                              csr=(B.indptr.astype(PETSc.IntType), B.indices.astype(PETSc.IntType), B.data), comm=comm)
    return M, lo, hi
