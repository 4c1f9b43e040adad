// nrmicp — one multigrid V-cycle on the reduced system K and its Galerkin operators
// (detail/galerkin.hpp): one forward Gauss–Seidel sweep before the coarse correction, one backward
// sweep after it, a direct factorization on the coarsest level. Symmetric, so positive definite
// for a symmetric positive definite K: CG's preconditioner (detail/multigrid.hpp).
#pragma once

#include "../inner_solver.hpp"
#include "galerkin.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <cstddef>
#include <stdexcept>
#include <vector>

namespace nrmicp::detail {

template <typename StorageIndex>
class VCycle {
 public:
  using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex>;
  using RowMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, StorageIndex>;
  using Fine = Eigen::Map<const RowMatrix>;
  using Vector = Eigen::VectorXd;

  /// `symmetric`: the fine operator and its Galerkin operators are symmetric (the fused sweep
  /// scatters the residual by columns), else each level's reach is found at setup.
  VCycle(std::size_t levels, bool symmetric) : levels_(levels), symmetric_(symmetric) { s_.resize(levels_); }

  /// 1 / diag of every level and the coarsest factorization, after the operators changed (K and
  /// `fine`, its row-major storage; `ops`, its Galerkin operators). False if singular.
  bool setup(const ColMatrix& K, const Fine& fine, const GalerkinOperators<StorageIndex>& ops) {
    for (std::size_t l = 0; l < levels_; ++l) {
      s_[l].inv_diag = (l == 0 ? Vector(K.diagonal()) : Vector(ops.K(l).diagonal())).cwiseInverse();
      if (!s_[l].inv_diag.allFinite()) return false;
      if (!symmetric_) s_[l].reach = l == 0 ? reach_of(fine) : reach_of(ops.K(l));
    }
    const ColMatrix coarsest = levels_ == 0 ? K : ColMatrix(ops.K(levels_));
    try {
      coarsest_.compute(coarsest, Inner::Auto, "the coarsest multigrid level");
    } catch (const std::runtime_error&) {
      return false;
    }
    return true;
  }

  /// e ≈ K⁻¹ r: one V-cycle from the fine level (`fine`: K row-major).
  void apply(const Fine& fine, const GalerkinOperators<StorageIndex>& ops, const Vector& r, Vector& e) const {
    cycle(0, fine, ops, r, e);
  }

 private:
  /// e ≈ K_l⁻¹ r: one V-cycle on level l.
  void cycle(std::size_t l, const Fine& fine, const GalerkinOperators<StorageIndex>& ops, const Vector& r,
             Vector& e) const {
    if (l == levels_) { coarsest_.solve(r, e); return; }
    Smoother& k = s_[l];
    auto smooth_and_correct = [&](const auto& A) {
      presmooth(A, k.inv_diag, k.reach, r, e, k.res);
      k.rc.noalias() = ops.level(l).R * k.res;
      cycle(l + 1, fine, ops, k.rc, k.ec);
      e.noalias() += ops.level(l).P * k.ec;
      gauss_seidel(A, k.inv_diag, r, e, false);
    };
    if (l == 0) smooth_and_correct(fine);
    else smooth_and_correct(ops.K(l));
  }

  /// One Gauss–Seidel sweep on M e = r, forward or backward; `after_row(i)` runs once e_i is new.
  struct NoHook {
    void operator()(Eigen::Index) const {}
  };
  template <typename M, typename AfterRow = NoHook>
  static void gauss_seidel(const M& A, const Vector& inv_diag, const Vector& r, Vector& e, bool forward,
                           AfterRow after_row = {}) {
    const Eigen::Index n = A.rows();
    const StorageIndex* outer = A.outerIndexPtr();
    const StorageIndex* col = A.innerIndexPtr();
    const double* v = A.valuePtr();
    for (Eigen::Index t = 0; t < n; ++t) {
      const Eigen::Index i = forward ? t : n - 1 - t;
      double sum = r[i];
      for (StorageIndex p = outer[i]; p < outer[i + 1]; ++p) sum -= v[p] * e[col[p]];
      e[i] += sum * inv_diag[i];
      after_row(i);
    }
  }

  /// The pre-smoothing of level l: the forward sweep on M e = r from e = 0 and the residual it
  /// leaves, res = r − M e = −(strict upper part of M) e, without a second read of M (docs/
  /// MEASUREMENTS.md, "Fused sweep"). A symmetric M: row j's entries left of the diagonal are column
  /// j's above it, so once e_j is known they scatter −m_ij e_j into res_i (i < j). Any M: row i's
  /// residual is final once e is known up to i + reach (M's largest column − row), so it is formed
  /// that many rows behind the sweep, while row i is still in cache (a grid's reach is a line or a
  /// plane of unknowns). Exact only for a plain sweep (inv_diag = 1 / diag(M): the lower part's
  /// residual it drops is zero then); a damped one needs the product again.
  template <typename M>
  void presmooth(const M& A, const Vector& inv_diag, Eigen::Index reach, const Vector& r, Vector& e, Vector& res) const {
    const Eigen::Index n = A.rows();
    const StorageIndex* outer = A.outerIndexPtr();
    const StorageIndex* col = A.innerIndexPtr();
    const double* v = A.valuePtr();
    e.setZero(n);
    res.resize(n);
    if (symmetric_) {
      gauss_seidel(A, inv_diag, r, e, true, [&](Eigen::Index j) {
        res[j] = 0.0;   // rows after j add to it
        for (StorageIndex p = outer[j]; p < outer[j + 1]; ++p)
          if (col[p] < j) res[col[p]] -= v[p] * e[j];
      });
      return;
    }
    auto upper_residual = [&](Eigen::Index i) {
      double s = 0.0;
      for (StorageIndex p = outer[i]; p < outer[i + 1]; ++p)
        if (col[p] > i) s -= v[p] * e[col[p]];
      res[i] = s;
    };
    gauss_seidel(A, inv_diag, r, e, true, [&](Eigen::Index j) {
      if (j >= reach) upper_residual(j - reach);
    });
    for (Eigen::Index i = std::max<Eigen::Index>(n - reach, 0); i < n; ++i) upper_residual(i);
  }

  /// The largest column − row of M's entries (0 for a lower-triangular M).
  template <typename M>
  static Eigen::Index reach_of(const M& A) {
    const StorageIndex* outer = A.outerIndexPtr();
    const StorageIndex* col = A.innerIndexPtr();
    Eigen::Index reach = 0;
    for (Eigen::Index i = 0; i < A.rows(); ++i)
      for (StorageIndex p = outer[i]; p < outer[i + 1]; ++p) reach = std::max<Eigen::Index>(reach, col[p] - i);
    return reach;
  }

  /// Level l's smoothing: 1 / diag(K_l) (l < coarsest) and the V-cycle's vectors there.
  struct Smoother {
    Vector inv_diag, res, rc, ec;
    Eigen::Index reach = 0;   // nonsymmetric K_l: its largest column − row (the lagged residual's)
  };
  std::size_t levels_;
  bool symmetric_;
  mutable std::vector<Smoother> s_;       // levels 0 (K), ..., L − 1 (the coarsest L is factorized)
  InnerSolver<StorageIndex> coarsest_;
};

}  // namespace nrmicp::detail
