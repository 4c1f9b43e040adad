// nrmicp — the splitting A = M − N of each method, as the left matrix
//     Lm = Ω2 + (M + φ) Ω1
// of Method 3.1 and the way to solve with it. For the AOR-type members
// M = (D − βL)/α is lower triangular, so Lm is solved by forward substitution (or is
// diagonal when β = 0); for NRM and NRMM (M = A) Lm is factorized once.
#pragma once

#include "detail/comm.hpp"
#include "detail/engine.hpp"
#include "inner_solver.hpp"
#include "options.hpp"

#include <Eigen/SparseCore>

#include <cfloat>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace nrmicp {

/// diag(A) for any sparse matrix type (Eigen's Map<const SparseMatrix> has no diagonal()).
template <typename MatrixType>
Eigen::VectorXd diagonal(const MatrixType& A) {
  Eigen::VectorXd d = Eigen::VectorXd::Zero(A.rows());
  for (Eigen::Index k = 0; k < A.outerSize(); ++k)
    for (typename MatrixType::InnerIterator it(A, k); it; ++it)
      if (it.row() == it.col()) d[it.row()] += it.value();  // duplicates add up, as in A·x
  return d;
}

/// The Newton member's default Ω2: diag(A) where it is positive (not subnormal), else the row's
/// largest |a_ij| plus |a_ii| (1 for an empty row). Ω2 only weighs w against z − ζ in the
/// active-set test and sets the fallback member's Ω2, so a zero diagonal (contact, games) needs no
/// refusal; |a_ii| keeps the fallback's Ω2 + A from a zero diagonal where a_ii = −max_j |a_ij|
/// (a row (−1, 0, 0) would make it singular).
/// max_j |a_ij| of each row (an engine's matrix overloads it: petsc/engine.hpp).
template <typename MatrixType>
Eigen::VectorXd row_max_abs(const MatrixType& A) {
  Eigen::VectorXd row_max = Eigen::VectorXd::Zero(A.rows());
  for (Eigen::Index k = 0; k < A.outerSize(); ++k)
    for (typename MatrixType::InnerIterator it(A, k); it; ++it)
      row_max[it.row()] = std::max(row_max[it.row()], std::abs(it.value()));
  return row_max;
}
template <typename MatrixType>
Eigen::VectorXd newton_default_omega2(const MatrixType& A, const Eigen::VectorXd& d) {
  const Eigen::VectorXd row_max = row_max_abs(A);
  Eigen::VectorXd omega2 = d;
  for (Eigen::Index i = 0; i < d.size(); ++i)
    if (!(d[i] >= DBL_MIN)) {
      const double m = row_max[i] + std::abs(d[i]);
      omega2[i] = row_max[i] >= DBL_MIN && std::isfinite(m) ? m : 1.0;
    }
  return omega2;
}

/// The method's parameters with every default resolved (docs/SPEC.md).
struct Parameters {
  Eigen::VectorXd omega1, omega2, phi;
  Eigen::VectorXd diagonal;  ///< diag(A), computed once
  double gamma = 1, alpha = 1, beta = 1;
};

namespace detail {

/// mean(d) over every process's rows (1 when there are none): nrmm's default α, one value on every process.
inline double mean_diagonal(const Eigen::VectorXd& d, const Comm& comm) {
  const double rows = comm.sum(static_cast<double>(d.size()));
  return rows > 0 ? comm.sum(d.sum()) / rows : 1.0;  // (serially d.mean(), bit for bit)
}

/// α and β by the method's definition (into p), refusing those the method does not have. `comm`: the
/// processes that own the other rows of d = diag(A).
inline void resolve_alpha_beta(const Options& o, const Eigen::VectorXd& d, Parameters& p,
                               const Comm& comm = serial_comm()) {
  const bool has_alpha = !std::isnan(o.alpha), has_beta = !std::isnan(o.beta);
  auto reject = [&](bool given, const char* name, const char* why) {
    if (given)
      throw std::invalid_argument(std::string("Options: method '") + to_string(o.method) + "' has no " + name + " (" + why + ")");
  };
  switch (o.method) {
    case Method::NRM:
      reject(has_alpha, "alpha", "M = A; Omega2 = I unless omega2 is given; for Omega2 = alpha*I use 'nrmm'");
      reject(has_beta, "beta", "M = A");
      p.alpha = 1; p.beta = 1;
      break;
    case Method::NRMM:
      reject(has_beta, "beta", "M = A; alpha sets Omega2 = alpha*I");
      if (has_alpha && o.omega2.size())
        throw std::invalid_argument("Options: method 'nrmm' sets omega2 = alpha*I; give alpha or omega2, not both");
      p.alpha = has_alpha ? o.alpha : mean_diagonal(d, comm); p.beta = 1;
      if (!has_alpha && !o.omega2.size() && !(p.alpha >= DBL_MIN))
        throw std::invalid_argument("Options: method 'nrmm' takes alpha = mean(diag(A)) = " + to_text(p.alpha) +
                                    " by default, which must be > 0 and not subnormal; pass alpha (Omega2 = "
                                    "alpha*I) explicitly, or rescale A");
      break;
    case Method::NRMAOR: case Method::MMS: case Method::TwoSweep:
      p.alpha = has_alpha ? o.alpha : 1.0;
      p.beta = has_beta ? o.beta : p.alpha;
      break;
    case Method::NRMSOR:
      p.alpha = has_alpha ? o.alpha : 1.0;
      p.beta = p.alpha;
      if (has_beta && o.beta != p.alpha)
        throw std::invalid_argument("Options: method 'nrmsor' has beta = alpha; do not set beta (or use 'nrmaor')");
      break;
    case Method::NRMGS: case Method::NRMJ: case Method::Newton:
      if (has_alpha || has_beta)
        throw std::invalid_argument(std::string("Options: method '") + to_string(o.method) +
                                    "' fixes alpha and beta; use 'nrmaor' to choose them");
      p.alpha = 1; p.beta = (o.method == Method::NRMJ) ? 0 : 1;
      break;
  }
}

/// The default Ω2 = D = diag(A) of the AOR types, MMS and two-sweep: it divides by the diagonal.
inline const Eigen::VectorXd& diagonal_omega2(Method method, const Eigen::VectorXd& d) {
  for (Eigen::Index i = 0; i < d.size(); ++i)
    if (!(d[i] >= DBL_MIN))
      throw std::invalid_argument(std::string("Options: method '") + to_string(method) +
                                  "' takes omega2 = diag(A) by default, which needs a positive (not subnormal) "
                                  "diagonal, but A[" + std::to_string(i) + "," + std::to_string(i) + "] = " +
                                  to_text(d[i]) + " (it divides by the diagonal); on such a matrix use "
                                  "method 'newton', whose default omega2 needs no diagonal, or pass omega2 "
                                  "explicitly (e.g. the row maxima of |A|) with accelerate='anderson'");
  return d;
}

}  // namespace detail

/// Resolves the method defaults: Ω1 = I; Ω2 = I (NRM), αI (NRMM, α = mean diag A),
/// D = diag(A) (AOR types, MMS, two-sweep), newton_default_omega2 (Newton); φ = 0; α, β by the
/// method's definition.
template <typename MatrixType>
Parameters resolve_parameters(const MatrixType& A, const Options& o) {
  const Eigen::Index n = A.rows();
  Parameters p;
  p.diagonal = diagonal(A);
  p.gamma = o.gamma;
  using detail::comm_of;  // (an engine's matrix brings its own: petsc/engine.hpp)
  detail::resolve_alpha_beta(o, p.diagonal, p, comm_of(A));
  p.omega1 = o.omega1.size() ? o.omega1 : Eigen::VectorXd::Ones(n);
  p.phi = o.phi.size() ? o.phi : Eigen::VectorXd::Zero(n);
  if (o.omega2.size())
    p.omega2 = o.omega2;
  else if (o.method == Method::NRM)
    p.omega2 = Eigen::VectorXd::Ones(n);
  else if (o.method == Method::NRMM)
    p.omega2 = Eigen::VectorXd::Constant(n, p.alpha);
  else if (o.method == Method::Newton)
    p.omega2 = newton_default_omega2(A, p.diagonal);
  else
    p.omega2 = detail::diagonal_omega2(o.method, p.diagonal);
  if (!(p.omega2.array() >= DBL_MIN).all())
    throw std::invalid_argument("Options: omega2 must be positive and not subnormal");
  return p;
}

/// The splitting A = M − N of a method as explicit matrices, from the paper's formulas
/// (NRM/NRMM: M = A, N = 0; AOR types: M = (D − βL)/α, N = ((1−α)D + (α−β)L + αU)/α;
/// two-sweep: its first splitting M1, N1). For tests and for inspecting a method.
template <typename MatrixType>
std::pair<Eigen::SparseMatrix<double, Eigen::ColMajor, typename MatrixType::StorageIndex>,
          Eigen::SparseMatrix<double, Eigen::ColMajor, typename MatrixType::StorageIndex>>
splitting_matrices(const MatrixType& A, Method method, const Parameters& p) {
  using StorageIndex = typename MatrixType::StorageIndex;
  using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex>;
  using Triplet = Eigen::Triplet<double, StorageIndex>;
  const Eigen::Index n = A.rows();
  ColMatrix M(n, n), N(n, n);
  if (!is_aor_type(method)) {
    M = ColMatrix(A);
    return {M, N};
  }
  const double a = p.alpha, b = p.beta;
  std::vector<Triplet> tm, tn;
  for (Eigen::Index k = 0; k < A.outerSize(); ++k)
    for (typename MatrixType::InnerIterator it(A, k); it; ++it) {
      const double v = it.value();  // D = diag, L = −strict lower, U = −strict upper
      if (it.row() == it.col()) {
        tm.emplace_back(it.row(), it.col(), v / a);
        tn.emplace_back(it.row(), it.col(), (1 - a) * v / a);
      } else if (it.col() < it.row()) {
        tm.emplace_back(it.row(), it.col(), b * v / a);          // −βL/α with L = −v
        tn.emplace_back(it.row(), it.col(), -(a - b) * v / a);   // (α−β)L/α
      } else {
        tn.emplace_back(it.row(), it.col(), -v);                 // αU/α
      }
    }
  M.setFromTriplets(tm.begin(), tm.end());
  N.setFromTriplets(tn.begin(), tn.end());
  return {M, N};
}

/// How Lm is solved.
enum class LeftKind { Factorized, Lower, Diagonal };

/// Lm and its solver; for the two-sweep method also N2 (its second sweep).
template <typename StorageIndex = int>
class Splitting {
 public:
  using Vector = Eigen::VectorXd;
  using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex>;
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;

  /// `index_limit`: for tests only (the size above which Lm gets 64-bit indices).
  template <typename MatrixType>
  Splitting(const MatrixType& A, Method method, const Parameters& p, Inner inner,
            std::int64_t index_limit = std::numeric_limits<StorageIndex>::max()) {
    using Triplet = Eigen::Triplet<double, StorageIndex>;
    const Eigen::Index n = A.rows();
    std::vector<Triplet> t;
    if (!is_aor_type(method)) {
      kind_ = LeftKind::Factorized;
      // Lm has up to nnz + n entries: past 2^31 − 1 an int32 A gets a left matrix with 64-bit indices.
      wide_ = detail::needs_wide_indices<StorageIndex>(std::int64_t(A.nonZeros()) + n, index_limit);
      if (wide_)
        factorize_left(A, p, inner, wide_solver_);
      else
        factorize_left(A, p, inner, solver_);
      return;
    }
    // Lm = Ω2 + ((D − βL)/α + φ)Ω1: diagonal Ω2 + (d/α + φ)Ω1, strictly lower (β/α) a_ij Ω1_j.
    const double a = p.alpha, b = p.beta;
    lower_scale_ = b / a;
    diagonal_ = p.omega2 + (p.diagonal / a + p.phi).cwiseProduct(p.omega1);
    for (Eigen::Index i = 0; i < n; ++i)
      if (!(std::abs(diagonal_[i]) >= DBL_MIN) || !std::isfinite(diagonal_[i]))
        throw std::invalid_argument(
            "Splitting: the left matrix Omega2 + (D/alpha + phi) Omega1 has diagonal entry [" + std::to_string(i) +
            "] = " + to_text(diagonal_[i]) + " (zero, subnormal or not finite), from omega2 = " +
            to_text(p.omega2[i]) + ", A[i,i] = " + to_text(p.diagonal[i]) + ", alpha = " + to_text(a) +
            ", phi = " + to_text(p.phi[i]) + ", omega1 = " + to_text(p.omega1[i]));
    inverse_diagonal_ = diagonal_.cwiseInverse();
    const bool lower = (b != 0);
    kind_ = lower ? LeftKind::Lower : LeftKind::Diagonal;
    if (lower) {
      // Built on first use only: the one-sweep kernel (detail/sweep.hpp) reads A itself, so the
      // default path never needs this copy (docs/MEASUREMENTS.md, "Inner solvers and splittings").
      build_lower_ = [&A, omega1 = p.omega1, scale = b / a, this](RowMatrix& L) {
        std::vector<Triplet> tl;
        tl.reserve(A.nonZeros() / 2 + A.rows());
        for (Eigen::Index k = 0; k < A.outerSize(); ++k)
          for (typename MatrixType::InnerIterator it(A, k); it; ++it)
            if (it.col() < it.row() && it.value() != 0)
              tl.emplace_back(it.row(), it.col(), scale * it.value() * omega1[it.col()]);
        for (Eigen::Index i = 0; i < A.rows(); ++i) tl.emplace_back(i, i, diagonal_[i]);
        L.resize(A.rows(), A.rows());
        L.setFromTriplets(tl.begin(), tl.end());
        L.makeCompressed();
      };
    }
    if (method == Method::TwoSweep) {
      // N2 = M2 − A with M2 = D − U: N2 = L = −(strictly lower part of A).
      t.clear();
      for (Eigen::Index k = 0; k < A.outerSize(); ++k)
        for (typename MatrixType::InnerIterator it(A, k); it; ++it)
          if (it.col() < it.row() && it.value() != 0) t.emplace_back(it.row(), it.col(), -it.value());
      n2_.resize(n, n);
      n2_.setFromTriplets(t.begin(), t.end());
      n2_.makeCompressed();
    }
  }

  /// x = Lm⁻¹ r (r is overwritten for the triangular kinds).
  void solve(Vector& r, Vector& x) const {
    switch (kind_) {
      case LeftKind::Factorized:
        if (wide_) wide_solver_.solve(r, x); else solver_.solve(r, x);
        return;
      case LeftKind::Diagonal: x = r.cwiseQuotient(diagonal_); return;
      case LeftKind::Lower:
        lower().template triangularView<Eigen::Lower>().solveInPlace(r);
        x.swap(r);
        return;
    }
  }

  LeftKind kind() const { return kind_; }
  /// Whether Lm (NRM, NRMM) was built with 64-bit indices because nnz(A) + n overflows StorageIndex.
  bool wide_indices() const { return wide_; }

  /// Lm as a sparse matrix (built on demand: for tests and inspection).
  ColMatrix left_matrix() const {
    switch (kind_) {
      case LeftKind::Factorized: return wide_ ? ColMatrix(wide_solver_.matrix()) : solver_.matrix();
      case LeftKind::Lower: return ColMatrix(lower());
      case LeftKind::Diagonal: break;
    }
    ColMatrix D(diagonal_.size(), diagonal_.size());
    D.reserve(Eigen::VectorXi::Ones(diagonal_.size()));
    for (Eigen::Index i = 0; i < diagonal_.size(); ++i) D.insert(i, i) = diagonal_[i];
    return D;
  }
  const char* inner_name() const {
    switch (kind_) {
      case LeftKind::Factorized: return wide_ ? wide_solver_.name() : solver_.name();
      case LeftKind::Lower: return "forward_substitution";
      case LeftKind::Diagonal: return "diagonal";
    }
    return "?";
  }
  bool two_sweep() const { return n2_.rows() > 0; }
  /// 1 / diag(Lm) (AOR types) and the factor β/α of its strictly lower part (β/α) a_ij Ω1_j.
  const Vector& left_inverse_diagonal() const { return inverse_diagonal_; }
  double lower_scale() const { return lower_scale_; }
  const RowMatrix& n2() const { return n2_; }

 private:
  // Lm = Ω2 + (A + φ)Ω1, assembled with index type Index and factorized.
  template <typename MatrixType, typename Index>
  static void factorize_left(const MatrixType& A, const Parameters& p, Inner inner, InnerSolver<Index>& solver) {
    using Triplet = Eigen::Triplet<double, Index>;
    const Eigen::Index n = A.rows();
    std::vector<Triplet> t;
    t.reserve(static_cast<std::size_t>(A.nonZeros() + n));
    for (Eigen::Index k = 0; k < A.outerSize(); ++k)
      for (typename MatrixType::InnerIterator it(A, k); it; ++it)
        t.emplace_back(it.row(), it.col(), it.value() * p.omega1[it.col()]);
    for (Eigen::Index i = 0; i < n; ++i) t.emplace_back(i, i, p.omega2[i] + p.phi[i] * p.omega1[i]);
    Eigen::SparseMatrix<double, Eigen::ColMajor, Index> Lm(n, n);
    Lm.setFromTriplets(t.begin(), t.end());  // sums duplicates: the diagonal of A joins its shift
    solver.compute(std::move(Lm), inner, "the left matrix Omega2 + (A + phi) Omega1");
  }

  LeftKind kind_ = LeftKind::Factorized;
  bool wide_ = false;
  InnerSolver<StorageIndex> solver_;
  InnerSolver<std::int64_t> wide_solver_;  // Lm when wide_
  Vector diagonal_, inverse_diagonal_;
  double lower_scale_ = 0;
  const RowMatrix& lower() const {
    std::call_once(lower_once_, [this] { build_lower_(lower_); });
    return lower_;
  }
  std::function<void(RowMatrix&)> build_lower_;
  mutable std::once_flag lower_once_;
  mutable RowMatrix lower_;
  RowMatrix n2_;
};

}  // namespace nrmicp
