// nrmicp — bounds in the Newton member's obstacle problem, solved in y = z − s (s: the finite
// lower bound where there is one, else the finite upper one, else 0):
//   lo ≤ y ≤ hi,  lo_i ∈ {0, −∞},  hi_i ∈ [0, +∞]           (a row with −∞ and +∞ is free)
// with PATH's conditions: w = Ay + q' ≥ 0 where y = lo, ≤ 0 where y = hi, = 0 strictly between, and
// Res = ‖mid(y − lo, y − hi, w)‖₂ = ‖min(y − lo, max(y − hi, w))‖₂ (the paper's Res without hi).
// The LCP (y ≥ 0) is the Box with no vectors and costs nothing; a row's place in an active set is
// one of three states, the inactive one (w = 0) being the LCP's `true`.
#pragma once

#include "residual.hpp"

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include <algorithm>
#include <limits>

namespace nrmicp::detail {

/// A row's state in an active set: at its lower bound, inactive (w = 0), at its upper bound.
enum : char { kAtLower = 0, kInactive = 1, kAtUpper = 2 };
inline bool inactive_state(char s) { return s == kInactive; }

struct Box {
  using Vector = Eigen::VectorXd;
  Vector lo, hi;  ///< empty: 0 resp. +∞ on every row

  bool empty() const { return lo.size() == 0 && hi.size() == 0; }
  double lower(Eigen::Index i) const { return lo.size() ? lo[i] : 0.0; }
  double upper(Eigen::Index i) const { return hi.size() ? hi[i] : std::numeric_limits<double>::infinity(); }
  double clamp(Eigen::Index i, double v) const { return std::min(upper(i), std::max(lower(i), v)); }
  /// The state of row i at y_i, w_i with the active-set weight r = Ω1/Ω2: x = y − r w below lo is at
  /// the lower bound, above hi at the upper one, else inactive (ties inactive: NewtonLevel::active_set).
  char state(double y, double w, double r, Eigen::Index i) const {
    const double x = y - r * w;
    return x < lower(i) ? kAtLower : x > upper(i) ? kAtUpper : kInactive;
  }
  /// The value an active row holds: its bound.
  double bound(char s, Eigen::Index i) const { return s == kAtUpper ? upper(i) : lower(i); }
  /// Res = ‖mid(y − lo, y − hi, w)‖₂, without overflow or underflow.
  double residual(const Vector& w, const Vector& y) const {
    if (empty()) return residual_of(w, y);
    Vector m(y.size());
    for (Eigen::Index i = 0; i < y.size(); ++i) m[i] = std::min(y[i] - lower(i), std::max(y[i] - upper(i), w[i]));
    return stable_norm(m);
  }
  /// y projected onto the box, in place.
  void project(Vector& y) const {
    if (empty()) { y = y.cwiseMax(0.0); return; }
    for (Eigen::Index i = 0; i < y.size(); ++i) y[i] = clamp(i, y[i]);
  }

  /// The box of the next coarser level (y_fine ≈ P y_coarse): a coarse row is bounded where any
  /// fine row it reaches is (lo: the largest, hi: the smallest), free where all of them are, so a
  /// row free on the finest level stays free on every level. The nested start is projected onto the
  /// finest box, so a coarse box needs only to make a good start, not to be exact.
  template <typename RowMatrix>
  Box coarse(const RowMatrix& P) const {
    if (empty()) return {};
    constexpr double inf = std::numeric_limits<double>::infinity();
    Box c;
    if (lo.size()) c.lo = Vector::Constant(P.cols(), -inf);
    if (hi.size()) c.hi = Vector::Constant(P.cols(), inf);
    for (Eigen::Index i = 0; i < P.rows(); ++i)
      for (typename RowMatrix::InnerIterator it(P, i); it; ++it) {
        if (it.value() == 0) continue;
        if (lo.size()) c.lo[it.index()] = std::max(c.lo[it.index()], lo[i]);
        if (hi.size()) c.hi[it.index()] = std::min(c.hi[it.index()], hi[i]);
      }
    return c;
  }
};

}  // namespace nrmicp::detail
