// nrmicp — Anderson acceleration (type II) of a fixed-point map x ↦ x + f(x), with a
// bounded memory, and `Accelerated`, which wraps any step of Method 3.1 with it (safeguarded:
// a step that does not reduce Res is replaced by the plain step).
//
// The differences live in a preallocated ring buffer and their Gram matrix is updated one row
// per step (m dot products, not m²/2), so a step costs O(m n) with no allocation: at n = 10⁵
// the old deque-of-fresh-vectors version spent more time in page faults than in the sweep.
#pragma once

#include "iterate.hpp"
#include "stopping.hpp"

#include <Eigen/Dense>

#include <limits>
#include <vector>

namespace nrmicp::detail {

class Anderson {
 public:
  using Vector = Eigen::VectorXd;
  /// `comm`: the processes that own the other rows of the iterates (their inner products are global).
  explicit Anderson(int m, const Comm& comm = serial_comm()) : m_(m), G_(Eigen::MatrixXd::Zero(m, m)), comm_(comm) {}

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
      if (count_ == 0) tau_ = comm_.units(df_[s]);  // the memory's units (Comm::units), until it restarts
      if (tau_ != 1.0) df_[s] /= tau_;
      if (count_ < m_) ++count_; else head_ = (head_ + 1) % m_;
      Eigen::VectorXd dots(count_);
      for (int i = 0; i < count_; ++i) dots[i] = df_[s].dot(df_[slot(i)]);
      comm_.sum(dots.data(), count_);
      for (int i = 0; i < count_; ++i) G_(s, slot(i)) = G_(slot(i), s) = dots[i];
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
      b[i] = df_[slot(i)].dot(f) / tau_;
      for (int j = 0; j < k; ++j) Gk(i, j) = G_(slot(i), slot(j));
    }
    comm_.sum(b.data(), k);
    const double reg = 1e-12 * (Gk.trace() > 0 ? Gk.trace() : 1.0);
    Gk.diagonal().array() += reg;
    const Eigen::VectorXd g = Gk.ldlt().solve(b);
    if (!g.allFinite()) return;
    for (int i = 0; i < k; ++i) x_next -= g[i] * (dx_[slot(i)] + tau_ * df_[slot(i)]);
  }

  /// Forget the differences (after a rejected step); the last (x, f) pair is kept.
  void reset() { count_ = 0; head_ = 0; }
  /// Forget the differences, then record (x, f) (a rejected mix and its step): the memory restarts
  /// from the one difference between the last pair and it, both exact samples of the map.
  void restart(const Vector& x, const Vector& f) {
    reset();
    Vector unused;
    step(x, f, unused);
  }
  /// The differences the last step mixed (0: it was the plain step x + f).
  int size() const { return count_; }

 private:
  int slot(int i) const { return (head_ + i) % m_; }
  int m_;
  int head_ = 0, count_ = 0;
  bool has_prev_ = false;
  double tau_ = 1.0;  // the units df_ is kept in
  Vector x_prev_, f_prev_;
  std::vector<Vector> dx_, df_;
  Eigen::MatrixXd G_;
  const Comm& comm_;
};

/// Any step (the interface at the top of solver.hpp), accelerated: x⁽ᵏ⁺¹⁾ is Anderson's mix of
/// the plain steps, and z is recomputed from it by the z-update. When the accelerated iterate
/// does not reduce Res, it is replaced by the plain step's x and the memory is cleared.
template <typename Step, typename ContextType>
class Accelerated {
 public:
  using Vector = Eigen::VectorXd;
  Accelerated(Step& plain, ContextType& ctx, int m) : plain_(plain), ctx_(ctx), aa_(m, ctx.comm) {}

  double evaluate(Iterate& s) {
    x_k_ = s.x;  // the one-pass sweep moves x while it evaluates
    double r = plain_.evaluate(s);
    if (pending_ && s.zeta_ok && !(r < prev_res_)) {
      ++rejections_;
      s.x = x_plain_;
      aa_.reset();
      ctx_.z_update(s);
      x_k_ = s.x;
      r = plain_.evaluate(s);
    }
    pending_ = false;
    prev_res_ = r;
    return r;
  }
  void move_x(Iterate& s) {
    plain_.move_x(s);
    aa_.step(x_k_, plain_.dx(), x_next_);
    s.step = ctx_.comm.inf_norm(x_next_ - x_k_);
    x_plain_.swap(s.x);
    s.x.swap(x_next_);
    pending_ = true;
  }
  void update_z(Iterate& s) { ctx_.next_z(s); }
  const Vector& dx() const { return plain_.dx(); }
  /// Accelerated steps replaced by the plain one (Result::counters "anderson_rejections").
  void report(Result& r) const {
    plain_.report(r);
    r.counters["anderson_rejections"] += rejections_;
  }
  const StepEnd* end() const { return plain_.end(); }

 private:
  Step& plain_;
  ContextType& ctx_;
  Anderson aa_;
  Vector x_k_, x_plain_, x_next_;
  bool pending_ = false;  // x came from an Anderson step not yet checked
  long long rejections_ = 0;
  double prev_res_ = std::numeric_limits<double>::infinity();
};

}  // namespace nrmicp::detail
