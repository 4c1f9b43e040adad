// nrmicp — the Newton member on a callable ζ without a Jacobian, or on bounds that depend on z
// (an affine ζ or an implicit upper bound u with bounds): the outer fixed point
//
//   z ← G(z) = S(ζ(z), u(z)),   S(ψ, υ) = the solution of the box problem ψ ≤ z ≤ υ (Newton,
//                              newton_run.hpp; υ none: the obstacle problem z ≥ ψ),
//
// as a step of the family's loop (solver.hpp), so that the one Monitor (detail/stopping.hpp)
// decides when it stops, keeps its history and best iterate and calls the callback. Each inner
// solve is warm-started from z and from the last inner solve's active set, and exact (to a settled
// active set: a stop at a fraction of Res, which weighs w against z − ζ(z), made the outer steps
// depend on A's units). The outer map is accelerated by Anderson (detail/anderson.hpp), safeguarded.
//
// The outer steps are judged by the map's own residual ‖G(z) − z‖∞, in z's units and in the norm in
// which S (an M-matrix's comparison principle) and a Lipschitz-1 ζ (impulse control's) are non-expansive:
// in ‖·‖₂ a warm start near the answer saw it double and stagnated (docs/MEASUREMENTS.md, "The outer
// fixed point judged in the max norm"). S, hence G and
// every decision below, is the same when A and q are scaled together, whereas Res mixes w (A's units)
// with z − ζ(z) (z's): on σA (the default rule's units) Res(0) is the small load ‖σq‖ and every
// good outer step looked worse than z = 0 (docs/MEASUREMENTS.md, "The outer fixed point in z's
// units"). A mixed iterate is kept when the next inner solve shows ‖G − z‖ below that of the iterate
// it was mixed from; else, when it is nearly as low (kReuseMix), its own G (that inner solve's
// answer) is the next iterate, a plain step from it, the memory restarting from the two iterates'
// pairs, or the plain G of the iterate it was mixed from, the memory cleared. A plain
// step whose ‖G − z‖ fails the non-monotone test hands over to runs of the fallback member on the
// whole ICP from the best iterate by Res (SweepRuns, as a level's loop does: detail/globalization.hpp).
// A move that meets Res's rounding floor (met_floor, the rule of a level's loop, with the level row by
// row) ends the solve STAGNATED with floor_message, which the default rule takes for converged.
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
///                                                         set); the first one may start nested, its
///                                                         bounds taken afresh on the way (at z_f)
///   bool moved_start(Vector& z, Frozen& b, double& r)     after the first: it was S at z_f; z, b, r
///                                                         become z_f, its bounds and Res
///   double icp_residual(const Vector& v, Frozen& b)       Res of the ICP at v, the bounds at v in b
///                                                         (NaN: ζ or u failed)
///   double rounding_level(const Vector& v, const Frozen& b)  the rounding level of Res at the v of the
///                                                         last icp_residual (its bounds b)
///   double tol() const                                    the solve's tol
///   Result sweep(const Vector& z0, int sweeps)            a run of the fallback member
///   int sweeps_spent() const, int sweep_budget() const, const Comm& comm() const
template <typename Run>
class OuterFixedPoint {
 public:
  using Vector = Eigen::VectorXd;
  using Frozen = typename Run::Frozen;

  /// From z (`given`: z is the user's start; else the inner solve starts as the problem's own).
  /// `memory`: Anderson's (0: the plain fixed point).
  OuterFixedPoint(Run& run, Vector z, bool given, Iterate& s, int memory)
      : run_(run), z_(std::move(z)), psi_(z_.size()), psi_new_(z_.size()), given_(given),
        r_(run.icp_residual(z_, psi_)), best_z_(z_), best_r_(r_), runs_(run.sweep_budget()),
        aa_(std::max(memory, 1), run.comm()), accelerate_(memory > 0) {
    s.z = z_;
  }

  /// Res of z (computed when z was made); NaN when ζ failed there.
  double evaluate(Iterate& s) {
    s.zeta_ok = !std::isnan(r_);
    return r_;
  }
  /// One outer step: G(z), which judges how z was reached, then the next iterate (Anderson's mix,
  /// or G(z)); or a run of the fallback member when a plain step is not acceptable.
  void move_x(Iterate&) {
    if (floor_end_) return void(end_ = floor_end_);  // (after the Monitor has looked at the iterate that met it)
    Result inner = run_.obstacle(psi_, given_ || !first_ ? &z_ : nullptr, first_, 0.0);
    // a nested first solve whose start took ζ at z_f solved S(ζ(z_f)): G of z_f, the iterate it judges
    // (z_f is not a best iterate: the Monitor never saw it, and the floor's message quotes the best)
    if (first_) run_.moved_start(z_, psi_, r_);
    first_ = false;
    const double f = run_.comm().inf_norm(inner.z - z_);  // ‖G(z) − z‖∞, z's units
    if (stalled(f)) return;
    if (mixed_) {
      mixed_ = false;
      if (!(f < f_from_)) return reject_mix(inner.z, f);
    } else if (judged_ && !test_.acceptable(f)) {
      return fall_back();
    }
    if (judged_) test_.push(f); else test_.reset(f);
    judged_ = true;
    if (!(accelerate_ && mix(inner.z, f))) take(inner.z);
    if (r_ < best_r_) { best_z_ = z_; best_r_ = r_; }
  }
  void update_z(Iterate& s) { s.z = z_; }
  const StepEnd* end() const { return end_ ? &*end_ : nullptr; }
  /// Accelerated outer steps replaced by the plain one (Result::counters "anderson_rejections").
  void report(Result& r) const { r.counters["anderson_rejections"] += rejections_; }

 private:
  /// Anderson's mix of the outer steps so far with G(z) = `plain` becomes the iterate, on trial until
  /// its own G is known; false (nothing to mix yet, or ζ failed at the mix: memory cleared) for the plain step.
  bool mix(Vector& plain, double f) {
    aa_.step(z_, plain - z_, mixed_z_);
    if (aa_.size() == 0) return false;
    const double r = run_.icp_residual(mixed_z_, psi_new_);
    if (std::isnan(r) || std::isinf(r)) {
      aa_.reset();
      ++rejections_;
      return false;
    }
    plain_.swap(plain);
    f_from_ = f;
    z_.swap(mixed_z_);
    psi_.swap(psi_new_);
    judge_floor(r);
    mixed_ = true;
    return true;
  }
  /// The mixed iterate did not lower ‖G − z‖ (it is f): the plain step from it, to its G = `plain`,
  /// which the inner solve that judged it computed, when f is within kReuseMix of the iterate it was
  /// mixed from (the memory then restarts from both pairs); else the plain step from that iterate,
  /// G of it, the memory cleared (an inner solve more: docs/MEASUREMENTS.md, "A rejected mix's own step").
  void reject_mix(Vector& plain, double f) {
    ++rejections_;
    if (f <= kReuseMix * f_from_) {
      aa_.restart(z_, plain - z_);
      take(plain);
    } else {
      aa_.reset();
      take(plain_);
    }
    if (r_ < best_r_) { best_z_ = z_; best_r_ = r_; }
  }
  /// A rejected mix whose ‖G − z‖ is at most this factor of its origin's is as good a point to step
  /// from, and its step is known; well above it the step from the mix did worse (docs/MEASUREMENTS.md,
  /// "A rejected mix's own step").
  static constexpr double kReuseMix = 1.1;
  /// The plain step to v = G(z) (z stays when ζ fails at v: the Monitor ends the solve).
  void take(Vector& v) {
    const double r = run_.icp_residual(v, psi_new_);
    if (std::isnan(r)) return void(r_ = r);
    z_.swap(v);
    psi_.swap(psi_new_);
    judge_floor(r);
  }
  /// z (Res r, just made from the iterate of Res r_) met Res's rounding floor: the next move ends the solve.
  void judge_floor(double r) {
    double level = 0;
    if (met_floor(r_, r, run_.tol(), [&] { return level = run_.rounding_level(z_, psi_); }))
      floor_end_ = StepEnd{Status::Stagnated,
                           floor_message(std::min(best_r_, r), run_.tol(), level,
                                         "an outer step did not halve Res, within " + to_text(kFloorFactor) +
                                         "x of its rounding level before and after it")};
    r_ = r;
  }

  void fall_back() {
    if (best_at_floor()) return;
    const int k = runs_.next(run_.sweeps_spent());
    if (!k) return give_up();
    const Result sw = run_.sweep(best_z_, k);
    if (!(sw.residual < best_r_)) return give_up();
    z_ = sw.z;
    r_ = run_.icp_residual(z_, psi_);
    judged_ = false;  // the sweeps' iterate is no outer step: its ‖G − z‖ starts the test afresh
    best_f_ = kNone, since_best_f_ = 0;  // ... and the stall rule's count
    aa_.reset();  // the differences before the sweeps describe another stretch of the map
    if (r_ < best_r_) { best_z_ = z_; best_r_ = r_; }
  }
  /// The best iterate's Res is within kFloorFactor of its rounding level: the steps that no longer
  /// contract are rounding's, and no sweeps bring Res lower; the solve ends there with floor_message.
  bool best_at_floor() {
    Frozen zeta_best(best_z_.size());
    const double r = run_.icp_residual(best_z_, zeta_best);  // (w of the best iterate, for its level)
    const double level = run_.rounding_level(best_z_, zeta_best);
    if (!(std::max(r, best_r_) <= kFloorFactor * level)) return false;
    end_ = StepEnd{Status::Stagnated, floor_message(best_r_, run_.tol(), level,
                                                    "the outer steps stopped contracting, the best iterate's Res within " +
                                                    to_text(kFloorFactor) + "x of its rounding level")};
    return true;
  }
  void give_up() { end_ = StepEnd{runs_.give_up(run_.sweeps_spent()), {}}; }
  /// ‖G − z‖ has not gone below its best for kStallSteps outer steps: the map no longer contracts (a ζ
  /// evaluated less accurately than the target asks, e.g. by an inner solve of its own); each step is
  /// a whole obstacle solve, so the solve ends here, STAGNATED, its best iterate returned.
  bool stalled(double f) {
    if (f < best_f_) best_f_ = f, since_best_f_ = 0;
    else if (++since_best_f_ >= kStallSteps)
      end_ = StepEnd{Status::Stagnated, "the outer steps stopped contracting: ||G(z) - z|| not below its best (" +
                                            to_text(best_f_) + ") for " + std::to_string(kStallSteps) +
                                            " outer steps; returning the best iterate"};
    return end_.has_value();
  }
  /// Outer steps without a new best ‖G − z‖ before the solve ends (docs/MEASUREMENTS.md, "The outer
  /// fixed point's stall rule").
  static constexpr int kStallSteps = 10;

  static constexpr double kNone = std::numeric_limits<double>::infinity();  // no ‖G − z‖ yet: any finite one is acceptable
  Run& run_;
  Vector z_;
  Frozen psi_, psi_new_;  // the bounds frozen at z, at the trial
  bool given_, first_ = true;
  double r_;
  NonMonotone test_{kNone};  // on the plain steps' ‖G − z‖
  bool judged_ = false;      // test_ holds a ‖G − z‖ (not at the start, nor after the sweeps)
  Vector best_z_;
  double best_r_;
  SweepRuns runs_;
  Anderson aa_;
  Vector mixed_z_, plain_;  // Anderson's iterate; G of the iterate it was mixed from
  bool mixed_ = false;      // z is Anderson's mix, on trial
  double f_from_ = kNone;   // ‖G − z‖ of the iterate z was mixed from
  bool accelerate_;
  double best_f_ = kNone;  // the smallest ‖G − z‖ so far
  int since_best_f_ = 0;   // outer steps since it
  long long rejections_ = 0;
  std::optional<StepEnd> end_, floor_end_;
};

}  // namespace nrmicp::detail
