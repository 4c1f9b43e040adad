// nrmicp — Anderson acceleration (type II) of a fixed-point map x ↦ x + f(x), with a
// bounded memory. The safeguard (reject a step that does not reduce Res) lives in the solver.
//
// The differences live in a preallocated ring buffer and their Gram matrix is updated one row
// per step (m dot products, not m²/2), so a step costs O(m n) with no allocation: at n = 10⁵
// the old deque-of-fresh-vectors version spent more time in page faults than in the sweep.
#pragma once

#include <Eigen/Dense>

#include <vector>

namespace nrmicp::detail {

class Anderson {
 public:
  using Vector = Eigen::VectorXd;
  explicit Anderson(int m) : m_(m), G_(Eigen::MatrixXd::Zero(m, m)) {}

  /// Given the current iterate x and its fixed-point step f = G(x) − x, returns the
  /// accelerated next iterate in x_next.
  void step(const Vector& x, const Vector& f, Vector& x_next) {
    const Eigen::Index n = x.size();
    if (dx_.empty()) {
      dx_.assign(m_, Vector(n));
      df_.assign(m_, Vector(n));
    }
    if (has_prev_) {
      const int s = (head_ + count_) % m_;  // slot of the new difference (overwrites the oldest when full)
      dx_[s] = x - x_prev_;
      df_[s] = f - f_prev_;
      if (count_ < m_) ++count_; else head_ = (head_ + 1) % m_;
      for (int i = 0; i < count_; ++i) {
        const int t = slot(i);
        G_(s, t) = G_(t, s) = df_[s].dot(df_[t]);
      }
    }
    x_prev_ = x;
    f_prev_ = f;
    has_prev_ = true;
    x_next = x + f;
    const int k = count_;
    if (k == 0) return;
    // min_g ‖f − ΔF g‖ by the (regularized) normal equations: k ≤ m is small.
    Eigen::MatrixXd Gk(k, k);
    Eigen::VectorXd b(k);
    for (int i = 0; i < k; ++i) {
      b[i] = df_[slot(i)].dot(f);
      for (int j = 0; j < k; ++j) Gk(i, j) = G_(slot(i), slot(j));
    }
    const double reg = 1e-12 * (Gk.trace() > 0 ? Gk.trace() : 1.0);
    Gk.diagonal().array() += reg;
    const Eigen::VectorXd g = Gk.ldlt().solve(b);
    if (!g.allFinite()) return;
    for (int i = 0; i < k; ++i) x_next -= g[i] * (dx_[slot(i)] + df_[slot(i)]);
  }

  /// Forget the differences (after a rejected step); the last (x, f) pair is kept.
  void reset() { count_ = 0; head_ = 0; }

 private:
  int slot(int i) const { return (head_ + i) % m_; }
  int m_;
  int head_ = 0, count_ = 0;
  bool has_prev_ = false;
  Vector x_prev_, f_prev_;
  std::vector<Vector> dx_, df_;
  Eigen::MatrixXd G_;
};

}  // namespace nrmicp::detail
