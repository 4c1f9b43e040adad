// nrmicp — the steps of Method 3.1, one type per kind of member (the interface is described at
// the top of solver.hpp):
//   SweepStep      AOR-type members, explicit z-update, row-major A: one pass over A per step
//                  (serial only: a distributed engine runs SplittingStep, the same iterates)
//   SplittingStep  any splitting: rhs = Ω2(|x| − x) − γ(A ẑ + q), x += Lm⁻¹ rhs (Lm factorized,
//                  triangular or diagonal)
//   TwoSweepStep   the two-sweep baseline: SplittingStep's rhs minus N2(|x⁽ᵏ⁾| − |x⁽ᵏ⁻¹⁾|), relaxed by θ
// With bounds, m(x) replaces |x| throughout (detail/modulus.hpp): the passes over A are templates
// over the modulus, chosen once per pass by with_modulus (the LCP's code is unchanged).
#pragma once

#include "../splitting.hpp"
#include "iterate.hpp"
#include "residual.hpp"
#include "stopping.hpp"
#include "sweep.hpp"
#include "timer.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <limits>

namespace nrmicp::detail {

/// What a step reports beyond the loop's own counts (none by default), and its own end of the
/// loop (none: the stationary members stop by the Monitor's rules only).
struct StepBase {
  void report(Result&) const {}
  const StepEnd* end() const { return nullptr; }
};

/// The AOR-type members with the explicit z-update on a row-major A: evaluate is one sweep over
/// A (detail/sweep.hpp) that returns Res(z⁽ᵏ⁾) and has already made x⁽ᵏ⁺¹⁾ (in place) and
/// z⁽ᵏ⁺¹⁾, which are simply not used when the loop stops at k.
template <typename MatrixType>
class SweepStep : public StepBase {
  static_assert(MatrixType::IsRowMajor, "SweepStep needs a row-major matrix");

 public:
  using Vector = Eigen::VectorXd;
  template <typename I>
  SweepStep(Context<MatrixType>& ctx, const Splitting<I>& sp)
      : ctx_(ctx), inverse_diagonal_(sp.left_inverse_diagonal()), lower_scale_(sp.lower_scale()),
        omega1_is_identity_((ctx.p.omega1.array() == 1.0).all()), z_next_(ctx.n()), dx_(ctx.n()), zhat_(ctx.n()) {}

  double evaluate(Iterate& s) {
    const bool lcp = ctx_.lcp();
    if (!lcp) {
      ctx_.eval_zeta(s, s.z, s.zeta_z);
      if (!s.zeta_ok || !s.finite) return std::numeric_limits<double>::quiet_NaN();
      ctx_.from_modulus(&s.zeta_z, s.x, zhat_);
    }
    const Parameters& p = ctx_.p;
    ResidualSum res;
    {
      ScopedTimer t(ctx_.tm.spmv);  // the sweep is the product with A (and the triangular solve)
      res = with_modulus(ctx_.box, [&](const auto& m) {
        return aor_sweep(m, ctx_.A, s.z, lcp ? nullptr : &s.zeta_z, lcp ? nullptr : &zhat_, ctx_.q, p.omega1,
                         omega1_is_identity_, p.omega2, inverse_diagonal_, lower_scale_, p.gamma, s.x, z_next_, dx_,
                         s.step);
      });
    }
    return ctx_.residual_norm(res, s);
  }
  void move_x(Iterate&) {}  // done by the sweep
  void update_z(Iterate& s) { s.z.swap(z_next_); }
  /// x⁽ᵏ⁺¹⁾ − x⁽ᵏ⁾ of the last sweep.
  const Vector& dx() const { return dx_; }

 private:
  Context<MatrixType>& ctx_;
  const Vector& inverse_diagonal_;
  const double lower_scale_;
  const bool omega1_is_identity_;
  Vector z_next_, dx_, zhat_;
};

/// One step of Method 3.1 with any splitting: rhs = Ω2(m(x) − x) − γ(A ẑ + q), x += Lm⁻¹ rhs.
/// For an LCP with the explicit z-update on a row-major A, evaluate computes the product, Res
/// and rhs in one pass (ẑ = z there): the iteration is memory-bound.
template <typename MatrixType>
class SplittingStep : public StepBase {
 public:
  using Vector = Eigen::VectorXd;
  using StorageIndex = typename MatrixType::StorageIndex;
  SplittingStep(Context<MatrixType>& ctx, const Splitting<StorageIndex>& sp)
      : ctx_(ctx), sp_(sp),
        fused_(MatrixType::IsRowMajor && ctx.lcp() && ctx.zu == ZUpdate::Explicit),
        Az_(ctx.n()), rhs_(ctx.n()), dx_(ctx.n()) {}

  double evaluate(Iterate& s) {
    if (fused_) return evaluate_fused(s);
    ctx_.spmv(s.z, Az_);
    ctx_.eval_zeta(s, s.z, s.zeta_z);
    if (!s.zeta_ok || !s.finite) return std::numeric_limits<double>::quiet_NaN();
    return ctx_.residual(Az_, s);
  }
  void move_x(Iterate& s) {
    make_rhs(s);
    solve_left();
    relax(s, 1.0);
  }
  void update_z(Iterate& s) { ctx_.next_z(s); }
  /// x⁽ᵏ⁺¹⁾ − x⁽ᵏ⁾ of the last step.
  const Vector& dx() const { return dx_; }

 protected:
  double evaluate_fused(const Iterate& s) {
    return with_modulus(ctx_.box, [&](const auto& m) { return evaluate_fused(m, s); });
  }
  template <typename Modulus>
  double evaluate_fused(const Modulus& m, const Iterate& s) {
    if constexpr (MatrixType::IsRowMajor) {
      const Vector &q = ctx_.q, &om2 = ctx_.p.omega2, &x = s.x, &z = s.z;
      const double gamma = ctx_.p.gamma;
      ResidualSum res;
      {
        ScopedTimer t(ctx_.tm.spmv);
        for (Eigen::Index i = 0; i < ctx_.n(); ++i) {
          double a = 0;
          for (typename MatrixType::InnerIterator it(ctx_.A, i); it; ++it) a += it.value() * z[it.index()];
          const double wi = a + q[i];
          m.add(res, i, wi, z[i]);
          rhs_[i] = om2[i] * m.minus(i, x[i]) - gamma * wi;
        }
      }
      return ctx_.residual_norm(res, s);
    }
    return std::numeric_limits<double>::quiet_NaN();  // unreachable: fused_ needs row-major
  }
  // rhs = Ω2(m(x) − x) − γ(A ẑ + q); ẑ = z (Az known) for an LCP with the explicit update.
  void make_rhs(Iterate& s) {
    if (fused_) return;
    const Vector* Azh = &Az_;
    if (!(ctx_.lcp() && ctx_.zu == ZUpdate::Explicit)) {
      zhat_.resize(ctx_.n());
      ctx_.from_modulus(&s.zeta_z, s.x, zhat_);
      ctx_.spmv(zhat_, Azhat_);
      Azh = &Azhat_;
    }
    const Vector &q = ctx_.q, &om2 = ctx_.p.omega2, &x = s.x;
    const double gamma = ctx_.p.gamma;
    with_modulus(ctx_.box, [&](const auto& m) {
      for (Eigen::Index i = 0; i < ctx_.n(); ++i) rhs_[i] = om2[i] * m.minus(i, x[i]) - gamma * ((*Azh)[i] + q[i]);
    });
  }
  void solve_left() {
    ScopedTimer t(ctx_.tm.inner_solve);
    sp_.solve(rhs_, dx_);
  }
  // dx ← θ dx, x += dx, s.step = ‖x⁽ᵏ⁺¹⁾ − x⁽ᵏ⁾‖∞ as taken (0 when x is unchanged, however large dx),
  // over every process's rows.
  void relax(Iterate& s, double theta) {
    double step = 0;
    for (Eigen::Index i = 0; i < ctx_.n(); ++i) {
      const double d = theta * dx_[i];
      dx_[i] = d;
      const double xn = s.x[i] + d;
      step = std::max(step, std::abs(xn - s.x[i]));
      s.x[i] = xn;
    }
    s.step = ctx_.comm.max(step);
  }

  Context<MatrixType>& ctx_;
  const Splitting<StorageIndex>& sp_;
  const bool fused_;
  Vector Az_, Azhat_, zhat_, rhs_, dx_;
};

/// The two-sweep modulus method (Wu–Li form): SplittingStep with M1, whose rhs also takes
/// −N2(m(x⁽ᵏ⁾) − m(x⁽ᵏ⁻¹⁾)), relaxed by θ.
template <typename MatrixType>
class TwoSweepStep : public SplittingStep<MatrixType> {
  using Base = SplittingStep<MatrixType>;

 public:
  TwoSweepStep(Context<MatrixType>& ctx, const Splitting<typename Base::StorageIndex>& sp, double theta,
               const Iterate& s)
      : Base(ctx, sp), theta_(theta) {
    ctx.modulus(s.x, absx_prev_);
  }

  void move_x(Iterate& s) {
    this->make_rhs(s);
    {
      this->ctx_.modulus(s.x, absx_);
      ScopedTimer t(this->ctx_.tm.spmv);
      this->rhs_.noalias() -= this->sp_.n2() * (absx_ - absx_prev_);
      absx_prev_.swap(absx_);
    }
    this->solve_left();
    this->relax(s, theta_);
  }

 private:
  const double theta_;
  Eigen::VectorXd absx_prev_, absx_;  // m(x⁽ᵏ⁻¹⁾), m(x⁽ᵏ⁾): |x| for the LCP
};

}  // namespace nrmicp::detail
