// nrmicp — the iterative inner solve of the Newton member (inner = "cg"): a Krylov method on the
// reduced system K of one Newton step (detail/active_set.hpp), preconditioned by one multigrid
// V-cycle built from the same prolongations P_0, P_1, ... the nested iteration uses: conjugate
// gradients when K is symmetric positive definite, else BiCGSTAB (Eigen's).
//
// Per Newton step (setup): the Galerkin operators K_{l+1} = P_lᵀ K_l P_l of the reduced system
// (K changes with the active set, so they are recomputed: detail/galerkin.hpp) and a direct
// factorization of the coarsest one (detail/vcycle.hpp). The V-cycle smooths with one forward Gauss–Seidel sweep before the coarse
// correction and one backward sweep after it: a symmetric preconditioner, positive definite for
// symmetric positive definite K, so CG applies. K's active rows are identity rows with zeroed
// columns (the LCP): K stays SPD when A is, and so does every PᵀKP of full-rank P.
//
// A nonsymmetric K (a nonsymmetric A, or an affine ζ: active rows I − B) is read through a
// row-major copy on a fixed pattern (values only per step) for the Gauss–Seidel sweeps, the
// products and the Galerkin operators Pᵀ K P; the V-cycle is the same, a nonsymmetric
// preconditioner then, and BiCGSTAB replaces CG.
//
// Why BiCGSTAB rather than GMRES: no Krylov basis to store, and its residual is the true one, which
// the absolute target of solve() is about (docs/MEASUREMENTS.md, "BiCGSTAB for a nonsymmetric K").
// The hand-written CG stays for SPD K: its work vectors are kept across
// solves (Eigen's solvers allocate theirs per solve).
#pragma once

#include "engine.hpp"
#include "galerkin.hpp"
#include "vcycle.hpp"

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseCore>

#include <cstddef>
#include <type_traits>
#include <vector>

namespace nrmicp::detail {

template <typename StorageIndex>
class MultigridKrylov;

/// The V-cycle as a preconditioner of Eigen's iterative solvers (their preconditioner concept:
/// the set-up is MultigridKrylov::setup's, so compute/analyzePattern/factorize do nothing).
template <typename StorageIndex>
struct VCyclePreconditioner {
  const MultigridKrylov<StorageIndex>* mg = nullptr;
  template <typename M> VCyclePreconditioner& analyzePattern(const M&) { return *this; }
  template <typename M> VCyclePreconditioner& factorize(const M&) { return *this; }
  template <typename M> VCyclePreconditioner& compute(const M&) { return *this; }
  template <typename Rhs> Eigen::VectorXd solve(const Rhs& r) const {
    Eigen::VectorXd e;
    if constexpr (std::is_same_v<Rhs, Eigen::VectorXd>) mg->precondition(r, e);
    else mg->precondition(Eigen::VectorXd(r), e);
    return e;
  }
  Eigen::ComputationInfo info() const { return Eigen::Success; }
};

/// A nonsymmetric K in row-major storage, for the sweeps, products and Galerkin operators; on K's
/// previous pattern only the values are copied (through to_row_: K's storage position → rows_').
template <typename StorageIndex>
class RowCopy {
 public:
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  template <typename M>
  void copy(const M& K, bool same_pattern) {
    const StorageIndex* outer = K.outerIndexPtr();
    const StorageIndex* row = K.innerIndexPtr();
    if (!same_pattern || rows_.nonZeros() != K.nonZeros()) {
      rows_ = K;  // Eigen transposes the storage; rows come out sorted
      to_row_.resize(static_cast<std::size_t>(K.nonZeros()));
      std::vector<StorageIndex> next(rows_.outerIndexPtr(), rows_.outerIndexPtr() + K.rows());
      for (Eigen::Index j = 0; j < K.cols(); ++j)
        for (StorageIndex p = outer[j]; p < outer[j + 1]; ++p) to_row_[p] = next[row[p]]++;
      return;
    }
    const double* v = K.valuePtr();
    double* w = rows_.valuePtr();
    for (Eigen::Index p = 0; p < K.nonZeros(); ++p) w[to_row_[p]] = v[p];
  }
  const RowMatrix& matrix() const { return rows_; }

 private:
  RowMatrix rows_;
  std::vector<StorageIndex> to_row_;
};

template <typename StorageIndex>
class MultigridKrylov {
 public:
  using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex>;
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  using Vector = Eigen::VectorXd;

  /// The Krylov method stops when ‖b − Kz‖ ≤ the absolute target the caller gives, or without one at rtol ‖b‖.
  /// The Newton loop asks for a tenth of its tol, so that the step on the right active set meets
  /// tol and no more (‖b − Kz‖ on the inactive rows is ‖w‖ there, what Res measures), and on the
  /// coarse levels for a fraction of the iterate's Res (a start needs no more). CG's recursive
  /// residual keeps falling below the rounding floor of the true one, so any target is reached;
  /// if the true residual cannot follow, the Newton loop ends with its active set settled.
  static constexpr double rtol = kKrylovRtol;
  static constexpr int default_max_iterations = 500;

  /// The hierarchy must outlive this object. `symmetric`: the systems K given to setup are
  /// symmetric (their column storage is their row storage; CG), else a row-major copy of each is
  /// kept (BiCGSTAB). `borrow`: the hierarchy's operators A_l become this V-cycle's K_l instead of
  /// being copied (start_from_hierarchy), and are freed while it works (restore_hierarchy).
  MultigridKrylov(Hierarchy<StorageIndex> h, bool symmetric, bool borrow = false)
      : galerkin_(h, borrow), vcycle_(h.levels, symmetric), symmetric_(symmetric) {
    bicgstab_.preconditioner().mg = this;
  }
  MultigridKrylov(const MultigridKrylov&) = delete;  // the preconditioner points here
  MultigridKrylov& operator=(const MultigridKrylov&) = delete;

  /// Galerkin operators of K and the coarsest factorization. K must outlive this until the next
  /// setup. False if singular. `changes`, when given, lists every entry of K that changed since
  /// the previous successful setup: the operators are then updated if they are few
  /// (GalerkinOperators::form).
  bool setup(const ColMatrix& K, const std::vector<Change<StorageIndex>>* changes = nullptr) {
    galerkin_.lend();
    fine_ = &K;
    if (!symmetric_) rows_.copy(K, galerkin_.same_pattern(K.nonZeros()));
    galerkin_.form(fine(), K.nonZeros(), valid_ ? changes : nullptr);
    valid_ = vcycle_.setup(K, fine(), galerkin_);
    if (valid_ && !symmetric_) bicgstab_.compute(rows_.matrix());
    return valid_;
  }

  /// The hierarchy's own operators taken as those of a K equal to A with `nnz` stored entries
  /// (GalerkinOperators::start_from_hierarchy): the first setup builds on them.
  void start_from_hierarchy(Eigen::Index nnz) {
    galerkin_.start_from_hierarchy(nnz);
    valid_ = true;
  }

  /// Whether the hierarchy's operators are freed while this V-cycle works (`borrow`).
  bool lent() const { return galerkin_.lent(); }

  /// The hierarchy's operators formed again, as the Galerkin ones of `A_values` (a column-major
  /// matrix on K's pattern holding A's values), on the patterns of this V-cycle's K_l, which stay
  /// as they are (the next setup updates them from the last K). The next setup frees them again.
  /// A_l and K_l have one pattern and the coarse levels need A_l only for nested iteration, before
  /// the finest level's solve: not held during it, for one pass of the Galerkin products a solve
  /// (docs/MEASUREMENTS.md, "The algebraic hierarchy on grids", Memory).
  template <typename M>
  void restore_hierarchy(const M& A_values) {
    if (!galerkin_.lent()) return;
    if (!symmetric_) rows_.copy(A_values, galerkin_.same_pattern(A_values.nonZeros()));  // K's again at setup
    galerkin_.restore(symmetric_ ? as_rows(A_values) : as_rows(rows_.matrix()));
  }
  /// GalerkinOperators::max_changes.
  static std::size_t max_changes(Eigen::Index nnz) { return GalerkinOperators<StorageIndex>::max_changes(nnz); }

  /// K z = b from the start z (the current Newton iterate: close), until ‖b − Kz‖ ≤ `target`
  /// (absolute), or ≤ rtol ‖b‖ when target is 0: CG for a symmetric K, else BiCGSTAB. Returns
  /// the number of iterations (max_iterations + 1 when not converged or broken down).
  int solve(const Vector& b, Vector& z, double target = 0) const {
    return solve_in_units(serial_comm(), b, z, target, [this](const Vector& bt, Vector& zt, double t) {
      const double stop = t > 0 ? t : rtol * bt.norm();
      return symmetric_ ? cg(bt, zt, stop) : krylov(bt, zt, stop);
    });
  }

  /// e = one V-cycle applied to r (≈ K⁻¹ r).
  void precondition(const Vector& r, Vector& e) const { vcycle_.apply(fine(), galerkin_, r, e); }

  const char* name() const { return symmetric_ ? "cg" : "bicgstab"; }
  int max_iterations() const { return max_iterations_; }
  void set_max_iterations(int k) { max_iterations_ = k; }
  std::size_t levels() const { return galerkin_.levels() + 1; }

 private:
  /// Preconditioned CG; ‖b − Kz‖ ≤ stop, the target as given (no bound by rtol ‖b‖: it cost
  /// iterations; docs/MEASUREMENTS.md, "The Krylov target taken as given").
  int cg(const Vector& b, Vector& z, double stop) const {
    const auto K = fine();
    Vector &r = cg_.r, &s = cg_.s, &p = cg_.p, &Kp = cg_.Kp;  // reused: no page faults per solve
    r.noalias() = K * z;
    r = b - r;
    if (r.norm() <= stop) return 0;
    s.resize(b.size()); p.resize(b.size()); Kp.resize(b.size());
    precondition(r, s);
    p = s;
    double rs = r.dot(s);
    for (int k = 1; k <= max_iterations_; ++k) {
      Kp.noalias() = K * p;
      const double alpha = rs / p.dot(Kp);
      z += alpha * p;
      r -= alpha * Kp;
      if (r.norm() <= stop) return k;
      precondition(r, s);
      const double rs_new = r.dot(s);
      p = s + (rs_new / rs) * p;
      rs = rs_new;
    }
    return max_iterations_ + 1;
  }

  /// Eigen's preconditioned BiCGSTAB (its residual is the unpreconditioned b − Kz, relative to
  /// ‖b‖, updated recursively as CG's is) until ‖b − Kz‖ ≤ stop. z is kept when the solve breaks
  /// down (a non-finite iterate). The convergence is Eigen's test on the recursive residual: the
  /// true one has a rounding floor (docs/MEASUREMENTS.md, "BiCGSTAB for a nonsymmetric K") that the
  /// Newton loop's target tol / 10 can lie below, where a check of the true residual would fail
  /// every step.
  int krylov(const Vector& b, Vector& z, double stop) const {
    const double bn = b.norm();
    if (bn == 0) { z.setZero(); return 0; }
    auto& s = bicgstab_;
    s.setMaxIterations(max_iterations_);
    s.setTolerance(stop / bn);
    Vector x = s.solveWithGuess(b, z);
    const int k = static_cast<int>(s.iterations());
    if (!x.allFinite()) return max_iterations_ + 1;
    z.swap(x);
    return s.info() == Eigen::Success ? k : max_iterations_ + 1;
  }

  /// The fine operator, row-major: K's own storage when symmetric, else its row copy.
  Eigen::Map<const RowMatrix> fine() const { return symmetric_ ? as_rows(*fine_) : as_rows(rows_.matrix()); }

  struct CGWork {
    Vector r, s, p, Kp;
  };
  mutable CGWork cg_;
  GalerkinOperators<StorageIndex> galerkin_;   // K_1, ..., K_L on the hierarchy
  VCycle<StorageIndex> vcycle_;
  bool symmetric_;
  bool valid_ = false;                    // the last setup succeeded (an update builds on it)
  const ColMatrix* fine_ = nullptr;
  int max_iterations_ = default_max_iterations;
  RowCopy<StorageIndex> rows_;            // K in row-major storage (nonsymmetric K)
  mutable Eigen::BiCGSTAB<RowMatrix, VCyclePreconditioner<StorageIndex>> bicgstab_;
};

}  // namespace nrmicp::detail
