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

#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>

namespace nrmicp {

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

template <typename SpMat>
bool is_symmetric(const SpMat& M) {
  using ColMat = Eigen::SparseMatrix<double, Eigen::ColMajor, typename SpMat::StorageIndex>;
  ColMat T = M.transpose();
  const double scale = M.norm();
  return (ColMat(M) - T).norm() <= 1e-14 * (scale > 0 ? scale : 1.0);
}

template <typename SpMat>
bool has_positive_diagonal(const SpMat& M) {
  return (M.diagonal().array() > 0).all();
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
    if (kind == Inner::Auto) {
      const bool spd_candidate = detail::is_symmetric(M) && detail::has_positive_diagonal(M);
      if (spd_candidate) {
        // Cholesky fails cleanly on an indefinite matrix; fall back to LU then.
        if (try_compute(M, have_cholmod() ? Inner::Cholmod : Inner::EigenLLT)) return;
      }
      if (try_compute(M, have_umfpack() ? Inner::Umfpack : Inner::EigenLU)) return;
      throw std::runtime_error("InnerSolver: factorization of " + what + " failed (the matrix is singular)");
    }
    if (!try_compute(M, kind))
      throw std::runtime_error("InnerSolver: " + std::string(name_of(kind)) + " factorization of " + what +
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
  template <typename EigenSolver>
  struct Impl : Base {
    ColMatrix mat;  // the solver refers to it
    EigenSolver solver;
    bool compute(ColMatrix M) {
      mat = std::move(M);
#if defined(NRMICP_HAVE_CHOLMOD)
      // CHOLMOD prints its warnings (e.g. "not positive definite") to stdout; we report
      // failures ourselves, and a library must not write to the user's terminal.
      if constexpr (std::is_base_of_v<Eigen::CholmodBase<ColMatrix, Eigen::Lower, EigenSolver>, EigenSolver>)
        solver.cholmod().print = 0;
#endif
      solver.compute(mat);
      return solver.info() == Eigen::Success;
    }
    void solve(const Vector& b, Vector& x) const override { x = solver.solve(b); }
    const ColMatrix& matrix() const override { return mat; }
  };

  template <typename EigenSolver>
  bool emplace(const ColMatrix& M, Inner k) {
    auto p = std::make_unique<Impl<EigenSolver>>();
    p->name = name_of(k);
    if (!p->compute(M)) return false;
    impl_ = std::move(p);
    return true;
  }

  bool try_compute(const ColMatrix& M, Inner k) {
    switch (k) {
      case Inner::Cholmod:
#if defined(NRMICP_HAVE_CHOLMOD)
        return emplace<Eigen::CholmodSupernodalLLT<ColMatrix, Eigen::Lower>>(M, k);
#else
        throw std::invalid_argument("inner = 'cholmod' but this build has no CHOLMOD (SuiteSparse was not found)");
#endif
      case Inner::Umfpack:
#if defined(NRMICP_HAVE_UMFPACK)
        return emplace<Eigen::UmfPackLU<ColMatrix>>(M, k);
#else
        throw std::invalid_argument("inner = 'umfpack' but this build has no UMFPACK (SuiteSparse was not found)");
#endif
      case Inner::EigenLLT:
        return emplace<Eigen::SimplicialLLT<ColMatrix, Eigen::Lower, Eigen::AMDOrdering<StorageIndex>>>(M, k);
      case Inner::EigenLU:
        // COLAMD: AMD ordering took 450 s at n = 250,000 on this machine, COLAMD 2.5 s.
        return emplace<Eigen::SparseLU<ColMatrix, Eigen::COLAMDOrdering<StorageIndex>>>(M, k);
      case Inner::CG:
        throw std::invalid_argument("inner = 'cg' is the iterative inner solve of method 'newton' only; the "
                                    "stationary members factorize their matrices (use 'auto' or a direct backend)");
      case Inner::Auto: break;
    }
    return false;
  }

  std::unique_ptr<Base> impl_;
};

}  // namespace nrmicp
