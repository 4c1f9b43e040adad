// nrmicp — Anderson acceleration (type II) of a fixed-point map x ↦ x + f(x), with a
// bounded memory. The safeguard (reject a step that does not reduce Res) lives in the solver.
#pragma once

#include <Eigen/Dense>

#include <deque>

namespace nrmicp::detail {

class Anderson {
 public:
  using Vector = Eigen::VectorXd;
  explicit Anderson(int m) : m_(m) {}

  /// Given the current iterate x and its fixed-point step f = G(x) − x, returns the
  /// accelerated next iterate in x_next.
  void step(const Vector& x, const Vector& f, Vector& x_next) {
    if (has_prev_) {
      dx_.push_back(x - x_prev_);
      df_.push_back(f - f_prev_);
      if (static_cast<int>(dx_.size()) > m_) { dx_.pop_front(); df_.pop_front(); }
    }
    x_prev_ = x;
    f_prev_ = f;
    has_prev_ = true;
    const int k = static_cast<int>(df_.size());
    x_next = x + f;
    if (k == 0) return;
    // min_g ‖f − ΔF g‖ by the (regularized) normal equations: k ≤ m is small.
    Eigen::MatrixXd G(k, k);
    Eigen::VectorXd b(k);
    for (int i = 0; i < k; ++i) {
      b[i] = df_[i].dot(f);
      for (int j = 0; j <= i; ++j) G(i, j) = G(j, i) = df_[i].dot(df_[j]);
    }
    const double reg = 1e-12 * (G.trace() > 0 ? G.trace() : 1.0);
    G.diagonal().array() += reg;
    const Eigen::VectorXd g = G.ldlt().solve(b);
    if (!g.allFinite()) return;
    for (int i = 0; i < k; ++i) x_next -= g[i] * (dx_[i] + df_[i]);
  }

  /// Forget the differences (after a rejected step); the last (x, f) pair is kept.
  void reset() { dx_.clear(); df_.clear(); }

 private:
  int m_;
  bool has_prev_ = false;
  Vector x_prev_, f_prev_;
  std::deque<Vector> dx_, df_;
};

}  // namespace nrmicp::detail
