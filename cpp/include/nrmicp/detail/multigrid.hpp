// nrmicp — the iterative inner solve of the Newton member (inner = "cg"): conjugate gradients on
// the reduced system K of one Newton step (detail/active_set.hpp), preconditioned by one multigrid
// V-cycle built from the same prolongations P_0, P_1, ... the nested iteration uses.
//
// Per Newton step (setup): the Galerkin operators K_{l+1} = P_lᵀ K_l P_l of the reduced system
// (K changes with the active set, so they are recomputed) and a direct factorization of the
// coarsest one. The V-cycle smooths with one forward Gauss–Seidel sweep before the coarse
// correction and one backward sweep after it: a symmetric preconditioner, positive definite for
// symmetric positive definite K, so CG applies. K's active rows are identity rows with zeroed
// columns (the LCP): K stays SPD when A is, and so does every PᵀKP of full-rank P.
#pragma once

#include "../inner_solver.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

namespace nrmicp::detail {

template <typename StorageIndex>
class MultigridCG {
 public:
  using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex>;
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  using Vector = Eigen::VectorXd;

  /// CG stops when ‖b − Kz‖ ≤ rtol ‖b‖ (or an absolute target: the Newton loop asks for a tenth
  /// of its tol, so that the step on the right active set meets tol).
  static constexpr double rtol = 1e-12;
  static constexpr int max_iterations = 500;

  /// `P` points to `levels` prolongations (P[0]: level 1 → this level); they are copied.
  MultigridCG(const RowMatrix* P, std::size_t levels) : P_(P, P + levels) {
    for (const RowMatrix& p : P_) R_.emplace_back(p.transpose());
    coarse_ops_.resize(levels);
    work_.resize(levels + 1);
  }

  /// Galerkin operators of the symmetric K (its column storage is its row storage) and the
  /// coarsest factorization. K must outlive this until the next setup. False if singular.
  bool setup(const ColMatrix& K) {
    fine_ = &K;
    for (std::size_t l = 0; l < P_.size(); ++l) {
      RowMatrix KP = (l == 0) ? RowMatrix(rows(K) * P_[0]) : RowMatrix(coarse_ops_[l - 1] * P_[l]);
      coarse_ops_[l] = R_[l] * KP;
      coarse_ops_[l].makeCompressed();
    }
    inv_diag_.resize(P_.size());
    for (std::size_t l = 0; l < P_.size(); ++l) {
      inv_diag_[l] = (l == 0 ? Vector(K.diagonal()) : Vector(coarse_ops_[l - 1].diagonal())).cwiseInverse();
      if (!inv_diag_[l].allFinite()) return false;
    }
    const ColMatrix coarsest = P_.empty() ? K : ColMatrix(coarse_ops_.back());
    try {
      coarsest_.compute(coarsest, Inner::Auto, "the coarsest multigrid level");
    } catch (const std::runtime_error&) {
      return false;
    }
    return true;
  }

  /// Preconditioned CG for K z = b from the start z (the current Newton iterate: close), until
  /// ‖b − Kz‖ ≤ rtol ‖b‖ or ≤ `target` (absolute, if > 0). Returns the number of CG iterations
  /// (max_iterations + 1 when not converged).
  int solve(const Vector& b, Vector& z, double target = 0) const {
    const auto K = rows(*fine_);
    Vector r = b - K * z;
    double stop = rtol * b.norm();
    if (target > 0) stop = std::min(stop, target);
    if (r.norm() <= stop) return 0;
    Vector s(b.size()), p(b.size()), Kp(b.size());
    vcycle(0, r, s);
    p = s;
    double rs = r.dot(s);
    for (int k = 1; k <= max_iterations; ++k) {
      Kp.noalias() = K * p;
      const double alpha = rs / p.dot(Kp);
      z += alpha * p;
      r -= alpha * Kp;
      if (r.norm() <= stop) return k;
      vcycle(0, r, s);
      const double rs_new = r.dot(s);
      p = s + (rs_new / rs) * p;
      rs = rs_new;
    }
    return max_iterations + 1;
  }

  std::size_t levels() const { return P_.size() + 1; }

 private:
  /// K's column storage read as rows (K is symmetric).
  static Eigen::Map<const RowMatrix> rows(const ColMatrix& K) {
    return Eigen::Map<const RowMatrix>(K.rows(), K.cols(), K.nonZeros(), K.outerIndexPtr(), K.innerIndexPtr(),
                                       K.valuePtr());
  }

  /// One Gauss–Seidel sweep on M e = r, forward or backward.
  template <typename M>
  static void gauss_seidel(const M& A, const Vector& inv_diag, const Vector& r, Vector& e, bool forward) {
    const Eigen::Index n = A.rows();
    const StorageIndex* outer = A.outerIndexPtr();
    const StorageIndex* col = A.innerIndexPtr();
    const double* v = A.valuePtr();
    for (Eigen::Index t = 0; t < n; ++t) {
      const Eigen::Index i = forward ? t : n - 1 - t;
      double sum = r[i];
      for (StorageIndex p = outer[i]; p < outer[i + 1]; ++p) sum -= v[p] * e[col[p]];
      e[i] += sum * inv_diag[i];
    }
  }

  /// e ≈ K_l⁻¹ r: one V-cycle on level l.
  void vcycle(std::size_t l, const Vector& r, Vector& e) const {
    if (l == P_.size()) { coarsest_.solve(r, e); return; }
    Work& w = work_[l];
    e.setZero(r.size());
    auto smooth_and_correct = [&](const auto& A) {
      gauss_seidel(A, inv_diag_[l], r, e, true);
      w.res.noalias() = A * e;
      w.res = r - w.res;
      w.rc.noalias() = R_[l] * w.res;
      vcycle(l + 1, w.rc, w.ec);
      e.noalias() += P_[l] * w.ec;
      gauss_seidel(A, inv_diag_[l], r, e, false);
    };
    if (l == 0) smooth_and_correct(rows(*fine_));
    else smooth_and_correct(coarse_ops_[l - 1]);
  }

  struct Work {
    Vector res, rc, ec;
  };
  std::vector<RowMatrix> P_, R_;          // prolongations and their transposes (restrictions)
  std::vector<RowMatrix> coarse_ops_;     // K_1, K_2, ...: Galerkin operators of the reduced system
  std::vector<Vector> inv_diag_;          // 1 / diag(K_l), l < coarsest
  const ColMatrix* fine_ = nullptr;
  InnerSolver<StorageIndex> coarsest_;
  mutable std::vector<Work> work_;
};

}  // namespace nrmicp::detail
