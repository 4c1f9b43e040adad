// nrmicp — the paper's accuracy measure Res(z) = ‖min(Az + q, z − ζ(z))‖₂, defined once.
// The stationary members' passes over A (the one-pass sweep, the fused product, the generic
// step) accumulate the plain sum of squares row by row with ResidualSum as they go (no cost added
// to the sweep); Context::residual_norm takes its square root, or, when the plain sum overflowed
// or may have lost terms to underflow, recomputes Res with stable_norm. The Newton member, which
// has w and g as vectors, calls residual_of(w, g). (Python's nrmicp.residual is an independent numpy
// check, on purpose.)
#pragma once

#include <Eigen/Core>

#include <algorithm>
#include <cfloat>
#include <cmath>

namespace nrmicp::detail {

/// Σ min(wᵢ, gᵢ)², accumulated one row at a time.
struct ResidualSum {
  double sum = 0;
  void add(double w, double g) {
    const double m = std::min(w, g);
    sum += m * m;
  }
  /// A term already formed (a box problem's mid(y − lo, y − hi, w): detail/modulus.hpp).
  void add_term(double m) { sum += m * m; }
  /// The plain sum is exact up to rounding: it did not overflow, and it is large enough that
  /// squares lost to underflow (each < 2^-1022) cannot matter (n · 2^-1074 ≪ 2^-800).
  bool plain_is_accurate() const { return sum >= 0x1p-800 && sum <= DBL_MAX; }
};

/// ‖m‖₂ without overflow or underflow: scaled by the largest |mᵢ| (two passes; for the rare
/// cases ResidualSum cannot take, |mᵢ| beyond about 1e154 or all below about 1e-120). m may be an
/// expression (min(w, g), |z| + |ζ(z)|): it is read twice, never formed as an n-vector.
template <typename Derived>
double stable_norm(const Eigen::MatrixBase<Derived>& m) {
  const double scale = m.cwiseAbs().maxCoeff();
  if (!(scale > 0) || !std::isfinite(scale)) return m.size() ? std::sqrt(m.squaredNorm()) : 0.0;
  return scale * std::sqrt((m / scale).squaredNorm());
}

/// Res = ‖min(w, g)‖₂ of whole vectors w = Az + q, g = z − ζ(z), without overflow or underflow.
inline double residual_of(const Eigen::VectorXd& w, const Eigen::VectorXd& g) { return stable_norm(w.cwiseMin(g)); }

}  // namespace nrmicp::detail
