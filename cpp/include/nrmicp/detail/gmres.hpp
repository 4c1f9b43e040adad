// nrmicp — restarted, right-preconditioned flexible GMRES (Saad's FGMRES) for an operator known
// only by its products: the Krylov solve of the matrix-free Newton step (detail/matrix_free.hpp).
//
// Right preconditioning minimizes the true residual ‖b − Kx‖ (not a preconditioned one), which is
// what the step's absolute target is about; "flexible" keeps the preconditioned directions
// Z = M⁻¹V, so the preconditioner may change from one application to the next (an inner CG
// stopped at a tolerance, as the V-cycle-preconditioned solve of the LCP piece is). The basis
// grows by one pair of n-vectors per iteration, up to `restart` pairs, allocated on first need
// and kept for the next solve. Vectors hold the rows a process owns: inner products and norms are
// reduced over every process by the Comm (detail/comm.hpp; serially nothing).
#pragma once

#include "comm.hpp"

#include <Eigen/Core>

#include <cmath>
#include <vector>

namespace nrmicp::detail {

class Gmres {
 public:
  using Vector = Eigen::VectorXd;

  /// Krylov dimension before a restart, and the iterations of one solve in all.
  explicit Gmres(int restart = 30, int max_iterations = 300, const Comm& comm = serial_comm())
      : restart_(restart), max_iterations_(max_iterations), comm_(&comm) {}

  /// x ← x + the correction with ‖b − Kx‖ ≤ `target` (absolute), from the start x; `apply(v, out)`:
  /// out = K v, `precondition(v, out)`: out ≈ K⁻¹ v. Returns the iterations (products with K) taken;
  /// stops early, keeping the best x of the last cycle, after max_iterations or when a product is
  /// not finite (then x is not finite either: the caller's step fails). `residual()` is then the
  /// last residual estimate.
  template <typename Apply, typename Precondition>
  int solve(Apply&& apply, Precondition&& precondition, const Vector& b, Vector& x, double target) {
    double tau = 1.0;
    const int k = solve_in_units(*comm_, b, x, target, [&](const Vector& bt, Vector& xt, double t) {
      return cycles(apply, precondition, bt, xt, t);
    }, &tau);
    residual_ *= tau;
    return k;
  }
  double residual() const { return residual_; }

 private:
  /// solve() in units where b's size is near 1 (Comm::units).
  template <typename Apply, typename Precondition>
  int cycles(Apply& apply, Precondition& precondition, const Vector& b, Vector& x, double target) {
    int total = 0;
    r_ = b;
    if (comm_->sum(x.squaredNorm()) > 0) { apply(x, w_); r_ -= w_; }  // the start's residual (zero start: b)
    double beta = comm_->norm(r_);
    while (beta > target && std::isfinite(beta) && total < max_iterations_) {
      const int k = cycle(apply, precondition, beta, target, total);
      update(x, k);
      if (residual_ <= target || !std::isfinite(residual_) || total >= max_iterations_) break;
      r_ = b;  // the true residual for the restart (the estimate drifts from it)
      apply(x, w_);
      r_ -= w_;
      beta = comm_->norm(r_);
    }
    if (total == 0) residual_ = beta;
    return total;
  }
  /// One cycle from r_ (‖r_‖ = beta): Arnoldi (modified Gram–Schmidt) with Givens rotations
  /// until the residual estimate |g_{k}| ≤ target, a breakdown, `restart` or max_iterations. Returns k.
  template <typename Apply, typename Precondition>
  int cycle(Apply& apply, Precondition& precondition, double beta, double target, int& total) {
    const int m = restart_;
    h_.setZero(m + 1, m);
    g_.setZero(m + 1);
    cs_.resize(m); sn_.resize(m);
    g_[0] = beta;
    basis(0) = r_ / beta;
    int k = 0;
    while (k < m && total < max_iterations_) {
      if (static_cast<int>(z_.size()) <= k) z_.emplace_back(r_.size());
      precondition(v_[k], z_[k]);
      apply(z_[k], w_);
      ++total;
      for (int i = 0; i <= k; ++i) {
        h_(i, k) = comm_->sum(w_.dot(v_[i]));
        w_ -= h_(i, k) * v_[i];
      }
      const double w_norm = comm_->norm(w_);
      h_(k + 1, k) = w_norm;
      for (int i = 0; i < k; ++i) rotate(i, h_(i, k), h_(i + 1, k));
      givens(k);
      rotate(k, g_[k], g_[k + 1]);
      ++k;
      residual_ = std::abs(g_[k]);
      if (!(residual_ > target) || !(w_norm > 0)) break;  // converged, broken down (exact), or NaN
      basis(k) = w_ / w_norm;
    }
    return k;
  }
  /// x += Z y with H(0:k, 0:k) y = g(0:k) (upper triangular after the rotations).
  void update(Vector& x, int k) {
    if (k == 0) return;
    const Vector y = h_.topLeftCorner(k, k).triangularView<Eigen::Upper>().solve(g_.head(k));
    for (int i = 0; i < k; ++i) x += y[i] * z_[i];
  }
  /// The rotation that zeroes H(k+1, k), applied to column k.
  void givens(int k) {
    const double a = h_(k, k), b = h_(k + 1, k), r = std::hypot(a, b);
    cs_[k] = r > 0 ? a / r : 1.0;
    sn_[k] = r > 0 ? b / r : 0.0;
    h_(k, k) = r;
    h_(k + 1, k) = 0.0;
  }
  void rotate(int i, double& a, double& b) const {
    const double t = cs_[i] * a + sn_[i] * b;
    b = -sn_[i] * a + cs_[i] * b;
    a = t;
  }
  Vector& basis(int k) {
    if (static_cast<int>(v_.size()) <= k) v_.emplace_back(r_.size());
    return v_[k];
  }

  int restart_, max_iterations_;
  const Comm* comm_;
  std::vector<Vector> v_, z_;  // the Arnoldi basis and its preconditioned directions (kept across solves)
  Vector r_, w_, g_, cs_, sn_;
  Eigen::MatrixXd h_;
  double residual_ = 0;
};

}  // namespace nrmicp::detail
