// nrmicp — the rows of a PETSc AIJ Mat that one process owns, read and written in place through their
// CSR arrays with global column numbers (an MPIAIJ Mat's diagonal and off-diagonal blocks, the latter's
// columns through its sorted global column list; a SeqAIJ Mat is all diagonal block), and the one
// exchange of entries between processes that the PETSc engine's own row-wise algorithms need
// (petsc/galerkin.hpp's update by K's change, petsc/symmetric.hpp's check).
#pragma once

#include <petscmat.h>

#include <Eigen/SparseCore>

#include <algorithm>
#include <cstddef>
#include <stdexcept>
#include <string>
#include <vector>

namespace nrmicp::petsc {

/// A PETSc call's error as an exception (PETSc has printed its trace already); the engine's one helper.
inline void check(PetscErrorCode e, const char* what) {
  if (e) throw std::runtime_error(std::string("PETSc: ") + what + " failed (PETSc error " + std::to_string(e) + ")");
}

/// M's stored entries over every process (every process decides alike; collective).
inline Eigen::Index global_nonzeros(Mat M) {
  MatInfo info;
  check(MatGetInfo(M, MAT_GLOBAL_SUM, &info), "MatGetInfo");
  return static_cast<Eigen::Index>(info.nz_used);
}

/// Which process owns global index g of a layout whose process p owns [ranges[p], ranges[p + 1]).
inline int owner_of(const PetscInt* ranges, int processes, PetscInt g) {
  return static_cast<int>(std::upper_bound(ranges, ranges + processes + 1, g) - ranges) - 1;
}

/// What every process sent to this one (all_to_all): source s's items are data[from[s], from[s + 1]).
template <typename T>
struct Received {
  std::vector<T> data;
  std::vector<std::size_t> from;
};

/// out[p] sent to process p, for every p, one collective call (trivially copyable items, sent as a
/// contiguous MPI type of sizeof(T) bytes: counts and offsets in items, so an int holds them).
template <typename T>
Received<T> all_to_all(MPI_Comm comm, const std::vector<std::vector<T>>& out) {
  int processes = 1;
  MPI_Comm_size(comm, &processes);
  const auto p = static_cast<std::size_t>(processes);
  std::vector<int> sent(p), got(p), sent_at(p, 0), got_at(p, 0);
  for (std::size_t r = 0; r < p; ++r) sent[r] = static_cast<int>(out[r].size());
  MPI_Alltoall(sent.data(), 1, MPI_INT, got.data(), 1, MPI_INT, comm);
  std::vector<T> send;
  for (std::size_t r = 0; r < p; ++r) {
    sent_at[r] = static_cast<int>(send.size());
    send.insert(send.end(), out[r].begin(), out[r].end());
  }
  Received<T> in;
  in.from.assign(p + 1, 0);
  for (std::size_t r = 0; r < p; ++r) {
    got_at[r] = static_cast<int>(in.from[r]);
    in.from[r + 1] = in.from[r] + static_cast<std::size_t>(got[r]);
  }
  in.data.resize(in.from[p]);
  MPI_Datatype item;
  MPI_Type_contiguous(static_cast<int>(sizeof(T)), MPI_BYTE, &item);
  MPI_Type_commit(&item);
  MPI_Alltoallv(send.data(), sent.data(), sent_at.data(), item, in.data.data(), got.data(), got_at.data(), item, comm);
  MPI_Type_free(&item);
  return in;
}

/// This process's rows of an assembled AIJ Mat, open while this object lives. A position numbers a
/// stored entry: the diagonal block's first, then the off-diagonal block's. `write`: the values may be
/// written (value()); the Mat is assembled again when this object goes (a new state: PETSc's
/// preconditioners see the values).
class LocalRows {
 public:
  LocalRows(Mat M, bool write) : M_(M), write_(write) {
    PetscBool mpi = PETSC_FALSE;
    PetscObjectBaseTypeCompare(reinterpret_cast<PetscObject>(M), MATMPIAIJ, &mpi);  // (subtypes too)
    d_.seq = M;
    if (mpi) check(MatMPIAIJGetSeqAIJ(M, &d_.seq, &o_.seq, &garray_), "MatMPIAIJGetSeqAIJ");
    check(MatGetOwnershipRange(M, &rstart_, nullptr), "MatGetOwnershipRange");
    check(MatGetOwnershipRangeColumn(M, &cstart_, &cend_), "MatGetOwnershipRangeColumn");
    open(d_);
    if (o_.seq) open(o_);
    if (o_.seq) check(MatGetSize(o_.seq, nullptr, &ngarray_), "MatGetSize");
  }
  LocalRows(const LocalRows&) = delete;
  LocalRows& operator=(const LocalRows&) = delete;
  ~LocalRows() {
    close(d_);
    if (o_.seq) close(o_);
    if (write_) {
      MatAssemblyBegin(M_, MAT_FINAL_ASSEMBLY);
      MatAssemblyEnd(M_, MAT_FINAL_ASSEMBLY);
    }
  }

  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, PetscInt>;
  PetscInt rows() const { return d_.rows; }
  /// The diagonal block (this process's rows and columns, local numbers; the whole Mat on one process).
  Eigen::Map<RowMatrix> diagonal_block() const {
    PetscInt cols = 0;
    MatGetSize(d_.seq, nullptr, &cols);
    return Eigen::Map<RowMatrix>(d_.rows, cols, nnz(d_), const_cast<PetscInt*>(d_.ia), const_cast<PetscInt*>(d_.ja), d_.va);
  }
  /// The first row (global) this process owns.
  PetscInt row_begin() const { return rstart_; }
  PetscInt nonzeros() const { return nnz(d_) + nnz(o_); }
  PetscScalar& value(PetscInt position) const {
    return position < nnz(d_) ? d_.va[position] : o_.va[position - nnz(d_)];
  }
  /// f(local row, global column, position) for every stored entry (diagonal block first).
  template <typename F>
  void for_each(F&& f) const {
    for (PetscInt i = 0; i < d_.rows; ++i)
      for (PetscInt p = d_.ia[i]; p < d_.ia[i + 1]; ++p) f(i, d_.ja[p] + cstart_, p);
    if (!o_.seq) return;
    for (PetscInt i = 0; i < o_.rows; ++i)
      for (PetscInt p = o_.ia[i]; p < o_.ia[i + 1]; ++p) f(i, garray_[o_.ja[p]], nnz(d_) + p);
  }
  /// f(local row, off, column, position) for every stored entry, row by row (each row's diagonal-block
  /// entries first): `off` false, the column is this process's (local number); true, the off-diagonal
  /// block's (its number among that block's columns: a ghost's, ghost_columns()).
  template <typename F>
  void for_each_local(F&& f) const {
    for (PetscInt i = 0; i < d_.rows; ++i) {
      for (PetscInt p = d_.ia[i]; p < d_.ia[i + 1]; ++p) f(i, false, d_.ja[p], p);
      if (o_.seq)
        for (PetscInt p = o_.ia[i]; p < o_.ia[i + 1]; ++p) f(i, true, o_.ja[p], nnz(d_) + p);
    }
  }
  /// f(local row, ghost, value) for every entry of the off-diagonal block (none on one process).
  template <typename F>
  void for_each_ghost(F&& f) const {
    if (!o_.seq) return;
    for (PetscInt i = 0; i < o_.rows; ++i)
      for (PetscInt p = o_.ia[i]; p < o_.ia[i + 1]; ++p) f(i, o_.ja[p], o_.va[p]);
  }
  /// The off-diagonal block's columns (global numbers, sorted; none on one process).
  const PetscInt* ghost_columns() const { return garray_; }
  /// The first column (global) of the diagonal block.
  PetscInt col_begin() const { return cstart_; }
  /// f(global column, value) for every stored entry of local row i.
  template <typename F>
  void for_row(PetscInt i, F&& f) const {
    for (PetscInt p = d_.ia[i]; p < d_.ia[i + 1]; ++p) f(d_.ja[p] + cstart_, d_.va[p]);
    if (!o_.seq) return;
    for (PetscInt p = o_.ia[i]; p < o_.ia[i + 1]; ++p) f(garray_[o_.ja[p]], o_.va[p]);
  }
  /// The position of (local row i, global column j), −1 when it is not stored.
  PetscInt find(PetscInt i, PetscInt j) const {
    if (j >= cstart_ && j < cend_) return search(d_, i, j - cstart_);
    if (!o_.seq) return -1;
    const PetscInt* at = std::lower_bound(garray_, garray_ + ngarray_, j);
    if (at == garray_ + ngarray_ || *at != j) return -1;
    const PetscInt p = search(o_, i, static_cast<PetscInt>(at - garray_));
    return p < 0 ? -1 : nnz(d_) + p;
  }
  /// Whether every process's rows have their columns sorted and distinct in both blocks, and the
  /// global column lists too (find searches them); collective, every process answers alike.
  bool sorted() const {
    int ok = (!o_.seq || std::is_sorted(garray_, garray_ + ngarray_)) && sorted(d_) && (!o_.seq || sorted(o_));
    MPI_Comm comm;
    PetscObjectGetComm(reinterpret_cast<PetscObject>(M_), &comm);
    MPI_Allreduce(MPI_IN_PLACE, &ok, 1, MPI_INT, MPI_LAND, comm);
    return ok != 0;
  }

 private:
  struct Block {
    Mat seq = nullptr;
    PetscInt rows = 0;
    const PetscInt *ia = nullptr, *ja = nullptr;
    PetscScalar* va = nullptr;
  };
  static PetscInt nnz(const Block& b) { return b.seq ? b.ia[b.rows] : 0; }
  static PetscInt search(const Block& b, PetscInt i, PetscInt c) {
    const PetscInt* at = std::lower_bound(b.ja + b.ia[i], b.ja + b.ia[i + 1], c);
    return at == b.ja + b.ia[i + 1] || *at != c ? -1 : static_cast<PetscInt>(at - b.ja);
  }
  static bool sorted(const Block& b) {
    for (PetscInt i = 0; i < b.rows; ++i)
      for (PetscInt p = b.ia[i] + 1; p < b.ia[i + 1]; ++p)
        if (b.ja[p - 1] >= b.ja[p]) return false;
    return true;
  }
  void open(Block& b) {
    PetscBool done = PETSC_FALSE;
    if (MatGetRowIJ(b.seq, 0, PETSC_FALSE, PETSC_FALSE, &b.rows, &b.ia, &b.ja, &done) || !done)
      throw std::runtime_error("PETSc: a matrix has no CSR arrays (an AIJ matrix is needed)");
    check(write_ ? MatSeqAIJGetArray(b.seq, &b.va) : MatSeqAIJGetArrayRead(b.seq, const_cast<const PetscScalar**>(&b.va)),
          "MatSeqAIJGetArray");
  }
  void close(Block& b) {
    PetscBool done;
    if (write_) MatSeqAIJRestoreArray(b.seq, &b.va);
    else MatSeqAIJRestoreArrayRead(b.seq, const_cast<const PetscScalar**>(&b.va));
    MatRestoreRowIJ(b.seq, 0, PETSC_FALSE, PETSC_FALSE, &b.rows, &b.ia, &b.ja, &done);
  }

  Mat M_;
  bool write_;
  Block d_, o_;                       // the diagonal block (this process's columns) and the rest
  const PetscInt* garray_ = nullptr;  // the off-diagonal block's columns, global, sorted
  PetscInt ngarray_ = 0;
  PetscInt rstart_ = 0, cstart_ = 0, cend_ = 0;
};

}  // namespace nrmicp::petsc
