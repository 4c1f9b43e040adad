// nrmicp — the modulus map m of Method 3.1, componentwise, for the LCP and for bounds.
//
// LCP (z ≥ 0): m(x) = |x|, z = Ω1(|x| + x)/γ, w = Ω2(|x| − x)/γ (Theorem 3.1).
// Bounds lower ≤ z ≤ upper: the box problem in y = z − s (s: lower where finite, else upper where
// finite, else 0), lo ≤ y ≤ hi with lo_i ∈ {0, −∞}, hi_i ∈ [0, +∞], q' = q + As, PATH's conditions
// (w ≥ 0 at lo, ≤ 0 at hi, = 0 between). With lo' = γ lo/(2Ω1), hi' = γ hi/(2Ω1),
//     m(x) = 2 mid(lo', x, hi') − x,   y = Ω1(m(x) + x)/γ,   w = Ω2(m(x) − x)/γ
// satisfy the box conditions for every x (y = lo, w ≥ 0 where x ≤ lo'; y = hi, w ≤ 0 where x ≥ hi';
// w = 0 between), and every (y, w) that solves the box problem comes from x = γ(y/Ω1 − w/Ω2)/2. So
// the problem is (Ω2 + AΩ1)x = (Ω2 − AΩ1)m(x) − γq', and each member's box form is its LCP form with
// |x| replaced by m(x): m = |·| where lo' = 0, hi' = ∞; m(x) = x (w = 0) on a free row.
// Convergence: m is 1-Lipschitz componentwise, |m(x) − m(x')| ≤ |x − x'|, the only property of |·|
// the LCP convergence proofs use (the paper's Theorem 4.1 with Ψ = 0, hence Theorems 4.2–4.4), so
// they hold for the box unchanged (docs/SPEC.md, "Bounds in the stationary members").
//
// The steps are written once over a modulus type (AbsModulus or BoxModulus): m(x) + x, m(x) − x,
// y's clamp into the box and Res's term. AbsModulus is the LCP's exact arithmetic, inlined: the LCP
// path costs nothing and its results are bit for bit those without bounds.
#pragma once

#include "box.hpp"
#include "residual.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <limits>

namespace nrmicp::detail {

/// m(x) = |x|: the LCP.
struct AbsModulus {
  double value(Eigen::Index, double x) const { return std::abs(x); }      ///< m(x)
  double plus(Eigen::Index, double x) const { return std::abs(x) + x; }   ///< m(x) + x
  double minus(Eigen::Index, double x) const { return std::abs(x) - x; }  ///< m(x) − x
  double in_box(Eigen::Index, double y) const { return y; }               ///< y ≥ 0 already
  /// Res's term min(w, y).
  void add(ResidualSum& r, Eigen::Index, double w, double y) const { r.add(w, y); }
};

/// m(x) = 2 mid(lo', x, hi') − x: the box problem of lower ≤ z ≤ upper in y = z − s.
struct BoxModulus {
  using Vector = Eigen::VectorXd;
  Vector s;       ///< z = y + s
  Box box;        ///< lo ≤ y ≤ hi (full vectors)
  Vector lo, hi;  ///< lo' = γ lo/(2Ω1), hi' = γ hi/(2Ω1): the box in units of x

  /// `lower` (empty: 0) may hold −∞, `upper` (empty: +∞) +∞; Ω1 > 0 and γ > 0 are the method's.
  /// s and the box are the Newton member's (ShiftedBounds, box.hpp), with full vectors.
  BoxModulus(const Vector& lower, const Vector& upper, const Vector& omega1, double gamma) {
    const Eigen::Index n = omega1.size();
    const ShiftedBounds b(lower, upper);
    s = b.shifted() ? b.s : Vector::Zero(n);
    box = b.box.full(n);
    const Vector scale = (gamma / 2) * omega1.cwiseInverse();
    lo = box.lo.cwiseProduct(scale);  // 0·scale = 0, −∞·scale = −∞ (scale > 0)
    hi = box.hi.cwiseProduct(scale);
  }

  double mid(Eigen::Index i, double x) const { return std::min(hi[i], std::max(lo[i], x)); }
  double value(Eigen::Index i, double x) const { return 2 * mid(i, x) - x; }  ///< m(x)
  double plus(Eigen::Index i, double x) const { return 2 * mid(i, x); }         ///< m(x) + x
  double minus(Eigen::Index i, double x) const { return 2 * (mid(i, x) - x); }  ///< m(x) − x
  /// y = Ω1(m(x) + x)/γ is in the box up to rounding: clamped, so that y at a bound is the bound.
  double in_box(Eigen::Index i, double y) const { return box.clamp(i, y); }
  /// Res's term mid(y − lo, y − hi, w) = min(y − lo, max(y − hi, w)).
  void add(ResidualSum& r, Eigen::Index i, double w, double y) const {
    r.add_term(std::min(y - box.lo[i], std::max(y - box.hi[i], w)));
  }
};

/// Calls f with the modulus of a problem: *box when given, else AbsModulus (the LCP).
template <typename F>
decltype(auto) with_modulus(const BoxModulus* box, F&& f) {
  if (box) return f(*box);
  return f(AbsModulus{});
}

}  // namespace nrmicp::detail
