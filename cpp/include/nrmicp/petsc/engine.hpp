// nrmicp — the PETSc engine of the Newton driver (detail/engine.hpp lists the operations): the
// Newton member over MPI with nrmicp::Newton<nrmicp::petsc::Matrix>, the same driver as the serial
// one. A petsc::Matrix is a distributed AIJ Mat; the driver's vectors (Eigen) hold the rows this
// process owns, so every row-wise decision is the serial code, and only the reductions
// (petsc::MpiComm), the products (MatMult), the reduced step's solve (KSP: the serial V-cycle in PCMG,
// or LU) and the level's sweeps and fallback (on the process's diagonal block, the
// couplings to other processes' rows held) are PETSc's.
// Needs PETSc (3.18 or later) with hypre; include it before any nrmicp header that instantiates
// Newton<petsc::Matrix> (nrmicp/petsc.hpp does).
#pragma once

#include "../detail/active_set.hpp"
#include "../detail/box.hpp"
#include "../detail/comm.hpp"
#include "../detail/newton_level.hpp"
#include "../options.hpp"
#include "../result.hpp"
#include "../solver.hpp"
#include "../zeta.hpp"
#include "galerkin.hpp"
#include "symmetric.hpp"

#include <petscksp.h>

#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace nrmicp::petsc {

/// The reductions over an MPI communicator (detail::Comm).
class MpiComm : public detail::Comm {
 public:
  explicit MpiComm(MPI_Comm c) : c_(c) { MPI_Comm_size(c, &size_); }
  void sum(double* v, int n) const override { MPI_Allreduce(MPI_IN_PLACE, v, n, MPI_DOUBLE, MPI_SUM, c_); }
  void sum(std::uint64_t* v, int n) const override { MPI_Allreduce(MPI_IN_PLACE, v, n, MPI_UINT64_T, MPI_SUM, c_); }
  /// A NaN on any process is the maximum (as lpNorm keeps it serially; MPI_MAX leaves NaN undefined).
  void max(double* v, int n) const override {
    std::vector<double> t(2 * static_cast<std::size_t>(n));
    for (int i = 0; i < n; ++i) {
      t[2 * i] = std::isnan(v[i]) ? -std::numeric_limits<double>::infinity() : v[i];
      t[2 * i + 1] = std::isnan(v[i]) ? 1.0 : 0.0;
    }
    MPI_Allreduce(MPI_IN_PLACE, t.data(), 2 * n, MPI_DOUBLE, MPI_MAX, c_);
    for (int i = 0; i < n; ++i) v[i] = t[2 * i + 1] > 0 ? std::numeric_limits<double>::quiet_NaN() : t[2 * i];
  }
  int size() const override { return size_; }
  MPI_Comm get() const { return c_; }

 private:
  MPI_Comm c_;
  int size_ = 1;
};

/// v's array is `data` while this object lives (VecPlaceArray), and v's own again after (VecResetArray),
/// also when a PETSc call in between throws: v stays usable for the next product or solve.
class PlacedArray {
 public:
  PlacedArray(Vec v, const double* data) : v_(v) { check(VecPlaceArray(v, data), "VecPlaceArray"); }
  ~PlacedArray() { VecResetArray(v_); }
  PlacedArray(const PlacedArray&) = delete;
  PlacedArray& operator=(const PlacedArray&) = delete;

 private:
  Vec v_;
};

/// A distributed AIJ matrix (a reference to the caller's Mat, which it keeps alive): rows()/cols()
/// are this process's, as the driver's vectors are. Copies share the Mat and its work vectors.
class Matrix {
 public:
  using StorageIndex = PetscInt;
  using Block = Eigen::Map<const Eigen::SparseMatrix<double, Eigen::RowMajor, PetscInt>>;
  static constexpr bool IsRowMajor = false;  // rows are reached through sweep_rows, not Eigen's iterators

  Matrix() = default;
  /// Takes a reference to `A` (released when the last copy goes).
  explicit Matrix(Mat A) : s_(std::make_shared<State>(A)) {}

  Mat get() const { return s_ ? s_->A : nullptr; }
  Eigen::Index rows() const { return s_ ? s_->m : 0; }
  Eigen::Index cols() const { return s_ ? s_->n : 0; }
  Eigen::Index row_offset() const { return s_ ? s_->lo : 0; }
  const MpiComm& comm() const { return *s_->comm; }
  void swap(Matrix& other) noexcept { s_.swap(other.s_); }

  /// out = A v (add: out += A v).
  void multiply(const Eigen::VectorXd& v, Eigen::VectorXd& out, bool add = false) const {
    if (!add) out.resize(rows());
    State& s = *s_;
    const PlacedArray x(s.x, v.data()), y(s.y, out.data());
    check(add ? MatMultAdd(s.A, s.x, s.y, s.y) : MatMult(s.A, s.x, s.y), "MatMult");
  }
  /// out += |A| v, read off A's own rows (a copy |A| cost more than the products: docs/MEASUREMENTS.md);
  /// the off-diagonal block's columns of v from their owners.
  void abs_multiply_add(const Eigen::VectorXd& v, Eigen::VectorXd& out) const {
    const Eigen::VectorXd ghost = ghosts(v);
    const LocalRows rows(get(), false);
    rows.for_each_local([&](PetscInt i, bool off, PetscInt c, PetscInt p) {
      out[i] += std::abs(rows.value(p)) * (off ? ghost[c] : v[c]);
    });
  }
  /// v (this process's entries of a vector in A's column layout) at the off-diagonal block's columns,
  /// LocalRows::ghost_columns (gathered from their owners; empty on one process). Collective.
  Eigen::VectorXd ghosts(const Eigen::VectorXd& v) const { return s_->ghosts(v); }
  /// The diagonal block (this process's rows and columns; the whole matrix on one process), a view
  /// valid while this Matrix lives and its values do not change.
  Block block() const {
    State& s = *s_;
    if (!s.block_ready) s.open_block();
    return Block(s.m, s.m, s.block_nnz, s.ia, s.ja, s.va);
  }
  /// c = A v − (diagonal block) v: the couplings of this process's rows to other processes' unknowns
  /// (zero on one process, not computed).
  Eigen::VectorXd coupling(const Eigen::VectorXd& v) const {
    Eigen::VectorXd c = Eigen::VectorXd::Zero(rows());
    if (comm().size() == 1) return c;
    const Eigen::VectorXd ghost = ghosts(v);  // (the off-diagonal block's product alone: not A v − block v)
    LocalRows(get(), false).for_each_ghost([&](PetscInt i, PetscInt k, double a) { c[i] += a * ghost[k]; });
    return c;
  }
  Eigen::VectorXd diagonal() const {
    Eigen::VectorXd d(rows());
    Vec v;
    check(MatCreateVecs(get(), nullptr, &v), "MatCreateVecs");
    check(MatGetDiagonal(get(), v), "MatGetDiagonal");
    copy_out(v, d);
    VecDestroy(&v);
    return d;
  }
  /// max_j |a_ij| of this process's rows.
  Eigen::VectorXd row_max_abs() const {
    Eigen::VectorXd d(rows());
    Vec v;
    check(MatCreateVecs(get(), nullptr, &v), "MatCreateVecs");
    check(MatGetRowMaxAbs(get(), v, nullptr), "MatGetRowMaxAbs");
    copy_out(v, d);
    VecDestroy(&v);
    return d;
  }
  /// Whether A is symmetric to rounding: the serial engine's rule (petsc/symmetric.hpp). Collective.
  bool symmetric() const { return is_symmetric(get()); }

 private:
  static void copy_out(Vec v, Eigen::VectorXd& d) {
    const PetscScalar* a;
    check(VecGetArrayRead(v, &a), "VecGetArrayRead");
    std::copy_n(a, d.size(), d.data());
    VecRestoreArrayRead(v, &a);
  }
  struct State {
    Mat A = nullptr;
    Vec x = nullptr, y = nullptr;  // work vectors whose arrays are the driver's (VecPlaceArray)
    PetscInt m = 0, n = 0, lo = 0;
    std::unique_ptr<MpiComm> comm;
    VecScatter gather = nullptr;  // v's entries at the off-diagonal block's columns (ghosts), formed on first use
    Vec ghost = nullptr;
    Mat Ad = nullptr;  // the diagonal block, its CSR arrays open while the State lives
    const PetscInt *ia = nullptr, *ja = nullptr;
    const PetscScalar* va = nullptr;
    PetscInt block_nnz = 0;
    bool block_ready = false;

    explicit State(Mat a) : A(a) {
      check(PetscObjectReference(reinterpret_cast<PetscObject>(A)), "PetscObjectReference");
      check(MatGetLocalSize(A, &m, &n), "MatGetLocalSize");
      check(MatGetOwnershipRange(A, &lo, nullptr), "MatGetOwnershipRange");
      MPI_Comm c;
      check(PetscObjectGetComm(reinterpret_cast<PetscObject>(A), &c), "PetscObjectGetComm");
      comm = std::make_unique<MpiComm>(c);
      check(MatCreateVecs(A, &x, &y), "MatCreateVecs");
    }
    /// v (this process's columns) at the off-diagonal block's columns (empty without that block).
    Eigen::VectorXd ghosts(const Eigen::VectorXd& v) {
      if (!gather && !scatter_ghosts()) return {};
      {
        const PlacedArray placed(x, v.data());
        check(VecScatterBegin(gather, x, ghost, INSERT_VALUES, SCATTER_FORWARD), "VecScatterBegin");
        check(VecScatterEnd(gather, x, ghost, INSERT_VALUES, SCATTER_FORWARD), "VecScatterEnd");
      }
      PetscInt k;
      const PetscScalar* g;
      VecGetLocalSize(ghost, &k);
      check(VecGetArrayRead(ghost, &g), "VecGetArrayRead");
      Eigen::VectorXd out = Eigen::Map<const Eigen::VectorXd>(g, k);
      VecRestoreArrayRead(ghost, &g);
      return out;
    }
    /// The scatter of ghosts (false on a SeqAIJ Mat: none).
    bool scatter_ghosts() {
      PetscBool mpi = PETSC_FALSE;
      PetscObjectBaseTypeCompare(reinterpret_cast<PetscObject>(A), MATMPIAIJ, &mpi);  // (subtypes too)
      if (!mpi) return false;
      Mat Ad, Ao;
      const PetscInt* columns;
      PetscInt k;
      check(MatMPIAIJGetSeqAIJ(A, &Ad, &Ao, &columns), "MatMPIAIJGetSeqAIJ");
      check(MatGetSize(Ao, nullptr, &k), "MatGetSize");
      IS is;
      check(ISCreateGeneral(PETSC_COMM_SELF, k, columns, PETSC_COPY_VALUES, &is), "ISCreateGeneral");
      check(VecCreateSeq(PETSC_COMM_SELF, k, &ghost), "VecCreateSeq");
      const PetscErrorCode e = VecScatterCreate(x, is, ghost, nullptr, &gather);
      ISDestroy(&is);
      check(e, "VecScatterCreate");
      return true;
    }
    void open_block() {
      check(MatGetDiagonalBlock(A, &Ad), "MatGetDiagonalBlock");
      PetscInt rows;
      PetscBool done;
      check(MatGetRowIJ(Ad, 0, PETSC_FALSE, PETSC_FALSE, &rows, &ia, &ja, &done), "MatGetRowIJ");
      if (!done) throw std::runtime_error("PETSc: the diagonal block has no CSR arrays (an AIJ matrix is needed)");
      check(MatSeqAIJGetArrayRead(Ad, &va), "MatSeqAIJGetArrayRead");
      block_nnz = ia[rows];
      block_ready = true;
    }
    ~State() {
      if (block_ready) {
        PetscInt rows;
        PetscBool done;
        MatSeqAIJRestoreArrayRead(Ad, &va);
        MatRestoreRowIJ(Ad, 0, PETSC_FALSE, PETSC_FALSE, &rows, &ia, &ja, &done);
      }
      VecDestroy(&x);
      VecDestroy(&y);
      VecScatterDestroy(&gather);
      VecDestroy(&ghost);
      MatDestroy(&A);
    }
  };
  std::shared_ptr<State> s_;
};

// ---- the engine's free operations (detail/engine.hpp), found by argument-dependent lookup
inline const detail::Comm& comm_of(const Matrix& A) { return A.comm(); }
inline Eigen::Index row_offset(const Matrix& A) { return A.row_offset(); }
inline Eigen::Index global_rows(const Matrix& A) {
  PetscInt m;
  check(MatGetSize(A.get(), &m, nullptr), "MatGetSize");
  return m;
}
inline Eigen::Index global_cols(const Matrix& A) {
  PetscInt n;
  check(MatGetSize(A.get(), nullptr, &n), "MatGetSize");
  return n;
}
inline void multiply(const Matrix& A, const Eigen::VectorXd& v, Eigen::VectorXd& out) { A.multiply(v, out); }
inline void multiply_add(const Matrix& A, const Eigen::VectorXd& v, Eigen::VectorXd& out) { A.multiply(v, out, true); }
template <typename V>
void abs_multiply_add(const Matrix& A, const V& v, Eigen::VectorXd& out) {
  A.abs_multiply_add(Eigen::VectorXd(v), out);
}
inline Matrix transpose(const Matrix& P) {
  Mat R;
  check(MatTranspose(P.get(), MAT_INITIAL_MATRIX, &R), "MatTranspose");
  Matrix out(R);
  MatDestroy(&R);
  return out;
}
/// PᵀAP (R = Pᵀ is not needed: PETSc's PtAP).
inline Matrix galerkin(const Matrix&, const Matrix& A, const Matrix& P) {
  Mat C;
  check(MatPtAP(A.get(), P.get(), MAT_INITIAL_MATRIX, 2.0, &C), "MatPtAP");
  Matrix out(C);
  MatDestroy(&C);
  return out;
}
inline Eigen::VectorXd diagonal(const Matrix& A) { return A.diagonal(); }
/// A as this engine reads it: AIJ (its rows' CSR arrays; not (S)BAIJ's blocks), square, this process's rows its
/// columns (the driver's vectors hold both), every stored entry finite (as the serial entry point's rule). Local
/// queries only; throws naming what differs.
inline void check_layout(const Matrix& A) {
  MatType type;
  check(MatGetType(A.get(), &type), "MatGetType");
  if (!std::strstr(type, "aij") || std::strstr(type, "baij"))
    throw std::invalid_argument(std::string("A must be an AIJ (sparse) PETSc matrix, got type '") + type + "'");
  if (global_rows(A) != global_cols(A))
    throw std::invalid_argument("A must be square, got shape (" + std::to_string(global_rows(A)) + ", " +
                                std::to_string(global_cols(A)) + ")");
  if (A.rows() != A.cols())
    throw std::invalid_argument("A's local row and column sizes differ on this process (" + std::to_string(A.rows()) + " rows, " +
                                std::to_string(A.cols()) + " columns): create A with the same row and column layout");
  const LocalRows rows(A.get(), false);
  rows.for_each([&](PetscInt i, PetscInt j, PetscInt p) {
    if (!std::isfinite(rows.value(p)))
      throw std::invalid_argument("A has a non-finite entry " + to_text(rows.value(p)) + " at (" +
                                  std::to_string(rows.row_begin() + i) + ", " + std::to_string(j) + ")");
  });
}
/// What every member on this engine needs of A's diagonal: it divides by a_ii (V-cycle smoothers, Krylov solves,
/// splittings), so this process's diagonal is positive and normal (a subnormal one's reciprocal overflows); the
/// serial member has other rules.
inline void check_diagonal(const Matrix& A) {
  const Eigen::VectorXd d = A.diagonal();
  for (Eigen::Index i = 0; i < d.size(); ++i)
    if (!(d[i] >= std::numeric_limits<double>::min())) {
      const std::string row = std::to_string(A.row_offset() + i);
      throw std::invalid_argument("A's diagonal must be positive (not subnormal) on the PETSc engine (its smoothers, "
                                  "Krylov solves and splittings divide by it); A[" + row + ", " + row + "] = " + to_text(d[i]));
    }
}
/// A's layout (check_layout, on every process first: the diagonal's calls are collective), then its diagonal.
inline void check_operator(const Matrix& A) {
  detail::collective_check(A.comm(), [&] { check_layout(A); });
  check_diagonal(A);
}
/// The diagonal block (a view of A's own arrays): the stationary members split it (multisplitting).
inline Matrix::Block diagonal_block(const Matrix& A) { return A.block(); }
inline Eigen::VectorXd row_max_abs(const Matrix& A) { return A.row_max_abs(); }

/// k symmetric projected Gauss–Seidel sweeps on this process's rows (detail::projected_gauss_seidel
/// on the diagonal block), the couplings to other processes' unknowns held at y: Gauss–Seidel within
/// a process, Jacobi between them (on one process, the serial sweeps exactly).
inline void sweep_rows(const Matrix& A, const Eigen::VectorXd& q, Eigen::VectorXd& y, int sweeps, const detail::Box* box) {
  if (A.comm().size() == 1) return detail::projected_gauss_seidel(A.block(), q, y, sweeps, box);
  const Eigen::VectorXd qe = q + A.coupling(y);
  detail::projected_gauss_seidel(A.block(), qe, y, sweeps, box);
}

/// detail::inject_bounds (box.hpp) on P's columns this process owns: the rows of R = Pᵀ, with every
/// fine row's bound gathered (once per level and solve, at the nested start).
inline Eigen::VectorXd inject_bounds(const Matrix& P, const Eigen::VectorXd& b, double none) {
  const Matrix R = transpose(P);
  Vec local, all;
  VecScatter scatter;
  check(VecCreateMPIWithArray(P.comm().get(), 1, P.rows(), PETSC_DECIDE, b.data(), &local), "VecCreateMPIWithArray");
  check(VecScatterCreateToAll(local, &scatter, &all), "VecScatterCreateToAll");
  check(VecScatterBegin(scatter, local, all, INSERT_VALUES, SCATTER_FORWARD), "VecScatterBegin");
  check(VecScatterEnd(scatter, local, all, INSERT_VALUES, SCATTER_FORWARD), "VecScatterEnd");
  const PetscScalar* ball;
  check(VecGetArrayRead(all, &ball), "VecGetArrayRead");
  Eigen::VectorXd c = Eigen::VectorXd::Constant(R.rows(), none), weight = Eigen::VectorXd::Zero(R.rows());
  for (Eigen::Index j = 0; j < R.rows(); ++j) {
    PetscInt ncols;
    const PetscInt* cols;
    const PetscScalar* vals;
    const PetscInt row = static_cast<PetscInt>(R.row_offset() + j);
    check(MatGetRow(R.get(), row, &ncols, &cols, &vals), "MatGetRow");
    for (PetscInt k = 0; k < ncols; ++k) detail::weigh_bound(vals[k], ball[cols[k]], weight[j], c[j]);
    MatRestoreRow(R.get(), row, &ncols, &cols, &vals);
  }
  VecRestoreArrayRead(all, &ball);
  VecScatterDestroy(&scatter);
  VecDestroy(&all);
  VecDestroy(&local);
  return c;
}

/// A level of the hierarchy below another, and the levels below one, in PETSc Mats.
using Level = detail::HierarchyLevel<Matrix>;
using Hierarchy = detail::LevelsBelow<Level>;

/// The serial V-cycle (detail/multigrid.hpp) in PETSc's PCMG, set up on `pc` over the hierarchy below a
/// level: its P's, the Galerkin operators PᵀKP of each step's K (GalerkinOperators: updated by K's change,
/// as the serial engine's), one forward Gauss–Seidel sweep before the coarse correction and one backward
/// after (symmetric: CG applies), LU on the coarsest level (redundant on several processes).
class VCycle {
 public:
  /// `A`: the level's matrix (its hierarchy's operators below start the Galerkin ones).
  VCycle(PC pc, const Matrix& A, const Hierarchy& below, int processes) : below_(below), mg_(pc) {
    const PetscInt L = static_cast<PetscInt>(below_.levels) + 1;
    check(PCSetType(pc, PCMG), "PCSetType");
    check(PCMGSetLevels(pc, L, nullptr), "PCMGSetLevels");
    check(PCMGSetGalerkin(pc, PC_MG_GALERKIN_NONE), "PCMGSetGalerkin");
    std::vector<Mat> P, operators;
    for (std::size_t l = 0; l < below_.levels; ++l) {
      P.push_back(below_.level[l].P.get());
      operators.push_back(below_.level[l].A.get());
    }
    galerkin_ = std::make_unique<GalerkinOperators>(std::move(P), A.get(), std::move(operators));
    for (PetscInt l = 1; l < L; ++l) {
      check(PCMGSetInterpolation(pc, l, below_.level[L - 1 - l].P.get()), "PCMGSetInterpolation");
      smoother(pc, l, true);
      smoother(pc, l, false);
    }
    KSP coarse;
    PC cpc;
    check(PCMGGetCoarseSolve(pc, &coarse), "PCMGGetCoarseSolve");
    KSPSetType(coarse, KSPPREONLY);
    KSPGetPC(coarse, &cpc);
    PCSetType(cpc, processes > 1 ? PCREDUNDANT : PCLU);
  }
  VCycle(const VCycle&) = delete;
  VCycle& operator=(const VCycle&) = delete;
  /// Whether PCMG is still the preconditioner (the user's options may have chosen another).
  bool in_use() const {
    PetscBool mg = PETSC_FALSE;
    PetscObjectTypeCompare(reinterpret_cast<PetscObject>(mg_), PCMG, &mg);
    return mg;
  }
  /// The most changed entries of K that the next update takes (GalerkinOperators::most_changes).
  std::size_t most_changes() const { return galerkin_->most_changes(); }
  /// The coarse operators of the step's K (updated by its `changes` since the last update where
  /// GalerkinOperators can; null: more than most_changes).
  void update(Mat K, const GalerkinOperators::Changes* changes) {
    if (galerkin_->form(K, changes)) coarse_operators();
  }

 private:
  /// PCMG's coarse levels take the Galerkin operators (whenever GalerkinOperators::form made new Mats).
  void coarse_operators() {
    const std::size_t L = below_.levels + 1;
    for (std::size_t k = 0; k + 1 < L; ++k) {  // K_{k+1} is PCMG's level L − 2 − k (0: the coarsest)
      const PetscInt l = static_cast<PetscInt>(L - 2 - k);
      Mat C = galerkin_->K(k);
      KSP s;
      check(PCMGGetSmoother(mg_, l, &s), "PCMGGetSmoother");
      check(KSPSetOperators(s, C, C), "KSPSetOperators");
      if (l == 0) continue;  // the coarse solve has no up smoother, no residual
      check(PCMGGetSmootherUp(mg_, l, &s), "PCMGGetSmootherUp");
      check(KSPSetOperators(s, C, C), "KSPSetOperators");
      // PCMG keeps the operator of a level's residual from its first set-up: it must follow the smoothers'
      check(PCMGSetResidual(mg_, l, PCMGResidualDefault, C), "PCMGSetResidual");
    }
  }
  static void smoother(PC pc, PetscInt l, bool down) {
    KSP s;
    PC p;
    check(down ? PCMGGetSmootherDown(pc, l, &s) : PCMGGetSmootherUp(pc, l, &s), "PCMGGetSmoother");
    KSPSetType(s, KSPRICHARDSON);
    KSPSetTolerances(s, PETSC_DEFAULT, PETSC_DEFAULT, PETSC_DEFAULT, 1);
    KSPSetNormType(s, KSP_NORM_NONE);
    KSPGetPC(s, &p);
    PCSetType(p, PCSOR);
    PCSORSetSymmetric(p, down ? SOR_LOCAL_FORWARD_SWEEP : SOR_LOCAL_BACKWARD_SWEEP);
  }

  Hierarchy below_;
  PC mg_;
  std::unique_ptr<GalerkinOperators> galerkin_;
};

/// The reduced system of a Newton step (detail::ActiveSetSystem's PETSc form) for the (shifted) LCP
/// and the box problem: K = A with the active rows and columns replaced by the identity's (on A's
/// pattern, written in place: K stays symmetric where A is), solved by KSP — CG (symmetric A) or BiCGSTAB
/// preconditioned by a V-cycle (PCMG) on the hierarchy's Galerkin operators of K (updated by K's changed
/// entries: cheaper than any per-step AMG set-up, docs/MEASUREMENTS.md), stopped on the true residual as
/// the serial Krylov solve is; where the serial rule (ActiveSetSystem::use_iterative) solves exactly, LU
/// (PETSc's on one process, MUMPS on several). Options prefix nrmicp_inner_ (e.g. -nrmicp_inner_pc_type).
class System {
 public:
  /// `finest`: the engine interface's `borrow` (the serial engine's finest system frees the hierarchy's
  /// operators while it solves); this engine keeps them.
  System(const Matrix& A, const Matrix* B, Inner inner, Hierarchy below = {}, bool /*finest*/ = false)
      : A_(A), below_(below) {
    if (B) throw std::invalid_argument("the PETSc engine has no affine zeta (B): use the serial Newton member");
    PetscInt N;
    check(MatGetSize(A.get(), &N, nullptr), "MatGetSize");
    iterative_ = detail::ActiveSetSystem<PetscInt>::use_iterative(inner, below.levels, N);
    lu_ = !iterative_;
    symmetric_ = A.symmetric();
    check(KSPCreate(A.comm().get(), &ksp_), "KSPCreate");
    configure();
    // the solves' vectors, their arrays the driver's (VecPlaceArray): no 8 MB a million rows per solve
    check(VecCreateMPIWithArray(A.comm().get(), 1, A.rows(), PETSC_DECIDE, nullptr, &bv_), "VecCreateMPIWithArray");
    check(VecDuplicate(bv_, &zv_), "VecDuplicate");
  }
  System(const System&) = delete;
  System& operator=(const System&) = delete;
  ~System() {
    KSPDestroy(&ksp_);
    vcycle_.reset();
    VecDestroy(&bv_);
    VecDestroy(&zv_);
    MatDestroy(&K_);
  }

  /// K of the active set `inactive` (rows with kInactive keep A's row; the others are identity rows).
  bool factorize(const std::vector<char>& inactive) {
    if (!K_) {
      check_diagonal();  // (first: a throw leaves no K behind for the next solve to skip the check)
      check(MatDuplicate(A_.get(), MAT_COPY_VALUES, &K_), "MatDuplicate");
    }
    const std::size_t most = vcycle_ ? vcycle_->most_changes() : 0;
    const bool few = write_values(inactive, most);
    if (vcycle_) vcycle_->update(K_, few ? &changes_ : nullptr);
    check(KSPSetOperators(ksp_, K_, K_), "KSPSetOperators");
    inactive_ = inactive;
    return true;
  }
  /// z = K⁻¹ b from z, the active rows set first; stops at ‖b − Kz‖ ≤ target (absolute), or at
  /// 1e-12 ‖b‖ when target is 0 (MultigridKrylov::rtol). Returns the Krylov iterations (0 for LU;
  /// max_iterations + 1 when the solve did not converge).
  int solve(const Eigen::VectorXd& b, Eigen::VectorXd& z, double target = 0) const {
    // (in z's units: the KSP's inner products stay within float's range)
    return detail::solve_in_units(A_.comm(), b, z, target, [this](const Eigen::VectorXd& bt, Eigen::VectorXd& zt, double t) {
      for (Eigen::Index i = 0; i < zt.size(); ++i)
        if (!detail::inactive_state(inactive_[i])) zt[i] = bt[i];
      const PlacedArray placed_b(bv_, bt.data()), placed_z(zv_, zt.data());
      int its = 0;
      if (!run(ksp_, bv_, zv_, t, max_iterations_, its)) its = max_iterations_ + 1;
      return lu_ ? 0 : its;
    });
  }
  void restore_hierarchy() {}
  /// "lu", or the Krylov method and the preconditioner ("cg+mg", "bicgstab+hypre", ...).
  const char* inner_name() const {
    PC pc;
    PCType type;
    KSPGetPC(ksp_, &pc);
    PCGetType(pc, &type);
    name_ = lu_ ? "lu" : std::string(symmetric_ ? "cg+" : "bicgstab+") + (type ? type : "none");
    return name_.c_str();
  }
  bool iterative() const { return iterative_; }
  void set_max_iterations(int k) { max_iterations_ = k; }

 private:
  /// K's values for the active set: A's where row and column are inactive, the identity's elsewhere (what
  /// MatZeroRowsColumns of the active rows makes of A, written in place: no copy of A, no exchange of the
  /// rows zeroed). K's changed entries are recorded (changes_, global numbers) up to `most` + 1: whether
  /// they were all recorded.
  bool write_values(const std::vector<char>& inactive, std::size_t most) {
    Eigen::VectorXd keep(static_cast<Eigen::Index>(inactive.size()));
    for (std::size_t i = 0; i < inactive.size(); ++i) keep[static_cast<Eigen::Index>(i)] = detail::inactive_state(inactive[i]);
    const Eigen::VectorXd ghost = A_.ghosts(keep);  // the other processes' columns' states
    const LocalRows a(A_.get(), false);
    LocalRows k(K_, true);                          // (assembled again when it goes)
    const PetscInt lo = a.row_begin(), clo = a.col_begin();
    const PetscInt* columns = a.ghost_columns();
    changes_.clear();
    a.for_each_local([&](PetscInt i, bool off, PetscInt c, PetscInt p) {
      const PetscInt j = off ? columns[c] : clo + c;
      const double v = keep[i] > 0 && (off ? ghost[c] : keep[c]) > 0 ? a.value(p) : (lo + i == j ? 1.0 : 0.0);
      double& kv = k.value(p);
      if (kv == v) return;
      if (changes_.size() <= most) changes_.push_back({lo + i, j, v - kv});
      kv = v;
    });
    return changes_.size() <= most;
  }
  /// Every row of A stores its diagonal (an active row's 1 goes there); every process alike.
  void check_diagonal() const {
    const LocalRows a(A_.get(), false);
    int stored = 1;
    for (PetscInt i = 0; i < a.rows() && stored; ++i) stored = a.find(i, a.row_begin() + i) >= 0;
    MPI_Allreduce(MPI_IN_PLACE, &stored, 1, MPI_INT, MPI_LAND, A_.comm().get());
    if (!stored) throw std::invalid_argument("the PETSc engine's Newton member needs A's diagonal stored in every row");
  }
  /// One KSP solve from zv to ‖b − Kz‖ ≤ target (1e-12 ‖b‖ when 0), at most `cap` iterations (added
  /// to `its`); whether it converged.
  bool run(KSP ksp, Vec bv, Vec zv, double target, int cap, int& its) const {
    if (!lu_)
      check(KSPSetTolerances(ksp, target > 0 ? 1e-300 : detail::kKrylovRtol, target > 0 ? target : 0.0, PETSC_DEFAULT, cap),
            "KSPSetTolerances");
    check(KSPSolve(ksp, bv, zv), "KSPSolve");
    KSPConvergedReason reason;
    PetscInt k;
    KSPGetConvergedReason(ksp, &reason);
    KSPGetIterationNumber(ksp, &k);
    its += static_cast<int>(k);
    return reason > 0;
  }
  /// CG (symmetric A) or right-preconditioned BiCGSTAB from the given z, stopped on the true residual
  /// (as the serial Krylov solve); its PC.
  PC krylov(KSP ksp) const {
    KSPSetType(ksp, symmetric_ ? KSPCG : KSPBCGS);
    if (!symmetric_) KSPSetPCSide(ksp, PC_RIGHT);
    KSPSetNormType(ksp, KSP_NORM_UNPRECONDITIONED);
    KSPSetInitialGuessNonzero(ksp, PETSC_TRUE);
    PC pc;
    KSPGetPC(ksp, &pc);
    return pc;
  }
  void configure() {
    if (lu_) {
      KSPSetType(ksp_, KSPPREONLY);
      PC pc;
      KSPGetPC(ksp_, &pc);
      PCSetType(pc, PCLU);
      if (A_.comm().size() > 1) PCFactorSetMatSolverType(pc, MATSOLVERMUMPS);  // PETSc's own LU is serial
      // PETSc's zero-pivot test is absolute (1e2 eps): in small units, or on rows far below A's largest, it took
      // every pivot for zero; exact zeros only, as the serial engine's factorizations (units-free)
      PCFactorSetZeroPivot(pc, 0.0);
    } else {
      PC pc = krylov(ksp_);
      vcycle_ = std::make_unique<VCycle>(pc, A_, below_, A_.comm().size());
    }
    KSPSetOptionsPrefix(ksp_, "nrmicp_inner_");
    check(KSPSetFromOptions(ksp_), "KSPSetFromOptions");
    if (vcycle_ && !vcycle_->in_use()) vcycle_.reset();  // -nrmicp_inner_pc_type chose another preconditioner
  }

  Matrix A_;
  Hierarchy below_;
  KSP ksp_ = nullptr;
  Vec bv_ = nullptr, zv_ = nullptr;
  Mat K_ = nullptr;
  std::unique_ptr<VCycle> vcycle_;  // PCMG's set-up and coarse operators (when it preconditions)
  GalerkinOperators::Changes changes_;  // K's changed entries at the last factorize (write_values)
  std::vector<char> inactive_;
  bool iterative_ = false, lu_ = false, symmetric_ = false;
  mutable std::string name_;  // inner_name's
  int max_iterations_ = 500;  // MultigridKrylov::default_max_iterations
};

/// The fallback member of a level (the serial engine's Solver<nrm>): nrm on this process's diagonal
/// block, the couplings to other processes' unknowns held at the start of the run (synchronous
/// multisplitting with one run as its step; on one process, the serial fallback exactly). Its Res
/// and sweep count are every process's.
class Fallback {
 public:
  using Local = Eigen::SparseMatrix<double, Eigen::RowMajor, PetscInt>;
  Fallback(const Matrix& A, const Options& o) : A_(A), block_(A.block()), solver_(block_, o) {}
  const Options& options() const { return solver_.options(); }
  Result solve(const Eigen::VectorXd& q, const Zeta<PetscInt>& zeta, const Eigen::VectorXd* z0,
               const detail::Callback&, const detail::Poll&, const SolveOptions* it) {
    const detail::Comm& comm = A_.comm();
    if (comm.size() == 1) return solver_.solve(q, zeta, z0, {}, {}, it);
    // ζ is every process's (a collective call) and the runs may differ in length: held at ζ(z0)
    Result r = solver_.solve(q + A_.coupling(*z0), held(zeta, *z0), z0, {}, {}, it);
    r.iterations = static_cast<int>(comm.max(r.iterations));
    Eigen::VectorXd w, zeta_z;
    A_.multiply(r.z, w);
    w += q;
    r.residual = comm.all(zeta.eval(r.z, zeta_z))
                     ? detail::bounded_residual(w, r.z - zeta_z, r.z, zeta.upper(), comm)
                     : std::numeric_limits<double>::quiet_NaN();
    return r;
  }

 private:
  /// ζ, a callable or affine one held at ζ(z0) (the bounds kept).
  static Zeta<PetscInt> held(const Zeta<PetscInt>& zeta, const Eigen::VectorXd& z0) {
    if (zeta.kind() != ZetaKind::Functor && zeta.kind() != ZetaKind::Affine) return zeta;
    Eigen::VectorXd psi;
    if (!zeta.eval(z0, psi)) psi = Eigen::VectorXd::Constant(z0.size(), std::numeric_limits<double>::quiet_NaN());
    const Zeta<PetscInt> c = Zeta<PetscInt>::constant(psi);
    return zeta.upper().size() ? c.with_upper(zeta.upper()) : c;
  }
  Matrix A_;
  Local block_;
  Solver<Local> solver_;
};

}  // namespace nrmicp::petsc

namespace nrmicp::detail {

/// The PETSc engine's types (detail/engine.hpp).
template <>
struct Engine<petsc::Matrix> {
  using StorageIndex = PetscInt;
  using Coarse = petsc::Matrix;
  using System = petsc::System;
  using Level = petsc::Level;
  using Hierarchy = petsc::Hierarchy;
  using Fallback = petsc::Fallback;
  static constexpr bool serial = false;
};

}  // namespace nrmicp::detail
