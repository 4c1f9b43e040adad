// nrmicp — the paper's accuracy measure Res(z) = ‖min(Az + q, z − ζ(z))‖₂, defined once.
// The passes over A (the one-pass sweep, the fused product, the generic step) accumulate it
// row by row with ResidualSum as they go; nothing else computes it.
#pragma once

#include <algorithm>
#include <cmath>

namespace nrmicp::detail {

/// Σ min(wᵢ, gᵢ)², accumulated one row at a time.
struct ResidualSum {
  double sum = 0;
  void add(double w, double g) {
    const double m = std::min(w, g);
    sum += m * m;
  }
  double norm() const { return std::sqrt(sum); }
};

}  // namespace nrmicp::detail
