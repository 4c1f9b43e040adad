// nrmicp — one iteration of an AOR-type member (NRMAOR/SOR/GS/J, MMS) with the explicit
// z-update, as a single pass over the rows of a row-major A. Lm's strictly lower part is
// (β/α) a_ij Ω1_j, the same pattern as A's, so the product with A, Res, the right-hand
// side, the forward substitution and the x/z update share one read of A. This is the same
// arithmetic as the generic splitting step (SplittingStep, steps.hpp) up to rounding order;
// SweepStep (steps.hpp) calls it from the one loop, detail::loop (solver.hpp). The tests check
// both against the reference implementation. The modulus m (|x|, or a box's: detail/modulus.hpp)
// is a template parameter: the LCP's sweep is the same code as before bounds existed.
#pragma once

#include "modulus.hpp"
#include "residual.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>

namespace nrmicp::detail {

/// Computes Res(z⁽ᵏ⁾)² (returned as its ResidualSum), x ← x⁽ᵏ⁺¹⁾ and z_next ← z⁽ᵏ⁺¹⁾; `step` = max|x⁽ᵏ⁺¹⁾ − x⁽ᵏ⁾|.
/// For an LCP pass zeta_z = zhat = nullptr (then ẑ = z); for an ICP, zeta_z = ζ(z⁽ᵏ⁾) and
/// zhat = ζ(z⁽ᵏ⁾) + Ω1(|x| + x)/γ; lm_inverse_diagonal = 1 / diag(Lm). `dx` is workspace of length n.
/// `OmegaOneIsIdentity`: Ω1 = I (the default), so Ω1 is not read: the sweep is bandwidth-bound.
/// `mod`: m (AbsModulus for the LCP; BoxModulus: z is y of the box problem, zeta_z = zhat = nullptr).
template <bool OmegaOneIsIdentity, typename Modulus, typename MatrixType>
ResidualSum aor_sweep_impl(const Modulus& mod, const MatrixType& A, const Eigen::VectorXd& z, const Eigen::VectorXd* zeta_z,
                      const Eigen::VectorXd* zhat, const Eigen::VectorXd& q, const Eigen::VectorXd& omega1,
                      const Eigen::VectorXd& omega2, const Eigen::VectorXd& lm_inverse_diagonal, double lower_scale,
                      double gamma, Eigen::VectorXd& x, Eigen::VectorXd& z_next, Eigen::VectorXd& dx, double& step) {
  static_assert(MatrixType::IsRowMajor, "aor_sweep needs a row-major matrix");
  auto om1 = [&](Eigen::Index j) { if constexpr (OmegaOneIsIdentity) return 1.0; else return omega1[j]; };
  const Eigen::Index n = A.rows();
  const double inv_gamma = 1.0 / gamma;
  ResidualSum res;
  double max_step = 0;
  for (Eigen::Index i = 0; i < n; ++i) {
    double az = 0, azhat = 0, lower = 0;
    for (typename MatrixType::InnerIterator it(A, i); it; ++it) {
      const Eigen::Index j = it.index();
      const double a = it.value();
      az += a * z[j];
      if (zhat) azhat += a * (*zhat)[j];
      if (j < i) lower += a * om1(j) * dx[j];
    }
    const double wi = az + q[i];
    const double gi = zeta_z ? z[i] - (*zeta_z)[i] : z[i];
    mod.add(res, i, wi, gi);
    const double xi = x[i];
    const double rhs = omega2[i] * mod.minus(i, xi) - gamma * ((zhat ? azhat : az) + q[i]);
    // A multiply, not a divide: dx_i depends on dx_{i-1} through `lower`, so this sits on the
    // sweep's sequential dependency chain (perf: the divide was its hottest instruction).
    const double d = (rhs - lower_scale * lower) * lm_inverse_diagonal[i];
    dx[i] = d;
    const double xn = xi + d;
    x[i] = xn;
    max_step = std::max(max_step, std::abs(xn - xi));  // the step taken: 0 when x is unchanged
    z_next[i] = (zeta_z ? (*zeta_z)[i] : 0.0) + mod.in_box(i, om1(i) * mod.plus(i, xn) * inv_gamma);
  }
  step = max_step;
  return res;
}

template <typename Modulus, typename MatrixType>
ResidualSum aor_sweep(const Modulus& mod, const MatrixType& A, const Eigen::VectorXd& z, const Eigen::VectorXd* zeta_z,
                 const Eigen::VectorXd* zhat, const Eigen::VectorXd& q, const Eigen::VectorXd& omega1,
                 bool omega1_is_identity, const Eigen::VectorXd& omega2, const Eigen::VectorXd& lm_inverse_diagonal,
                 double lower_scale, double gamma, Eigen::VectorXd& x, Eigen::VectorXd& z_next, Eigen::VectorXd& dx,
                 double& step) {
  if (omega1_is_identity)
    return aor_sweep_impl<true>(mod, A, z, zeta_z, zhat, q, omega1, omega2, lm_inverse_diagonal, lower_scale, gamma, x,
                                z_next, dx, step);
  return aor_sweep_impl<false>(mod, A, z, zeta_z, zhat, q, omega1, omega2, lm_inverse_diagonal, lower_scale, gamma, x,
                               z_next, dx, step);
}

}  // namespace nrmicp::detail
