// nrmicp — bounds: the box problem
//   lo ≤ y ≤ hi   (lo_i may be −∞, hi_i +∞; a row with both is free)
// with PATH's conditions: w = Ay + q ≥ 0 where y = lo, ≤ 0 where y = hi, = 0 strictly between, and
// Res = ‖mid(y − lo, y − hi, w)‖₂ = ‖min(y − lo, max(y − hi, w))‖₂ (the paper's Res without hi).
// The Newton member solves it in z itself (y = z); the modulus members in y = z − s, s the finite
// lower bound where there is one, else the finite upper one, else 0, so that lo_i ∈ {0, −∞}
// (ShiftedBounds; detail/modulus.hpp). The LCP (y ≥ 0) is the Box with no vectors and costs nothing;
// a row's place in an active set is one of three states, the inactive one (w = 0) the LCP's `true`.
#pragma once

#include "comm.hpp"
#include "engine.hpp"
#include "residual.hpp"

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <limits>

namespace nrmicp::detail {

/// Res = ‖mid(z − ζ, z − u, w)‖₂ = ‖min(g, max(z − u, w))‖₂ (g = z − ζ(z)) of an ICP with the upper
/// bound u (empty: none, the paper's Res). A row whose bounds cross (ζ > u, i.e. z − u > g: bounds
/// that depend on z) has no point between them, and there min(g, max(z − u, w)) would be 0 at z = ζ:
/// its term is max(z − u, ζ − z) instead, the larger violation of the two bounds (at least (ζ − u)/2),
/// so that Res vanishes only at a z that satisfies both (docs/SPEC.md, "Bounds").
/// `comm`: the processes that own the other rows (detail/comm.hpp).
inline double bounded_residual(const Eigen::VectorXd& w, const Eigen::VectorXd& g, const Eigen::VectorXd& z,
                               const Eigen::VectorXd& upper, const Comm& comm = serial_comm()) {
  if (upper.size() == 0) return comm.stable_norm(w.cwiseMin(g));
  const auto above = (z - upper).array();
  return comm.stable_norm((above > g.array()).select(above.max(-g.array()), g.array().min(above.max(w.array()))).matrix());
}

/// The rounding error of row i's term of bounded_residual, over ε: of w_i = (Az + q)_i, `tw` (the row
/// of |A||z| + |q|), where the term is w_i; of g_i = z_i − ζ_i(z), |z_i| + |ζ_i(z)|, where it is g_i; of
/// z_i − u_i, |z_i| + |u_i|, where it is that; the larger of tw and g's on a tie w_i = g_i.
inline double term_rounding(double tw, double w, double g, double z, const Eigen::VectorXd& upper, Eigen::Index i) {
  const double tg = std::abs(z) + std::abs(z - g);
  if (upper.size() && z - upper[i] > w) return g < z - upper[i] ? tg : std::abs(z) + std::abs(upper[i]);
  return w < g ? tw : g < w ? tg : std::max(tw, tg);
}

/// z = y + s of the box problem in y = z − s (hi: its upper bounds, empty for none), a row on its
/// upper bound exactly `upper` ((u − s) + s may miss u by an ulp).
inline Eigen::VectorXd unshift(const Eigen::VectorXd& y, const Eigen::VectorXd& s, const Eigen::VectorXd& hi,
                               const Eigen::VectorXd& upper) {
  Eigen::VectorXd z = y + s;
  if (hi.size())
    for (Eigen::Index i = 0; i < z.size(); ++i)
      if (y[i] == hi[i]) z[i] = upper[i];
  return z;
}

/// One entry p = P_ij of the injection below: the fine row's finite bound b_i becomes the coarse row's
/// (c_j) when |p| is the largest weight seen so far, the first such row on a tie.
inline void weigh_bound(double p, double b, double& weight, double& c) {
  if (p != 0 && std::isfinite(b) && std::abs(p) > weight) {
    weight = std::abs(p);
    c = b;
  }
}

/// Per column j of P, the finite bound b_i of the row i with the largest |P_ij|, the first such row
/// on a tie (`none` where no row of the column is bounded): the engine's injection of bounds (Box::coarse).
template <typename Derived>
Eigen::VectorXd inject_bounds(const Eigen::SparseMatrixBase<Derived>& P, const Eigen::VectorXd& b, double none) {
  static_assert(Derived::IsRowMajor, "inject_bounds reads P's rows");
  Eigen::VectorXd c = Eigen::VectorXd::Constant(P.cols(), none), weight = Eigen::VectorXd::Zero(P.cols());
  for (Eigen::Index i = 0; i < P.rows(); ++i)
    for (typename Derived::InnerIterator it(P.derived(), i); it; ++it)
      weigh_bound(it.value(), b[i], weight[it.index()], c[it.index()]);
  return c;
}

/// A row's state in an active set: at its lower bound, inactive (w = 0), at its upper bound.
enum : char { kAtLower = 0, kInactive = 1, kAtUpper = 2 };
inline bool inactive_state(char s) { return s == kInactive; }

struct Box {
  using Vector = Eigen::VectorXd;
  Vector lo, hi;  ///< read only where has_lo resp. has_hi: else 0 resp. +∞ on every row
  /// Whether lo, hi hold the bounds: the same on every process (a process may own no rows of a
  /// coarse level, where an empty vector cannot tell "no bound" from "no rows": every collective
  /// operation below is taken or skipped by these flags alike on all processes).
  bool has_lo = false, has_hi = false;

  bool empty() const { return !has_lo && !has_hi; }
  /// This box with both vectors of length n (0 and +∞ where it had none).
  Box full(Eigen::Index n) const {
    Box b;
    b.lo = has_lo ? lo : Vector::Zero(n);
    b.hi = has_hi ? hi : Vector::Constant(n, std::numeric_limits<double>::infinity());
    b.has_lo = b.has_hi = true;
    return b;
  }
  double lower(Eigen::Index i) const { return has_lo ? lo[i] : 0.0; }
  double upper(Eigen::Index i) const { return has_hi ? hi[i] : std::numeric_limits<double>::infinity(); }
  double clamp(Eigen::Index i, double v) const { return std::min(upper(i), std::max(lower(i), v)); }
  /// The state of row i at y_i, w_i with the active-set weight r = Ω1/Ω2: x = y − r w below lo is at
  /// the lower bound, above hi at the upper one, else inactive (ties inactive: ActiveSetTest::active_set).
  char state(double y, double w, double r, Eigen::Index i) const {
    const double x = y - r * w;
    return x < lower(i) ? kAtLower : x > upper(i) ? kAtUpper : kInactive;
  }
  /// The value an active row holds: its bound.
  double bound(char s, Eigen::Index i) const { return s == kAtUpper ? upper(i) : lower(i); }
  /// Res = ‖mid(y − lo, y − hi, w)‖₂, without overflow or underflow (bounded_residual with g = y − lo).
  double residual(const Vector& w, const Vector& y, const Comm& comm = serial_comm()) const {
    return has_lo ? bounded_residual(w, y - lo, y, hi, comm) : bounded_residual(w, y, y, hi, comm);  // (hi is empty without has_hi)
  }
  /// y projected onto the box, in place.
  void project(Vector& y) const {
    if (empty()) { y = y.cwiseMax(0.0); return; }
    for (Eigen::Index i = 0; i < y.size(); ++i) y[i] = clamp(i, y[i]);
  }
  /// y of the box `old` moved into this one with each row's state kept: a row at old's lower (upper)
  /// bound goes to this box's where that is finite (a bound lifted to ±∞ frees the row), any other
  /// keeps its value, projected.
  void carry(const Box& old, Vector& y) const {
    for (Eigen::Index i = 0; i < y.size(); ++i) {
      const double lo = lower(i), hi = upper(i);
      y[i] = y[i] == old.lower(i) && std::isfinite(lo) ? lo : y[i] == old.upper(i) && std::isfinite(hi) ? hi : clamp(i, y[i]);
    }
  }

  /// The box of the next coarser level (y_fine ≈ P y_coarse): a coarse row is bounded (below, above)
  /// where any fine row it reaches is, free where all of them are (so a row free on the finest level
  /// stays free on every level), and takes the bound of the bounded fine row it weighs most (P's
  /// largest entry in its column: the coarse point itself under classical AMG and grid interpolation).
  /// A coarse box makes a start, not a constraint of the fine problem: it needs to be near, not safe
  /// (the smallest bound around would tighten it level by level: docs/MEASUREMENTS.md, "Bounds: nested
  /// iteration on the two-sided membrane").
  template <typename RowMatrix>
  Box coarse(const RowMatrix& P) const {
    if (empty()) return {};
    constexpr double inf = std::numeric_limits<double>::infinity();
    Box c;
    c.has_lo = has_lo;
    c.has_hi = has_hi;
    if (has_lo) c.lo = inject_bounds(P, lo, -inf);
    if (has_hi) c.hi = inject_bounds(P, hi, inf);
    if (has_hi) c.hi = c.hi.cwiseMax(has_lo ? c.lo : Vector::Zero(P.cols()));  // two rows' bounds may cross
    return c;
  }

  /// The nested start on this (finer) level from the coarse solution yc of the box `cb`: each row
  /// keeps its prolongated distance to the nearer of its bounds, y = lo + P(yc − lo_c) or
  /// y = hi − P(hi_c − yc), then the box's projection. Where the coarse solution lies on a bound the
  /// fine start lies on the fine bound exactly, as y = P yc does for the LCP's 0; a bound that is not
  /// constant (an upper one in y) would otherwise be interpolated and the contact start inside it.
  template <typename RowMatrix>
  Vector prolongate(const RowMatrix& P, const Box& cb, const Vector& yc) const {
    Vector y;
    multiply(P, yc, y);
    if (!empty()) {
      constexpr double inf = std::numeric_limits<double>::infinity();
      Vector below = y, above;
      if (cb.has_lo) multiply(P, Vector(yc - lower_vector(cb, yc.size())), below);
      if (cb.has_hi) multiply(P, Vector((cb.hi - yc).cwiseMin(std::numeric_limits<double>::max())), above);
      for (Eigen::Index i = 0; i < y.size(); ++i) {
        const double s = std::isfinite(lower(i)) ? below[i] : inf;
        const double t = cb.has_hi && std::isfinite(upper(i)) ? above[i] : inf;
        if (t < s) y[i] = upper(i) - t;
        else if (s < inf) y[i] = lower(i) + s;
      }
    }
    project(y);
    return y;
  }

 private:
  /// lo of `b` with its −∞ entries as 0 (their rows are free: the distance to them is not used).
  static Vector lower_vector(const Box& b, Eigen::Index n) {
    if (!b.has_lo) return Vector::Zero(n);
    return b.lo.unaryExpr([](double v) { return std::isfinite(v) ? v : 0.0; });
  }
};

/// The bounds ψ ≤ z ≤ u of an obstacle problem (ψ empty: 0; u empty: +∞; either may be infinite
/// in places) as a box in y = z − s (detail/box.hpp): s = ψ where ψ is finite, else u where u is,
/// else 0. Without infinite ψ and without u this is the plain shift y = z − ψ, y ≥ 0 (an empty box).
struct ShiftedBounds {
  Eigen::VectorXd s;  ///< the shift (empty: 0)
  Box box;

  /// `shift` false (the Newton member's choice): a problem with bounds is not shifted at all, its box
  /// is ψ ≤ z ≤ u itself. `comm`: whether there are bounds is decided over every process's rows. A shift by ψ where ψ is finite and by 0 on the free rows makes y jump
  /// between them (elastic contact: the bounded normal displacements next to free ones), a rough y
  /// the coarse levels cannot represent (docs/MEASUREMENTS.md, "Box problems"). The modulus members
  /// keep the shift (their lo' = γ lo/(2Ω1) is then 0 or −∞: detail/modulus.hpp).
  ShiftedBounds(const Eigen::VectorXd& psi, const Eigen::VectorXd& upper, bool shift = true,
                const Comm& comm = serial_comm()) {
    constexpr double inf = std::numeric_limits<double>::infinity();
    const bool free_below = comm.any(psi.size() && (psi.array() == -inf).any());
    const bool has_upper = comm.any(upper.size() > 0);
    if (!free_below && !has_upper) { s = psi; return; }
    if (!shift) {
      box.lo = psi;
      box.hi = upper;
      box.has_lo = comm.any(psi.size() > 0);
      box.has_hi = has_upper;
      return;
    }
    const Eigen::Index n = std::max(psi.size(), upper.size());
    s.resize(n);
    if (free_below) box.lo = Eigen::VectorXd::Zero(n);
    if (has_upper) box.hi.resize(n);
    box.has_lo = free_below;
    box.has_hi = has_upper;
    for (Eigen::Index i = 0; i < n; ++i) {
      const double l = psi.size() ? psi[i] : 0.0, u = upper.size() ? upper[i] : inf;
      s[i] = std::isfinite(l) ? l : std::isfinite(u) ? u : 0.0;
      if (free_below && !std::isfinite(l)) box.lo[i] = -inf;
      if (has_upper) box.hi[i] = u - s[i];
    }
  }
  bool shifted() const { return s.size() > 0; }
};

}  // namespace nrmicp::detail
