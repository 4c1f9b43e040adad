// nrmicp — sparse direct solvers behind one interface (Eigen's compute/solve/info).
#pragma once

#include "options.hpp"

#include <Eigen/OrderingMethods>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <Eigen/SparseLU>

#if defined(NRMICP_HAVE_CHOLMOD)
#include <Eigen/CholmodSupport>
#endif
#if defined(NRMICP_HAVE_UMFPACK)
#include <Eigen/UmfPackSupport>
#endif

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

namespace nrmicp {

/// A factorization failed. The Python module raises MemoryError for OutOfMemory and
/// numpy.linalg.LinAlgError for the others; the message names the matrix.
class FactorizationError : public std::runtime_error {
 public:
  enum class Reason {
    Singular,       ///< singular (or, for a Cholesky backend, not positive definite)
    OutOfMemory,    ///< the backend ran out of memory
    IndexOverflow,  ///< the factor does not fit the backend's integer type
    Failed,         ///< any other failure the backend reports
  };
  FactorizationError(Reason reason, const std::string& message) : std::runtime_error(message), reason_(reason) {}
  Reason reason() const { return reason_; }

 private:
  Reason reason_;
};

/// Which backends this build has.
inline bool have_cholmod() {
#if defined(NRMICP_HAVE_CHOLMOD)
  return true;
#else
  return false;
#endif
}
inline bool have_umfpack() {
#if defined(NRMICP_HAVE_UMFPACK)
  return true;
#else
  return false;
#endif
}

namespace detail {

/// The symmetry rule of both engines from the squared Frobenius norms of M − Mᵀ and of M.
inline bool symmetric_within_rounding(double diff2, double norm2) {
  return std::sqrt(diff2) <= 1e-14 * (norm2 > 0 ? std::sqrt(norm2) : 1.0);
}

/// ‖M − Mᵀ‖_F ≤ 1e-14 ‖M‖_F, read off M's compressed storage (each entry's mirror found by
/// binary search in its sorted inner vector; a mirror that is not stored is 0), without
/// forming Mᵀ, which showed in a nested Newton solve's profile (docs/MEASUREMENTS.md, "Inner solvers
/// and splittings").
template <typename SpMat>
bool is_symmetric(const SpMat& M) {
  using StorageIndex = typename SpMat::StorageIndex;
  if (!M.isCompressed()) {
    Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex> C = M;
    C.makeCompressed();
    return is_symmetric(C);
  }
  const StorageIndex* outer = M.outerIndexPtr();
  const StorageIndex* inner = M.innerIndexPtr();
  const double* v = M.valuePtr();
  double diff = 0, norm = 0;  // squared Frobenius norms (M is checked finite before it gets here)
  for (Eigen::Index k = 0; k < M.outerSize(); ++k)
    for (StorageIndex p = outer[k]; p < outer[k + 1]; ++p) {
      norm += v[p] * v[p];
      const StorageIndex j = inner[p];
      const StorageIndex* b = inner + outer[j];
      const StorageIndex* e = inner + outer[j + 1];
      const StorageIndex* f = std::lower_bound(b, e, static_cast<StorageIndex>(k));
      if (f != e && *f == k) {
        const double d = v[p] - v[f - inner];
        diff += d * d;  // the mirror's own visit adds the other half
      } else {
        diff += 2 * v[p] * v[p];  // both (k, j) and (j, k) of M − Mᵀ
      }
    }
  return symmetric_within_rounding(diff, norm);
}

template <typename SpMat>
bool has_positive_diagonal(const SpMat& M) {
  return (M.diagonal().array() > 0).all();
}

/// "row i" or "column j" of a compressed column-major M that has no nonzero value, else "".
/// Such a matrix is singular whatever its values: no factorization is attempted (Eigen's
/// SparseLU does not return on an all-zero matrix).
template <typename ColMatrix>
std::string empty_row_or_column(const ColMatrix& M) {
  std::vector<char> row_used(static_cast<std::size_t>(M.rows()), 0);
  Eigen::Index empty_col = -1;
  for (Eigen::Index j = 0; j < M.cols(); ++j) {
    bool used = false;
    for (typename ColMatrix::InnerIterator it(M, j); it; ++it)
      if (it.value() != 0) { used = true; row_used[static_cast<std::size_t>(it.row())] = 1; }
    if (!used && empty_col < 0) empty_col = j;
  }
  for (Eigen::Index i = 0; i < M.rows(); ++i)
    if (!row_used[static_cast<std::size_t>(i)]) return "row " + std::to_string(i);
  return empty_col < 0 ? std::string() : "column " + std::to_string(empty_col);
}

/// Whether a matrix with `entries` stored entries needs wider indices than StorageIndex has
/// (`limit` is a parameter for tests only).
template <typename StorageIndex>
bool needs_wide_indices(std::int64_t entries, std::int64_t limit = std::numeric_limits<StorageIndex>::max()) {
  return entries > limit;
}

/// What to tell a user whose 32-bit indices are too small for a factor.
template <typename StorageIndex>
std::string index_hint() {
  return sizeof(StorageIndex) < 8 ? "; with 32-bit indices the factor is limited to 2^31 - 1 entries: pass A with "
                                    "int64 indices (A.indices and A.indptr as np.int64) for the 64-bit backend"
                                  : "";
}

#if defined(NRMICP_HAVE_CHOLMOD)
/// Throws FactorizationError for a failure status of CHOLMOD (or a factor it did not make);
/// warnings (not positive definite) pass.
template <typename StorageIndex>
void check_cholmod(int status, bool has_factor, const std::string& what) {
  using R = FactorizationError::Reason;
  if (status == CHOLMOD_OUT_OF_MEMORY)
    throw FactorizationError(R::OutOfMemory, "InnerSolver: CHOLMOD ran out of memory factorizing " + what);
  if (status == CHOLMOD_TOO_LARGE)
    throw FactorizationError(R::IndexOverflow, "InnerSolver: the CHOLMOD factor of " + what +
                                                   " overflows its integer type" + detail::index_hint<StorageIndex>());
  if (status < 0 || !has_factor)
    throw FactorizationError(R::Failed, "InnerSolver: CHOLMOD failed on " + what + " (status " +
                                            std::to_string(status) + ")");
}
#endif
#if defined(NRMICP_HAVE_UMFPACK)
/// Throws FactorizationError for a failure status of UMFPACK; warnings (singular) pass.
template <typename StorageIndex>
void check_umfpack(int status, const std::string& what) {
  using R = FactorizationError::Reason;
  if (status == UMFPACK_ERROR_out_of_memory)
    throw FactorizationError(R::OutOfMemory, "InnerSolver: UMFPACK ran out of memory factorizing " + what +
                                                 detail::index_hint<StorageIndex>());
  if (status < 0)
    throw FactorizationError(R::Failed, "InnerSolver: UMFPACK failed on " + what + " (status " +
                                            std::to_string(status) + ")");
}
#endif

/// The backends `Inner::Auto` chooses: CHOLMOD for a symmetric matrix with a positive diagonal
/// (a Cholesky that then fails means not positive definite: LU instead), else UMFPACK; Eigen's
/// own solvers in a build without SuiteSparse.
inline Inner cholesky_backend() { return have_cholmod() ? Inner::Cholmod : Inner::EigenLLT; }
inline Inner lu_backend() { return have_umfpack() ? Inner::Umfpack : Inner::EigenLU; }
inline Inner resolve_backend(Inner kind, bool spd_candidate) {
  if (kind != Inner::Auto) return kind;
  return spd_candidate ? cholesky_backend() : lu_backend();
}

#if defined(NRMICP_HAVE_CHOLMOD)
/// Eigen's CHOLMOD LLᵀ, silent (CHOLMOD prints warnings to stdout; a library must not), and able
/// to say whether cholmod_analyze made a factor (Eigen's wrapper dereferences one it did not).
template <typename ColMatrix>
struct CholmodLLT : Eigen::CholmodSupernodalLLT<ColMatrix, Eigen::Lower> {
  CholmodLLT() { this->cholmod().print = 0; }
  bool has_factor() const { return this->m_cholmodFactor != nullptr; }
  /// CHOLMOD's estimate of the reciprocal condition number, (min diag L / max diag L)² ≥ 1/κ.
  double rcond() {
    if constexpr (sizeof(typename ColMatrix::StorageIndex) == 8)
      return cholmod_l_rcond(this->m_cholmodFactor, &this->cholmod());
    else
      return cholmod_rcond(this->m_cholmodFactor, &this->cholmod());
  }
};
#endif

/// A numeric factorization that solves can use: Eigen's status (not positive definite is a
/// warning status for a Cholesky), and for CHOLMOD no pivot within rounding of zero.
template <typename EigenSolver>
bool factored(EigenSolver& s) {
  return s.info() == Eigen::Success;
}
#if defined(NRMICP_HAVE_CHOLMOD)
/// Pivots this close to rounding (min/max pivot of LLᵀ; κ ≳ 4.5e12) mean a singular matrix: its
/// solves would follow the machine's rounding, which differs between CPUs (docs/MEASUREMENTS.md,
/// "Inner solvers and splittings").
inline constexpr double singular_rcond = 1e3 * std::numeric_limits<double>::epsilon();
template <typename ColMatrix>
bool factored(CholmodLLT<ColMatrix>& s) {
  return s.info() == Eigen::Success && s.rcond() >= singular_rcond;
}
#endif
#if defined(NRMICP_HAVE_UMFPACK)
/// Eigen's UMFPACK LU, with UMFPACK's status.
template <typename ColMatrix>
struct UmfpackLU : Eigen::UmfPackLU<ColMatrix> {
  int status() const { return static_cast<int>(this->m_fact_errorCode); }
};
#endif

template <typename T>
struct Backend {
  using type = T;
};

/// f(Backend<S>{}) for the Eigen solver type S of the concrete backend `k` (not Auto: resolve it
/// first); throws std::invalid_argument for a backend this build lacks, and for 'cg'.
template <typename ColMatrix, typename F>
decltype(auto) with_backend(Inner k, F&& f) {
  using StorageIndex = typename ColMatrix::StorageIndex;
  switch (k) {
    case Inner::Cholmod:
#if defined(NRMICP_HAVE_CHOLMOD)
      return f(Backend<CholmodLLT<ColMatrix>>{});
#else
      throw std::invalid_argument("inner = 'cholmod' but this build has no CHOLMOD (SuiteSparse was not found)");
#endif
    case Inner::Umfpack:
#if defined(NRMICP_HAVE_UMFPACK)
      return f(Backend<UmfpackLU<ColMatrix>>{});
#else
      throw std::invalid_argument("inner = 'umfpack' but this build has no UMFPACK (SuiteSparse was not found)");
#endif
    case Inner::EigenLLT:
      return f(Backend<Eigen::SimplicialLLT<ColMatrix, Eigen::Lower, Eigen::AMDOrdering<StorageIndex>>>{});
    case Inner::EigenLU:
      // COLAMD: AMD ordering is far slower for SparseLU (docs/MEASUREMENTS.md, "Inner solvers and splittings").
      return f(Backend<Eigen::SparseLU<ColMatrix, Eigen::COLAMDOrdering<StorageIndex>>>{});
    case Inner::CG:
      throw std::invalid_argument("inner = 'cg' is the iterative inner solve of method 'newton' only; the "
                                  "stationary members factorize their matrices (use 'auto' or a direct backend)");
    case Inner::Auto: break;
  }
  throw std::logic_error("with_backend: inner = 'auto' must be resolved first (resolve_backend)");
}

}  // namespace detail

/// Factorizes a sparse matrix once and solves with it many times. Keeps its own copy of the
/// matrix: UMFPACK's solve reads the matrix again (iterative refinement).
template <typename StorageIndex = int>
class InnerSolver {
 public:
  using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex>;
  using Vector = Eigen::VectorXd;

  /// Factorizes M with the requested backend (Auto: CHOLMOD for SPD, else UMFPACK, Eigen's
  /// solvers without SuiteSparse). `what` names the matrix in error messages.
  void compute(ColMatrix M, Inner kind, const std::string& what) {
    M.makeCompressed();
    if (M.rows() == 0) {  // (a process without rows: nothing to factorize, and CHOLMOD refuses 0 × 0)
      impl_ = std::make_unique<Empty>();
      return;
    }
    const std::string empty = detail::empty_row_or_column(M);
    if (!empty.empty())
      throw FactorizationError(FactorizationError::Reason::Singular,
                               "InnerSolver: " + what + " is singular: its " + empty +
                                   " has no nonzero entry (every factorization fails on it)");
    if (kind == Inner::Auto) {
      const bool spd_candidate = detail::is_symmetric(M) && detail::has_positive_diagonal(M);
      if (spd_candidate && try_compute(M, detail::cholesky_backend(), what)) return;  // else LU
      if (try_compute(M, detail::lu_backend(), what)) return;
      throw FactorizationError(FactorizationError::Reason::Singular,
                               "InnerSolver: factorization of " + what + " failed (the matrix is singular)");
    }
    if (!try_compute(M, kind, what))
      throw FactorizationError(FactorizationError::Reason::Singular,
                               "InnerSolver: " + std::string(name_of(kind)) + " factorization of " + what +
                                   " failed (singular, or not positive definite for a Cholesky backend)");
  }

  /// x = M⁻¹ b.
  void solve(const Vector& b, Vector& x) const { impl_->solve(b, x); }
  bool ready() const { return static_cast<bool>(impl_); }
  /// The factorized matrix (a copy kept for the backend).
  const ColMatrix& matrix() const { return impl_->matrix(); }
  const char* name() const { return impl_ ? impl_->name : "none"; }

  static const char* name_of(Inner k) { return to_string(k); }

 private:
  struct Base {
    const char* name = "";
    virtual ~Base() = default;
    virtual void solve(const Vector& b, Vector& x) const = 0;
    virtual const ColMatrix& matrix() const = 0;
  };
#if defined(NRMICP_HAVE_CHOLMOD)
  static bool factorize(detail::CholmodLLT<ColMatrix>& s, const ColMatrix& M, const std::string& what) {
    s.analyzePattern(M);
    detail::check_cholmod<StorageIndex>(s.cholmod().status, s.has_factor(), what);
    s.factorize(M);
    detail::check_cholmod<StorageIndex>(s.cholmod().status, true, what);
    return detail::factored(s);
  }
#endif
#if defined(NRMICP_HAVE_UMFPACK)
  static bool factorize(detail::UmfpackLU<ColMatrix>& s, const ColMatrix& M, const std::string& what) {
    s.analyzePattern(M);
    detail::check_umfpack<StorageIndex>(s.status(), what);
    s.factorize(M);
    detail::check_umfpack<StorageIndex>(s.status(), what);
    return s.status() == UMFPACK_OK;  // UMFPACK_WARNING_singular_matrix: singular
  }
#endif
  // Eigen's own solvers: failures are numerical (out of memory throws std::bad_alloc).
  template <typename EigenSolver>
  static bool factorize(EigenSolver& s, const ColMatrix& M, const std::string&) {
    s.compute(M);
    return detail::factored(s);
  }

  struct Empty : Base {
    ColMatrix mat;
    Empty() { this->name = "none"; }
    void solve(const Vector&, Vector& x) const override { x.resize(0); }
    const ColMatrix& matrix() const override { return mat; }
  };

  template <typename EigenSolver>
  struct Impl : Base {
    ColMatrix mat;  // the solver refers to it
    EigenSolver solver;
    void solve(const Vector& b, Vector& x) const override { x = solver.solve(b); }
    const ColMatrix& matrix() const override { return mat; }
  };

  template <typename EigenSolver>
  bool emplace(const ColMatrix& M, Inner k, const std::string& what) {
    auto p = std::make_unique<Impl<EigenSolver>>();
    p->name = name_of(k);
    p->mat = M;
    if (!factorize(p->solver, p->mat, what)) return false;
    impl_ = std::move(p);
    return true;
  }

  bool try_compute(const ColMatrix& M, Inner k, const std::string& what) {
    return detail::with_backend<ColMatrix>(
        k, [&](auto backend) { return emplace<typename decltype(backend)::type>(M, k, what); });
  }

  std::unique_ptr<Base> impl_;
};

}  // namespace nrmicp
