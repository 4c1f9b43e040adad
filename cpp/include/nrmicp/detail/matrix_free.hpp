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
// perturbation, so the Krylov iterations do not grow with the mesh (docs/MEASUREMENTS.md).
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
#include <functional>
#include <limits>
#include <memory>
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
inline constexpr double kPreconditionerTolerance = 0.1;

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
  MatrixFreeSystem(NewtonLevel<MatrixType>& level, SemismoothRecord& record) : level_(level), record_(record) {}

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
    return ok && out.allFinite();
  }

 private:
  /// out = K v: A's rows on ℐ, (I − J)'s on 𝒜.
  void apply(const Vector& v, Vector& out) {
    {
      ScopedTimer t(level_.timings().spmv);
      out.noalias() = level_.matrix() * v;
    }
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
    {
      ScopedTimer t(level_.timings().spmv);
      av_.noalias() = level_.matrix() * active_;
    }
    for (Eigen::Index i = 0; i < v.size(); ++i)
      if (inactive_state(inactive_[i])) rhs_[i] -= av_[i];
    out.setZero(v.size());
    auto& K0 = level_.lcp_system();
    record_.preconditioner += K0.solve(rhs_, out, K0.iterative() ? kPreconditionerTolerance * rhs_.norm() : 0.0);
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

/// A callable ζ with its Jacobian, linearized at each step's z (NewtonStep's policy): a sparse
/// ∂ζ(z) = B gives the affine step of ζ(z) + B(v − z) on the union pattern of A, I and B (a new
/// ActiveSetSystem each step: semismooth Newton on the whole ICP); a matrix-free one the same step
/// by MatrixFreeSystem. The form is the Jacobian's, per call (Zeta::Derivative).
template <typename MatrixType>
struct SemismoothLinearization {
  using Level = NewtonLevel<MatrixType>;
  using Vector = Eigen::VectorXd;
  using StorageIndex = typename MatrixType::StorageIndex;
  using Sparse = ActiveSetSystem<StorageIndex>;
  static constexpr bool set_fixes_step = false;

  /// The reduced system of this step, of either form (the interface NewtonStep uses).
  struct System {
    std::unique_ptr<Sparse> sparse;
    MatrixFreeSystem<MatrixType> matrix_free;
    bool is_matrix_free = false;
    bool factorize(const std::vector<char>& inactive) {
      return is_matrix_free ? matrix_free.factorize(inactive) : sparse->factorize(inactive);
    }
    int solve(const Vector& b, Vector& z, double target) {
      return is_matrix_free ? matrix_free.solve(b, z, target) : sparse->solve(b, z, target);
    }
    bool iterative() const { return is_matrix_free || sparse->iterative(); }
  };

  /// `record`: where the linearizations record (outlives this).
  SemismoothLinearization(Level& level, const Vector& q, const Zeta<StorageIndex>& zeta, SemismoothRecord& record)
      : level(level), q(q), zeta(zeta), record(record), K{nullptr, MatrixFreeSystem<MatrixType>(level, record)} {}

  Level& level;
  const Vector& q;
  const Zeta<StorageIndex>& zeta;
  SemismoothRecord& record;
  typename Zeta<StorageIndex>::Derivative J;
  Vector c;        ///< the active rows' right-hand side: ζ(z) − Jz (sparse, for z⁺), ζ(z) − z = −g (matrix-free, for d)
  Vector minus_w;  ///< matrix-free: the inactive rows' right-hand side −w = −(Az + q)
  System K;
  const Box* box = nullptr;  // (no bounds on this path)

  bool g_is_z() const { return false; }
  /// Res of the ICP at v; Av + q in w, v − ζ(v) in g, ζ(v) in zv. NaN when ζ failed.
  double evaluate(const Vector& v, Vector& w, Vector& g, Vector& zv) const {
    const double r = level.icp_residual(q, zeta, v, zv, w);
    if (!std::isnan(r)) g = v - zv;
    return r;
  }
  /// ∂ζ(z) and the step's system for it; false when the Jacobian failed. The Jacobian counts as ζ's
  /// time; a sparse system's analysis as this step's factorization.
  bool linearize(const Vector& z, const Vector& zeta_z) {
    if (z_last.size() == z.size() && z_last != z) move = z - z_last;
    z_last = z;
    {
      ScopedTimer t(level.timings().zeta);
      if (!zeta.derivative(z, J)) return false;
    }
    K.is_matrix_free = J.matrix_free();
    if (K.is_matrix_free) {
      {
        ScopedTimer t(level.timings().spmv);
        minus_w.noalias() = level.matrix() * z;
      }
      minus_w = -(minus_w + q);
      c = zeta_z - z;  // −g
      K.matrix_free.linearize(std::move(J.product), stable_norm(minus_w.cwiseMax(c)));  // Res = ‖min(w, g)‖ = ‖max(−w, −g)‖
      K.sparse.reset();
      return true;
    }
    c = zeta_z - J.matrix * z;
    K.sparse = level.affine_system(J.matrix, &Timings::factorization);
    return true;
  }
  System& system() { return K; }

  /// How far J = ∂ζ(z) (the last linearization, at z) misses ζ's difference quotient along the loop's
  /// last move d, (ζ(z + εd) − ζ(z))/ε with εd 10⁻⁴ of z's size: ‖quotient − Jd‖ / max(‖quotient‖, ‖Jd‖);
  /// 0 when both vanish, NaN when ζ or the product failed. A relative step of 10⁻⁴: rounding (a float32
  /// ζ's included) and curvature are far below kJacobianMiss there. One call of ζ and one product.
  double jacobian_miss(const Vector& z, const Vector& zeta_z) {
    const Eigen::Index n = z.size();
    const Vector d = move.size() == n && move.squaredNorm() > 0 ? move : Vector::Ones(n);
    const double eps = kDifferenceStep * (z.norm() > 0 ? z.norm() : 1.0) / d.norm();
    Vector moved(n), jd;
    if (!level.eval_zeta(zeta, z + eps * d, moved)) return std::numeric_limits<double>::quiet_NaN();
    if (K.is_matrix_free) {
      if (!K.matrix_free.product(d, jd)) return std::numeric_limits<double>::quiet_NaN();
    } else {
      jd = J.matrix * d;
    }
    const Vector quotient = (moved - zeta_z) / eps;
    const double scale = std::max(quotient.norm(), jd.norm());
    return scale > 0 ? (quotient - jd).norm() / scale : 0.0;
  }
  static constexpr double kDifferenceStep = 1e-4;

 private:
  Vector z_last, move;  // the last linearization's z, and the move to it from the one before
 public:
  /// The step's right-hand side: for z⁺ (sparse: −q on ℐ, c on 𝒜), or for the correction d = z⁺ − z
  /// (matrix-free: −w on ℐ, −g on 𝒜).
  void rhs(const std::vector<char>& set, Vector& b) const {
    for (Eigen::Index i = 0; i < b.size(); ++i)
      b[i] = inactive_state(set[i]) ? (K.is_matrix_free ? minus_w[i] : -q[i]) : c[i];
  }
  /// The active set of the step from z: the one of the outer step S(ζ(z)) when `predict` is given
  /// (NewtonRun::solve_semismooth); false: the test x ≥ 0 on z decides.
  bool predict_set(const Vector& z, const Vector& zeta_z, std::vector<char>& inactive) {
    return predict && predict(z, zeta_z, inactive);
  }
  /// The fallback from z0: `fallback` when given (NewtonRun: the outer step from z0), else sweeps of
  /// the fallback member.
  Result sweep(const Vector& z0, int sweeps, double tol) {
    return fallback ? fallback(z0, sweeps, tol) : level.sweep(q, zeta, z0, sweeps, tol);
  }
  std::function<bool(const Vector&, const Vector&, std::vector<char>&)> predict;  ///< (z, ζ(z), inactive set)
  std::function<void(Vector&)> project;  ///< z ← S(ζ(z)), the outer step after a Newton step (or z kept)
  std::function<Result(const Vector&, int, double)> fallback;  ///< (z0, sweeps, tol) → the fallback's best iterate
  /// After a Newton step: the outer step from its result (`project`), kept when it lowers Res (NewtonStep::smooth).
  bool smoothable() const { return static_cast<bool>(project); }
  void smooth(Vector& z, int) const { project(z); }
};

}  // namespace nrmicp::detail
