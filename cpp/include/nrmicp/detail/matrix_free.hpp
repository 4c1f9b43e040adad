// nrmicp — the Newton step of a callable ζ whose Jacobian J = ∂ζ(z) is known only by its products
// (Zeta::JacobianProduct; in Python a zeta_jacobian returning a LinearOperator). The step solves,
// for the correction d = z⁺ − z with w = Az + q and g = z − ζ(z) at z,
//   row i ∈ ℐ:  (A d)_i = −w_i              (w⁺ = 0 on the inactive set)
//   row i ∈ 𝒜:  ((I − J) d)_i = −g_i        (z⁺ = ζ(z) + J(z⁺ − z) on the active set)
// the system of the sparse path (detail/active_set.hpp) in correction form, K d = b, by FGMRES
// (detail/gmres.hpp) preconditioned by the LCP piece nrmicp already solves for the same active set:
//   K₀ = [A_ℐℐ  A_ℐ𝒜; 0  I],   K₀⁻¹v: x_𝒜 = v_𝒜, A_ℐℐ x_ℐ = v_ℐ − A_ℐ𝒜 v_𝒜
// (the level's LCP system: a direct factorization, or its V-cycle-preconditioned CG), exact when
// J = 0. K K₀⁻¹ = I − E K₀⁻¹ with E = J's active rows: the identity but for a block of the size of
// 𝒜, J_𝒜· composed with the A-harmonic extension — for a smoothing J (a PDE solve) a compact
// perturbation, so the Krylov iterations do not grow with the mesh (docs/MEASUREMENTS.md, "Matrix-free
// Newton steps").
#pragma once

#include "../zeta.hpp"
#include "box.hpp"
#include "gmres.hpp"
#include "newton_level.hpp"
#include "timer.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

namespace nrmicp::detail {

/// The inexact Newton forcing of the matrix-free step (Eisenstat–Walker, choice 2): the Krylov solve
/// stops at η Res(z), η = min(kMatrixFreeMaxForcing, 0.9 (Res(z)/Res(z_prev))²), η =
/// kMatrixFreeMaxForcing at the first step: loose while the active set moves, tight as the steps
/// converge. Res, not ‖b‖: b's inactive rows are w, up to diag(A) times larger than min(w, g) there
/// (docs/MEASUREMENTS.md, "Matrix-free Newton steps").
inline constexpr double kMatrixFreeMaxForcing = 0.1;
/// The preconditioner's iterative solve (the LCP system with a hierarchy: CG + V-cycle) stops at this
/// fraction of its right-hand side (FGMRES takes a preconditioner that changes with each application).
/// Tight: each FGMRES iteration costs a product with J, a user's call (a PDE solve on thermoforming),
/// while a CG iteration costs a V-cycle (docs/MEASUREMENTS.md, "Matrix-free Newton steps").
inline constexpr double kPreconditionerTolerance = 1e-3;

/// What the matrix-free solves of one semismooth loop did (Result::counters "matrix_free_iterations",
/// "matrix_free_preconditioner_iterations").
struct SemismoothRecord {
  long long iterations = 0;      ///< FGMRES iterations (also in NewtonStats::inner_iterations)
  long long preconditioner = 0;  ///< iterations of the preconditioner's own solve (CG on the LCP piece)
};

/// K d = b of the header comment for one linearization, matrix-free; the interface of ActiveSetSystem
/// (factorize, solve, iterative) as NewtonStep uses it.
template <typename MatrixType>
class MatrixFreeSystem {
 public:
  using Vector = Eigen::VectorXd;
  using Product = typename Zeta<typename MatrixType::StorageIndex>::Product;

  /// `record`: where its solves count their iterations (outlives this).
  MatrixFreeSystem(NewtonLevel<MatrixType>& level, SemismoothRecord& record)
      : level_(level), gmres_(30, 300, level.comm()), record_(record) {}

  /// J = ∂ζ(z) by its product (valid until the next call); `res`: Res(z) (the forcing's).
  void linearize(Product product, double res) {
    product_ = std::move(product);
    eta_ = previous_ > 0 ? std::min(kMatrixFreeMaxForcing, 0.9 * (res / previous_) * (res / previous_))
                         : kMatrixFreeMaxForcing;
    res_ = previous_ = res;
  }
  /// The preconditioner K₀ of the active set (inactive[i] == kInactive: i ∈ ℐ); false when singular.
  bool factorize(const std::vector<char>& inactive) {
    inactive_ = inactive;
    return level_.lcp_system().factorize(inactive);
  }
  /// z ← z + d with ‖b − K d‖ ≤ max(target, η Res(z)) (the forcing η above); b in correction form
  /// (SemismoothLinearization::rhs). Returns the FGMRES iterations. A failed product of J leaves z
  /// not finite (the step is rejected). The products' seconds go to ζ's time, not the solve's.
  int solve(const Vector& b, Vector& z, double target) {
    product_seconds_ = 0;
    d_.setZero(b.size());
    const int k = gmres_.solve([this](const Vector& v, Vector& out) { apply(v, out); },
                               [this](const Vector& v, Vector& out) { precondition(v, out); }, b, d_,
                               std::max(target, eta_ * res_));
    z += d_;
    record_.iterations += k;
    level_.timings().zeta += product_seconds_;
    level_.timings().inner_solve -= product_seconds_;  // NewtonStep's timer around this solve adds them back
    return k;
  }
  bool iterative() const { return true; }
  /// out = J v with the current J; false when the product failed.
  bool product(const Vector& v, Vector& out) {
    out.resize(v.size());
    const auto t0 = std::chrono::steady_clock::now();
    const bool ok = product_ && product_(v.data(), out.data(), v.size());
    level_.timings().zeta += ScopedTimer::seconds_since(t0);
    return level_.comm().all(ok && out.allFinite());
  }

 private:
  /// out = K v: A's rows on ℐ, (I − J)'s on 𝒜.
  void apply(const Vector& v, Vector& out) {
    level_.apply(v, out);
    jv_.resize(v.size());
    const auto t0 = std::chrono::steady_clock::now();
    const bool ok = product_(v.data(), jv_.data(), v.size());
    product_seconds_ += ScopedTimer::seconds_since(t0);
    if (!ok) jv_.setConstant(std::numeric_limits<double>::quiet_NaN());
    for (Eigen::Index i = 0; i < v.size(); ++i)
      if (!inactive_state(inactive_[i])) out[i] = v[i] - jv_[i];
  }
  /// out = K₀⁻¹ v through the LCP system (its active rows are identity rows without the active
  /// columns of A: A_ℐ𝒜 v_𝒜 moves to the right-hand side).
  void precondition(const Vector& v, Vector& out) {
    rhs_ = v;
    active_.resize(v.size());
    for (Eigen::Index i = 0; i < v.size(); ++i) active_[i] = inactive_state(inactive_[i]) ? 0.0 : v[i];
    level_.apply(active_, av_);
    for (Eigen::Index i = 0; i < v.size(); ++i)
      if (inactive_state(inactive_[i])) rhs_[i] -= av_[i];
    out.setZero(v.size());
    auto& K0 = level_.lcp_system();
    record_.preconditioner += K0.solve(rhs_, out, K0.iterative() ? kPreconditionerTolerance * level_.comm().norm(rhs_) : 0.0);
  }

  NewtonLevel<MatrixType>& level_;
  Product product_;
  std::vector<char> inactive_;
  Gmres gmres_;
  Vector d_, jv_, rhs_, active_, av_;
  double res_ = 0, previous_ = 0, eta_ = kMatrixFreeMaxForcing;  // Res(z) of this step and the last; the forcing
  double product_seconds_ = 0;  // in J's products during this solve
  SemismoothRecord& record_;
};

}  // namespace nrmicp::detail
