// nrmicp — the global reductions of the Newton driver: the one thing a distributed engine changes in
// its decisions (AMGCL's MPI solvers are the serial ones with an inner-product policy; this is that
// policy). Vectors hold the rows a process owns; a norm, a maximum, a count or an active-set
// fingerprint is reduced over every process here. The serial Comm reduces nothing: one process owns
// every row, and its calls cost a virtual call a Newton step (nothing per row).
#pragma once

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <exception>
#include <stdexcept>

namespace nrmicp::detail {

class Comm {
 public:
  virtual ~Comm() = default;
  /// In place over every process: the sums resp. maxima of v[0..n).
  virtual void sum(double*, int) const {}
  virtual void max(double*, int) const {}
  virtual void sum(std::uint64_t*, int) const {}
  virtual int size() const { return 1; }

  double sum(double v) const { sum(&v, 1); return v; }
  double max(double v) const { max(&v, 1); return v; }
  std::uint64_t sum(std::uint64_t v) const { sum(&v, 1); return v; }
  /// Whether b holds on every process.
  bool all(bool b) const { return !(max(b ? 0.0 : 1.0) > 0); }
  /// Whether b holds on some process.
  bool any(bool b) const { return max(b ? 1.0 : 0.0) > 0; }
  /// ‖v‖∞ over every process (a NaN stays NaN, as in lpNorm).
  template <typename Derived>
  double inf_norm(const Eigen::MatrixBase<Derived>& v) const {
    return max(v.size() ? v.template lpNorm<Eigen::Infinity>() : 0.0);
  }
  /// ‖v‖₂ over every process (as Eigen's norm(): the root of the summed squares).
  template <typename Derived>
  double norm(const Eigen::MatrixBase<Derived>& v) const {
    return std::sqrt(sum(v.squaredNorm()));
  }
  /// ‖m‖₂ over every process without overflow or underflow: scaled by the largest |mᵢ| anywhere.
  /// m may be an expression (read twice, never formed).
  template <typename Derived>
  double stable_norm(const Eigen::MatrixBase<Derived>& m) const {
    const double scale = max(m.size() ? m.cwiseAbs().maxCoeff() : 0.0);
    if (!(scale > 0) || !std::isfinite(scale)) return std::sqrt(sum(m.size() ? m.squaredNorm() : 0.0));
    return scale * std::sqrt(sum(m.size() ? (m / scale).squaredNorm() : 0.0));
  }
  /// 1, or a power of two near the largest |vᵢ| anywhere where the squares of v's size would leave
  /// float's range: the units a Krylov solve or a least-squares fit takes its vectors in (z in units
  /// of 1e-200: CG's r·r underflowed to 0 and each solve stopped at once); exact but for subnormals.
  template <typename Derived>
  double units(const Eigen::MatrixBase<Derived>& v) const {
    const double m = max(v.size() ? v.cwiseAbs().maxCoeff() : 0.0);
    constexpr double low = 0x1p-400, high = 0x1p400;
    return !(m > 0) || !std::isfinite(m) || (m > low && m < high) ? 1.0 : std::ldexp(1.0, std::ilogb(m));
  }
};

/// solve(b, z, target) of a linear system K z = b from z, taken in z's units τ = comm.units(b): on K (z/τ) = b/τ
/// to target/τ, so that the Krylov method's inner products stay within float's range. Returns solve's count;
/// `units` (optional) receives τ.
template <typename Solve>
int solve_in_units(const Comm& comm, const Eigen::VectorXd& b, Eigen::VectorXd& z, double target, Solve&& solve,
                   double* units = nullptr) {
  const double tau = comm.units(b);
  if (units) *units = tau;
  if (tau == 1.0) return solve(b, z, target);
  const Eigen::VectorXd bt = b / tau;
  z /= tau;
  const int k = solve(bt, z, target / tau);
  z *= tau;
  return k;
}

/// Runs `check` (which may throw for this process's input: its rows' lengths, its layout, its diagonal)
/// so that every process throws when one does: a throw on one process alone would leave the others
/// waiting in the next reduction. The process at fault rethrows its own exception (type and message);
/// the others throw std::invalid_argument saying so. `check` may take collective calls before it throws.
/// The message of a process whose own part was accepted when another's was not.
inline constexpr const char* kRefusedElsewhere =
    "another process refused its part of the input (its own message names the argument)";

template <typename Check>
void collective_check(const Comm& comm, Check&& check) {
  std::exception_ptr failed;
  try {
    check();
  } catch (...) {
    failed = std::current_exception();
  }
  if (comm.all(!failed)) return;
  if (failed) std::rethrow_exception(failed);
  throw std::invalid_argument(kRefusedElsewhere);
}

/// The one process that owns every row.
inline const Comm& serial_comm() {
  static const Comm c;
  return c;
}

}  // namespace nrmicp::detail
