// nrmicp — the Newton member on a callable ζ without a Jacobian, or on bounds that depend on z
// (an affine ζ or an implicit upper bound u with bounds): the outer fixed point
//
//   z ← S(ζ(z), u(z)),   S(ψ, υ) = the solution of the box problem ψ ≤ z ≤ υ (Newton, newton_run.hpp;
//                       υ none: the obstacle problem z ≥ ψ),
//
// as a step of the family's loop (solver.hpp), so that the one Monitor (detail/stopping.hpp)
// decides when it stops, keeps its history and best iterate and calls the callback. Each inner
// solve is warm-started from z and from the last inner solve's active set, and inexact: it stops
// at `forcing` × Res(z) (0: to a settled active set). The outer map G(z) = S(ζ(z)) is accelerated
// by Anderson (detail/anderson.hpp), safeguarded: a mixed iterate whose Res is not below Res(z) is
// replaced by the plain G(z) and the memory cleared. A plain step whose Res fails the non-monotone
// test hands over to runs of the fallback member on the whole ICP from the best iterate
// (SweepRuns, as a level's loop does: detail/globalization.hpp).
#pragma once

#include "../result.hpp"
#include "anderson.hpp"
#include "globalization.hpp"
#include "iterate.hpp"
#include "stopping.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <utility>

namespace nrmicp::detail {

/// `Run` (detail::NewtonRun) provides, each counted in its tally:
///   Frozen                                                the bounds frozen at one z (ζ(z), and u(z)
///                                                         when u is implicit), constructible from n,
///                                                         with swap
///   Result obstacle(const Frozen& b, const Vector* z, bool first, double tol)
///                                                         the inner solve S(b) from z (null: from
///                                                         z = ψ) to Res < tol (0: a settled active
///                                                         set); the first one may start nested
///   double icp_residual(const Vector& v, Frozen& b)       Res of the ICP at v, the bounds at v in b
///                                                         (NaN: ζ or u failed)
///   Result sweep(const Vector& z0, int sweeps)            a run of the fallback member
///   int sweeps_spent() const, int sweep_budget() const
template <typename Run>
class OuterFixedPoint {
 public:
  using Vector = Eigen::VectorXd;
  using Frozen = typename Run::Frozen;

  /// From z (`given`: z is the user's start; else the inner solve starts as the problem's own).
  /// `memory`: Anderson's (0: the plain fixed point); `forcing`: the inner solves' (0: exact).
  OuterFixedPoint(Run& run, Vector z, bool given, Iterate& s, int memory, double forcing)
      : run_(run), z_(std::move(z)), psi_(z_.size()), psi_new_(z_.size()), given_(given),
        r_(run.icp_residual(z_, psi_)), test_(r_), best_z_(z_), best_r_(r_), runs_(run.sweep_budget()),
        aa_(std::max(memory, 1), run.comm()), accelerate_(memory > 0), forcing_(forcing) {
    s.z = z_;
  }

  /// Res of z (computed when z was made); NaN when ζ failed there.
  double evaluate(Iterate& s) {
    s.zeta_ok = !std::isnan(r_);
    return r_;
  }
  /// One outer step (accelerated, or plain), or a run of the fallback member when the step is not acceptable.
  void move_x(Iterate&) {
    Result inner = run_.obstacle(psi_, given_ || !first_ ? &z_ : nullptr, first_, forcing_ * r_);
    first_ = false;
    if (accelerate_ && accelerated(inner.z)) return;
    const double r = run_.icp_residual(inner.z, psi_new_);
    if (std::isnan(r)) {  // ζ failed: the Monitor ends the solve at this iterate
      r_ = r;
      return;
    }
    if (test_.acceptable(r)) {
      z_.swap(inner.z);
      psi_.swap(psi_new_);
      r_ = r;
      test_.push(r);
    } else {
      fall_back();
    }
    if (r_ < best_r_) { best_z_ = z_; best_r_ = r_; }
  }
  void update_z(Iterate& s) { s.z = z_; }
  const StepEnd* end() const { return end_ ? &*end_ : nullptr; }
  /// Accelerated outer steps replaced by the plain one (Result::counters "anderson_rejections").
  void report(Result& r) const { r.counters["anderson_rejections"] += rejections_; }

 private:
  /// Anderson's mix of the outer steps so far with G(z) = `plain`, taken when its Res is below
  /// Res(z); false (memory cleared) when it is not, or when there is nothing to mix yet.
  bool accelerated(const Vector& plain) {
    aa_.step(z_, plain - z_, mixed_);
    if (aa_.size() == 0) return false;
    const double r = run_.icp_residual(mixed_, psi_new_);
    if (!(r < r_)) {  // no lower Res (or ζ failed there): the plain step, by the plain rules
      aa_.reset();
      ++rejections_;
      return false;
    }
    z_.swap(mixed_);
    psi_.swap(psi_new_);
    r_ = r;
    test_.push(r);
    if (r_ < best_r_) { best_z_ = z_; best_r_ = r_; }
    return true;
  }

  void fall_back() {
    const int k = runs_.next(run_.sweeps_spent());
    if (!k) return give_up();
    const Result sw = run_.sweep(best_z_, k);
    if (!(sw.residual < best_r_)) return give_up();
    z_ = sw.z;
    r_ = run_.icp_residual(z_, psi_);
    test_.reset(r_);
    aa_.reset();  // the differences before the sweeps describe another stretch of the map
  }
  void give_up() { end_ = StepEnd{runs_.give_up(run_.sweeps_spent()), {}}; }

  Run& run_;
  Vector z_;
  Frozen psi_, psi_new_;  // the bounds frozen at z, at the trial
  bool given_, first_ = true;
  double r_;
  NonMonotone test_;
  Vector best_z_;
  double best_r_;
  SweepRuns runs_;
  Anderson aa_;
  Vector mixed_;  // Anderson's iterate
  bool accelerate_;
  double forcing_;
  long long rejections_ = 0;
  std::optional<StepEnd> end_;
};

}  // namespace nrmicp::detail
