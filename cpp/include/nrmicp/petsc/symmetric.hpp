// nrmicp — the serial rule for "A is symmetric" (detail::is_symmetric: ‖M − Mᵀ‖_F ≤ 1e-14 ‖M‖_F, a
// mirror that is not stored counting as 0) on a PETSc AIJ Mat. PETSc's MatIsSymmetric applies another
// rule (each entry within an absolute tolerance) and on several processes gathers the off-process
// blocks as submatrices (MatIsTranspose: more than a V-cycle's set-up at a million rows;
// docs/MEASUREMENTS.md). Here each process reads its own rows, an entry whose mirror another
// process owns is sent to it (one exchange of the off-diagonal blocks' entries), two sums are reduced.
#pragma once

#include "../inner_solver.hpp"
#include "local_rows.hpp"

#include <petscmat.h>

#include <Eigen/SparseCore>

#include <cmath>
#include <vector>

namespace nrmicp::petsc {

/// detail::is_symmetric's rule for an assembled AIJ Mat, every process deciding alike (collective).
/// On one process, detail::is_symmetric itself on the Mat's CSR arrays.
inline bool is_symmetric(Mat M) {
  MPI_Comm comm;
  PetscObjectGetComm(reinterpret_cast<PetscObject>(M), &comm);
  int processes = 1, rank = 0;
  MPI_Comm_size(comm, &processes);
  MPI_Comm_rank(comm, &rank);
  PetscInt rows, cols;
  MatGetSize(M, &rows, &cols);
  if (rows != cols) return false;
  const LocalRows K(M, false);
  if (!K.sorted()) throw std::runtime_error("PETSc: is_symmetric needs each row's columns sorted (an assembled AIJ Mat)");
  if (processes == 1) return detail::is_symmetric(K.diagonal_block());
  struct Entry {
    PetscInt row, col;  // the mirror's position (its row is the receiver's)
    double value;
  };
  const PetscInt* ranges;
  MatGetOwnershipRanges(M, &ranges);
  const PetscInt lo = ranges[rank], hi = ranges[rank + 1];
  double sums[2] = {0, 0};  // ‖M − Mᵀ‖_F², ‖M‖_F²: each entry's visit adds (m_ij − m_ji)², 2 m_ij² unmirrored
  auto visit = [&](PetscInt i, PetscInt j, double v) {  // (i, j): the mirror's position, a row of this process
    const PetscInt p = K.find(i - lo, j);
    const double d = p < 0 ? 0.0 : v - K.value(p);
    sums[0] += p < 0 ? 2 * v * v : d * d;
  };
  std::vector<std::vector<Entry>> out(static_cast<std::size_t>(processes));
  K.for_each([&](PetscInt i, PetscInt j, PetscInt p) {
    const double v = K.value(p);
    sums[1] += v * v;
    if (j >= lo && j < hi) visit(j, lo + i, v);
    else out[static_cast<std::size_t>(owner_of(ranges, processes, j))].push_back({j, lo + i, v});
  });
  for (const Entry& e : all_to_all(comm, out).data) visit(e.row, e.col, e.value);
  MPI_Allreduce(MPI_IN_PLACE, sums, 2, MPI_DOUBLE, MPI_SUM, comm);
  return detail::symmetric_within_rounding(sums[0], sums[1]);
}

}  // namespace nrmicp::petsc
