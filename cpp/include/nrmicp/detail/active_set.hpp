// nrmicp — the linear system of one semismooth Newton (active-set) step, kept on one fixed
// sparsity pattern so that its symbolic analysis is done once and every step is only a
// numeric refactorization (docs/SPEC.md, "The Newton member").
//
// For an active set 𝒜 (its complement, the inactive set ℐ = {x > 0}) the step solves K z = b with
//   row i ∈ ℐ:  (A z)_i = −q_i                      (w_i = 0)
//   row i ∈ 𝒜:  ((I − B) z)_i = c_i                 (g_i = z_i − ζ(z)_i = 0; ζ(z) = Bz + c)
// A (shifted) LCP has B = 0, c = 0: the active rows are identity rows and z_𝒜 = 0, so the active
// columns of the inactive rows may be zeroed too. That keeps K symmetric when A is (CHOLMOD);
// otherwise K is factorized by LU (UMFPACK). K lives on the union of the patterns of A, I and B,
// explicit zeros kept.
#pragma once

#include "../inner_solver.hpp"
#include "../options.hpp"
#include "box.hpp"
#include "multigrid.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

namespace nrmicp::detail {

/// One sparse direct solver whose symbolic analysis is done once (analyze) and whose numeric
/// factorization is redone for new values on the same pattern (factorize).
template <typename StorageIndex>
class Refactorizer {
 public:
  using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex>;
  using Vector = Eigen::VectorXd;

  /// Analyzes K's pattern with the backend `kind` means (detail::resolve_backend). K must outlive
  /// this object (UMFPACK reads it again when solving).
  void analyze(const ColMatrix& K, Inner kind, bool spd_candidate) {
    kind_ = kind;
    impl_ = make(resolve_backend(kind, spd_candidate));
    impl_->analyze(K);
  }

  /// Numeric factorization of K (same pattern as analyzed). A Cholesky that fails under
  /// inner = auto (K not positive definite) is replaced by LU for good. False when singular.
  bool factorize(const ColMatrix& K) {
    if (impl_->factorize(K)) return true;
    if (kind_ != Inner::Auto || !impl_->cholesky) return false;
    impl_ = make(lu_backend());
    impl_->analyze(K);
    return impl_->factorize(K);
  }

  void solve(const Vector& b, Vector& x) const { impl_->solve(b, x); }
  const char* name() const { return impl_ ? impl_->name : "none"; }

 private:
  struct Base {
    const char* name = "";
    bool cholesky = false;
    virtual ~Base() = default;
    virtual void analyze(const ColMatrix& K) = 0;
    virtual bool factorize(const ColMatrix& K) = 0;
    virtual void solve(const Vector& b, Vector& x) const = 0;
  };
  template <typename EigenSolver>
  struct Impl : Base {
    EigenSolver solver;
    void analyze(const ColMatrix& K) override { solver.analyzePattern(K); }
    bool factorize(const ColMatrix& K) override {
      solver.factorize(K);
      return factored(solver);
    }
    void solve(const Vector& b, Vector& x) const override { x = solver.solve(b); }
  };
  static std::unique_ptr<Base> make(Inner k) {
    return with_backend<ColMatrix>(k, [k](auto backend) -> std::unique_ptr<Base> {
      auto p = std::make_unique<Impl<typename decltype(backend)::type>>();
      p->name = to_string(k);
      p->cholesky = k == Inner::Cholmod || k == Inner::EigenLLT;
      return p;
    });
  }
  Inner kind_ = Inner::Auto;
  std::unique_ptr<Base> impl_;
};

/// K of the header comment on the union pattern, with its Refactorizer.
template <typename StorageIndex>
class ActiveSetSystem {
 public:
  using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex>;
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  using Vector = Eigen::VectorXd;

  /// B == nullptr: the (shifted) LCP. The symbolic analysis happens here, once.
  /// `below`: the levels below this one, for the iterative solve (detail/multigrid.hpp);
  /// `borrow`: its V-cycle frees their operators while it works (MultigridKrylov; restore_hierarchy).
  template <typename MatrixType>
  ActiveSetSystem(const MatrixType& A, const RowMatrix* B, Inner inner, Hierarchy<StorageIndex> below = {},
                  bool borrow = false)
      : lcp_(B == nullptr), inner_(inner) {
    if (lcp_ && has_full_diagonal(A))
      use_pattern_of(A);
    else
      use_union_pattern(A, B);
    spd_candidate_ = lcp_ && is_symmetric(K_) && has_positive_diagonal(K_);
    // CG needs a symmetric positive definite K: the LCP of a symmetric A (an indefinite K shows
    // as a failed coarsest Cholesky or CG breakdown; then the loop falls back). Any other K
    // (a nonsymmetric A, an affine ζ) takes BiCGSTAB (detail/multigrid.hpp).
    if (use_iterative(inner, below.levels, A.rows())) {
      krylov_ = std::make_unique<MultigridKrylov<StorageIndex>>(below, spd_candidate_, borrow);
      krylov_->start_from_hierarchy(K_.nonZeros());  // K holds A's values until the first factorize
    } else
      analyze();
  }

  /// Puts the values of the active set into K (inactive[i] == kInactive: i ∈ ℐ; any other state,
  /// at a bound, is an active row) and factorizes.
  /// False when K is singular.
  bool factorize(const std::vector<char>& inactive) {
    const StorageIndex* outer = K_.outerIndexPtr();
    const StorageIndex* row = K_.innerIndexPtr();
    double* v = K_.valuePtr();
    // The iterative solve's multigrid updates its operators by K's change when it is small.
    bool record = krylov_ != nullptr;
    const std::size_t most = MultigridKrylov<StorageIndex>::max_changes(K_.nonZeros());
    changes_.clear();
    for (Eigen::Index j = 0; j < K_.cols(); ++j)
      for (StorageIndex p = outer[j]; p < outer[j + 1]; ++p) {
        const bool row_inactive = inactive_state(inactive[row[p]]);
        // LCP: z_𝒜 is known (its bounds), so the active columns of the inactive rows are dropped
        // (symmetry) and their part goes to the right-hand side (NewtonStep::solve).
        const double value = row_inactive ? ((lcp_ && !inactive_state(inactive[j])) ? 0.0 : inactive_value_ptr_[p])
                                          : active_value(p, row[p], j);
        if (record && value != v[p]) {
          changes_.push_back({row[p], static_cast<StorageIndex>(j), value - v[p]});
          record = changes_.size() <= most;
        }
        v[p] = value;
      }
    if (!krylov_) return solver_.factorize(K_);
    inactive_ = inactive;
    factorized_ = false;
    return krylov_->setup(K_, record ? &changes_ : nullptr);
  }

  /// z = K⁻¹ b after factorize(). An iterative solve (inner = cg) starts from z's value and stops
  /// when ‖b − Kz‖ ≤ `target` (absolute), or ≤ MultigridKrylov::rtol ‖b‖ when target is 0; a
  /// direct one ignores both.
  /// The residual is that of the inactive rows, i.e. of w = Az + q there, what Res measures: for
  /// the LCP the active rows (identity, zeroed columns) are set exactly first and the V-cycle
  /// keeps them so. Returns the iterations of the iterative solve (0 for a direct one).
  ///
  /// An iterative solve that does not converge (max_iterations, a BiCGSTAB breakdown) is redone
  /// by the direct solve (analysed on first need), so the step is an exact Newton step whatever
  /// the Krylov method did; the iterations are reported as max_iterations + 1.
  int solve(const Vector& b, Vector& z, double target = 0) const {
    if (!krylov_) { solver_.solve(b, z); return 0; }
    if (lcp_)
      for (Eigen::Index i = 0; i < z.size(); ++i)
        if (!inactive_state(inactive_[i])) z[i] = b[i];
    const int k = krylov_->solve(b, z, target);
    if (k <= krylov_->max_iterations()) return k;
    direct_solve(b, z);
    return k;
  }
  /// The hierarchy's operators, freed by the V-cycle while it works, formed again (a no-op when
  /// none are freed): from A's values on K's pattern.
  void restore_hierarchy() {
    if (krylov_)
      krylov_->restore_hierarchy(Eigen::Map<const ColMatrix>(K_.rows(), K_.cols(), K_.nonZeros(), K_.outerIndexPtr(),
                                                             K_.innerIndexPtr(), inactive_value_ptr_));
  }
  const char* inner_name() const { return krylov_ ? krylov_->name() : solver_.name(); }
  /// Whether solve() honours its target (a Krylov solve); a direct one solves exactly whatever it is given.
  bool iterative() const { return krylov_ != nullptr; }
  /// The iterative solve's cap (MultigridKrylov::default_max_iterations); tests lower it to
  /// reach the direct retry.
  void set_max_iterations(int k) { if (krylov_) krylov_->set_max_iterations(k); }

  /// Whether `inner` (with `levels` prolongations below, K of size n) means the multigrid-
  /// preconditioned Krylov solve: cg with a hierarchy; auto with one from n = auto_krylov_min_n on.
  static bool use_iterative(Inner inner, std::size_t levels, Eigen::Index n) {
    return levels > 0 && (inner == Inner::CG || (inner == Inner::Auto && n >= auto_krylov_min_n));
  }
  /// The Krylov solve is faster from here on; below, the exact solve is the steadier one at a rounding
  /// floor (docs/MEASUREMENTS.md, "`ActiveSetSystem::auto_krylov_min_n`").
  static constexpr Eigen::Index auto_krylov_min_n = 1000;

 private:
  /// The symbolic analysis of the direct solve (at construction, or on first need).
  void analyze() const {
    solver_.analyze(K_, direct_inner(inner_), spd_candidate_);
    analyzed_ = true;
  }

  /// The direct solve of K (its values already in place), when the iterative one failed.
  void direct_solve(const Vector& b, Vector& z) const {
    if (!analyzed_) analyze();
    if (!factorized_ && !solver_.factorize(K_)) {
      z.setConstant(std::numeric_limits<double>::quiet_NaN());  // singular: the step fails
      return;
    }
    factorized_ = true;
    solver_.solve(b, z);
  }

  /// Whether every row of A has a stored diagonal entry.
  template <typename MatrixType>
  static bool has_full_diagonal(const MatrixType& A) {
    for (Eigen::Index k = 0; k < A.outerSize(); ++k) {
      bool found = false;
      for (typename MatrixType::InnerIterator it(A, k); it && !found; ++it) found = it.row() == it.col();
      if (!found) return false;
    }
    return true;
  }

  /// The LCP on A's own pattern (it holds the diagonal): K = A, the active-row values the
  /// identity's. A copy in column order, no sorting (the triplet path below is slow:
  /// docs/MEASUREMENTS.md, "The LCP's K on A's own pattern").
  template <typename MatrixType>
  void use_pattern_of(const MatrixType& A) {
    K_ = A;
    K_.makeCompressed();
    active_values_.resize(0);  // the identity's: active_value() gives them without storage
    // A symmetric row-major A stores K's column order: K's inactive values are A's own (held by
    // reference, as A is), not a copy.
    if constexpr (MatrixType::IsRowMajor) {
      if (A.isCompressed() && A.nonZeros() == K_.nonZeros() &&
          std::equal(K_.innerIndexPtr(), K_.innerIndexPtr() + K_.nonZeros(), A.innerIndexPtr()) &&
          std::equal(K_.valuePtr(), K_.valuePtr() + K_.nonZeros(), A.valuePtr())) {
        inactive_values_.resize(0);
        inactive_value_ptr_ = A.valuePtr();
        return;
      }
    }
    inactive_values_ = Eigen::Map<const Vector>(K_.valuePtr(), K_.nonZeros());
    inactive_value_ptr_ = inactive_values_.data();
  }

  /// The active-row value at storage position p (row i, column j): the identity's on A's own
  /// pattern (the LCP), else the stored I − B.
  double active_value(StorageIndex p, Eigen::Index i, Eigen::Index j) const {
    return active_values_.size() ? active_values_[p] : (i == j ? 1.0 : 0.0);
  }

  /// Any other case: the union of the patterns of A, I and B.
  template <typename MatrixType>
  void use_union_pattern(const MatrixType& A, const RowMatrix* B) {
    using Triplet = Eigen::Triplet<double, StorageIndex>;
    const Eigen::Index n = A.rows();
    // Two matrices on the same union pattern: the inactive-row values (A) and the active-row
    // values (I − B). setFromTriplets sorts and sums, and keeps zeros: the patterns coincide.
    std::vector<Triplet> ta, tb;
    ta.reserve(A.nonZeros() + n + (B ? B->nonZeros() : 0));
    tb.reserve(ta.capacity());
    for (Eigen::Index k = 0; k < A.outerSize(); ++k)
      for (typename MatrixType::InnerIterator it(A, k); it; ++it) {
        ta.emplace_back(it.row(), it.col(), it.value());
        tb.emplace_back(it.row(), it.col(), 0.0);
      }
    for (Eigen::Index i = 0; i < n; ++i) {
      ta.emplace_back(i, i, 0.0);
      tb.emplace_back(i, i, 1.0);
    }
    if (B)
      for (Eigen::Index k = 0; k < B->outerSize(); ++k)
        for (typename RowMatrix::InnerIterator it(*B, k); it; ++it) {
          ta.emplace_back(it.row(), it.col(), 0.0);
          tb.emplace_back(it.row(), it.col(), -it.value());
        }
    K_.resize(n, n);
    K_.setFromTriplets(ta.begin(), ta.end());
    K_.makeCompressed();
    ColMatrix Kb(n, n);
    Kb.setFromTriplets(tb.begin(), tb.end());
    Kb.makeCompressed();
    if (Kb.nonZeros() != K_.nonZeros()) throw std::logic_error("ActiveSetSystem: patterns differ");
    inactive_values_ = Eigen::Map<const Vector>(K_.valuePtr(), K_.nonZeros());
    inactive_value_ptr_ = inactive_values_.data();
    active_values_ = Eigen::Map<const Vector>(Kb.valuePtr(), Kb.nonZeros());
  }

  bool lcp_;
  ColMatrix K_;
  Vector inactive_values_, active_values_;
  const double* inactive_value_ptr_ = nullptr;  // the inactive-row values: inactive_values_, or A's own
  mutable Refactorizer<StorageIndex> solver_;  // mutable: analysed on first need (direct_solve)
  std::unique_ptr<MultigridKrylov<StorageIndex>> krylov_;
  std::vector<char> inactive_;  // of the last factorize (iterative)
  std::vector<Change<StorageIndex>> changes_;  // K's changed entries in the last factorize (iterative)
  Inner inner_ = Inner::Auto;
  bool spd_candidate_ = false;
  mutable bool analyzed_ = false, factorized_ = false;
};

}  // namespace nrmicp::detail
