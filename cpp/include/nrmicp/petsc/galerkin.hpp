// nrmicp — the PETSc engine's Galerkin operators K_{l+1} = P_lᵀ K_l P_l of a Newton step's reduced
// system K (the serial engine's detail/galerkin.hpp, on PETSc Mats): PCMG's coarse operators, kept
// across Newton steps. K keeps A's pattern (MatZeroRowsColumns stores zeros), so each K_l keeps the
// pattern of its first MatPtAP: later steps recompute only the values (MatPtAP, MAT_REUSE_MATRIX) or,
// when K changed in few entries, add P_lᵀ ΔK_l P_l level by level — detail::GalerkinUpdate, the serial
// engine's update itself, on the Mats' CSR arrays (one process: a SeqAIJ Mat's arrays are its CSR).
// On several processes the rows of P and K_l that an update touches live on other processes too: the
// values are recomputed there (what PCMG's own Galerkin option does each step).
#pragma once

#include "../detail/galerkin.hpp"

#include <petscksp.h>

#include <Eigen/SparseCore>

#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace nrmicp::petsc {

/// The CSR arrays of a Mat on one process (SeqAIJ, or the diagonal block of an MPIAIJ on one process,
/// whose local columns are the global ones) as an Eigen row-major Map, open while this object lives;
/// `write`: the values are written (the Mat's state is increased when this object goes).
class CsrView {
 public:
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, PetscInt>;
  CsrView(Mat M, bool write) : write_(write) {
    PetscBool mpi = PETSC_FALSE;
    PetscObjectTypeCompare(reinterpret_cast<PetscObject>(M), MATMPIAIJ, &mpi);
    seq_ = M;
    if (mpi && MatMPIAIJGetSeqAIJ(M, &seq_, nullptr, nullptr)) throw std::runtime_error("PETSc: MatMPIAIJGetSeqAIJ failed");
    PetscBool done = PETSC_FALSE;
    if (MatGetRowIJ(seq_, 0, PETSC_FALSE, PETSC_FALSE, &rows_, &ia_, &ja_, &done) || !done)
      throw std::runtime_error("PETSc: a Galerkin operator has no CSR arrays (an AIJ matrix is needed)");
    PetscInt cols;
    MatGetSize(seq_, nullptr, &cols);
    cols_ = cols;
    const PetscErrorCode e = write ? MatSeqAIJGetArray(seq_, &va_)
                                   : MatSeqAIJGetArrayRead(seq_, const_cast<const PetscScalar**>(&va_));
    if (e) throw std::runtime_error("PETSc: MatSeqAIJGetArray failed");
    outer_ = M;
  }
  CsrView(const CsrView&) = delete;
  CsrView& operator=(const CsrView&) = delete;
  ~CsrView() {
    PetscBool done;
    if (write_) MatSeqAIJRestoreArray(seq_, &va_);  // (increases the state of the SeqAIJ)
    else MatSeqAIJRestoreArrayRead(seq_, const_cast<const PetscScalar**>(&va_));
    MatRestoreRowIJ(seq_, 0, PETSC_FALSE, PETSC_FALSE, &rows_, &ia_, &ja_, &done);
    if (write_) {  // a new state: the SOR smoothers' cached diagonals and the coarsest LU see the values
      MatAssemblyBegin(outer_, MAT_FINAL_ASSEMBLY);
      MatAssemblyEnd(outer_, MAT_FINAL_ASSEMBLY);
    }
  }
  Eigen::Map<RowMatrix> map() const {
    return Eigen::Map<RowMatrix>(rows_, cols_, ia_[rows_], const_cast<PetscInt*>(ia_), const_cast<PetscInt*>(ja_), va_);
  }
  /// Whether every row's columns are sorted and distinct (GalerkinUpdate searches them).
  bool sorted() const {
    for (PetscInt i = 0; i < rows_; ++i)
      for (PetscInt p = ia_[i] + 1; p < ia_[i + 1]; ++p)
        if (ja_[p - 1] >= ja_[p]) return false;
    return true;
  }

 private:
  Mat outer_ = nullptr, seq_ = nullptr;
  PetscInt rows_ = 0, cols_ = 0;
  const PetscInt *ia_ = nullptr, *ja_ = nullptr;
  PetscScalar* va_ = nullptr;
  bool write_;
};

/// K_1, ..., K_L of a fine K on the prolongations P_0, ..., P_{L-1} (finest first), as PETSc Mats.
class GalerkinOperators {
 public:
  using Changes = std::vector<detail::Change<PetscInt>>;

  /// `P`: the prolongations (alive while this object is); `serial`: the Mats live on one process.
  GalerkinOperators(std::vector<Mat> P, bool serial) : P_(std::move(P)), serial_(serial) {}
  GalerkinOperators(const GalerkinOperators&) = delete;
  GalerkinOperators& operator=(const GalerkinOperators&) = delete;
  ~GalerkinOperators() {
    for (Mat& C : C_) MatDestroy(&C);
  }

  /// K_{l+1}, l = 0, ..., levels − 1 (null before the first form).
  Mat K(std::size_t l) const { return C_.empty() ? nullptr : C_[l]; }
  std::size_t levels() const { return P_.size(); }

  /// The operators of `fine` (assembled, the pattern of the first call): formed by MatPtAP the first
  /// time (returns true: the Mats are new), then updated by fine's changed entries since the last
  /// form when they are few (GalerkinUpdate::max_changes; one process), else their values recomputed.
  bool form(Mat fine) {
    if (C_.empty()) {
      C_.resize(P_.size(), nullptr);
      for (std::size_t l = 0; l < P_.size(); ++l)
        check(MatPtAP(l ? C_[l - 1] : fine, P_[l], MAT_INITIAL_MATRIX, 2.0, &C_[l]), "MatPtAP");
      updatable_ = serial_ && sorted();
      if (updatable_) remember(fine);
      return true;
    }
    if (!(updatable_ && update(fine)))
      for (std::size_t l = 0; l < P_.size(); ++l)
        check(MatPtAP(l ? C_[l - 1] : fine, P_[l], MAT_REUSE_MATRIX, 2.0, &C_[l]), "MatPtAP");
    return false;
  }

 private:
  static void check(PetscErrorCode e, const char* what) {
    if (e) throw std::runtime_error(std::string("PETSc: ") + what + " failed (PETSc error " + std::to_string(e) + ")");
  }
  /// Every K_l's rows sorted (MatPtAP's are; GalerkinUpdate needs it).
  bool sorted() const {
    for (Mat C : C_)
      if (!CsrView(C, false).sorted()) return false;
    return true;
  }
  /// fine's values, the reference of the next form's changes.
  void remember(Mat fine) {
    const CsrView K(fine, false);
    const auto k = K.map();
    previous_.assign(k.valuePtr(), k.valuePtr() + k.nonZeros());
  }
  /// The update by fine's changed entries (GalerkinUpdate::apply); false when there are too many
  /// or a term falls outside a level's pattern (then recompute them all). Remembers fine either way.
  bool update(Mat fine) {
    bool few = true;
    Eigen::Index nnz;
    {
      const CsrView K(fine, false);
      const auto k = K.map();
      nnz = k.nonZeros();
      if (static_cast<std::size_t>(nnz) != previous_.size()) throw std::logic_error("GalerkinOperators: K's pattern changed");
      const std::size_t most = detail::GalerkinUpdate<PetscInt>::max_changes(nnz);
      const PetscInt *outer = k.outerIndexPtr(), *col = k.innerIndexPtr();
      const double* v = k.valuePtr();
      changes_.clear();
      for (PetscInt i = 0; i < k.rows(); ++i)
        for (PetscInt p = outer[i]; p < outer[i + 1]; ++p) {
          if (v[p] == previous_[p]) continue;
          if (few) changes_.push_back({i, col[p], v[p] - previous_[p]});
          few = few && changes_.size() <= most;
          previous_[p] = v[p];
        }
    }
    if (!few) return false;
    std::vector<std::unique_ptr<CsrView>> Ps, Cs;  // open while the update runs
    for (std::size_t l = 0; l < P_.size(); ++l) {
      Ps.push_back(std::make_unique<CsrView>(P_[l], false));
      Cs.push_back(std::make_unique<CsrView>(C_[l], true));
    }
    return update_.apply(changes_, nnz, P_.size(), [&](std::size_t l) { return Ps[l]->map(); },
                         [&](std::size_t l) { return Cs[l]->map(); });
  }

  std::vector<Mat> P_;
  std::vector<Mat> C_;
  bool serial_;
  bool updatable_ = false;           // one process, sorted rows: form may update
  std::vector<double> previous_;     // the fine K's values at the last form (updatable_)
  Changes changes_;
  detail::GalerkinUpdate<PetscInt> update_;
};

}  // namespace nrmicp::petsc
