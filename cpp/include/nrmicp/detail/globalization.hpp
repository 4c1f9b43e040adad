// nrmicp — the globalization of the Newton member: a wrapper that makes a plain Newton step
// (detail/newton_step.hpp) a step of the family's loop (the interface at the top of solver.hpp),
// in the spirit of detail::Accelerated, which guards a step with a fallback too.
//
// A Newton step is accepted when its Res is below the largest Res of the last 5 accepted iterates
// (NonMonotone: the active-set steps are not monotone in Res, but the reference value never grows;
// the first step after a start is exempt: a start is not a Newton iterate); a step whose active set
// more than triples is halved first (an overshoot: Globalized::overshoots). A step that is rejected,
// an active set seen before (a cycle) or a singular reduced system hands over to sweeps of the
// fallback member (nrm: M = A, the paper's first member, chosen for P-matrices on which nrmgs
// cycles as the active-set steps do) from the best iterate, 10, then 20, 40, ... sweeps, after which
// Newton resumes (docs/MEASUREMENTS.md, "Non-monotone acceptance and the fallback member"). The
// step's own ends (StepEnd): the active set repeats, or z no longer moves beyond rounding
// (STAGNATED: z solves its own piece, Res is at its rounding floor); the fallback brings no better
// iterate (STAGNATED; MAX_ITERATIONS when it has spent its budget); maxiter Newton steps
// (MAX_ITERATIONS); ζ's Jacobian failed (ZETA_FAILED). Everything else — tol, divergence, the
// callback, Ctrl-C, the history — is the Monitor's (detail/stopping.hpp).
#pragma once

#include "../result.hpp"
#include "box.hpp"
#include "iterate.hpp"
#include "stopping.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <unordered_set>
#include <vector>

namespace nrmicp::detail {

/// The non-monotone acceptance test (Grippo–Lampariello–Lucidi): a new Res is acceptable when it
/// is below the largest of the last 5 accepted ones, so the reference value never grows.
class NonMonotone {
 public:
  explicit NonMonotone(double r) { reset(r); }
  void reset(double r) { recent_.assign(1, r); }
  bool acceptable(double r) const { return std::isfinite(r) && r < *std::max_element(recent_.begin(), recent_.end()); }
  void push(double r) {
    recent_.push_back(r);
    if (recent_.size() > 5) recent_.erase(recent_.begin());
  }

 private:
  std::vector<double> recent_;
};

/// How close to its rounding level Res counts as there (a step on the right piece lands within
/// a few times the level; one on a wrong piece leaves Res orders of magnitude above it).
inline constexpr double kFloorFactor = 100;

/// A Newton step whose trial has more than kOvershootGrowth times the active points of the
/// (nonempty) set it was solved on has overshot, and is damped to z + kOvershootDamping (z⁺ − z)
/// (Globalized::overshoots; docs/MEASUREMENTS.md, "`Globalized::kOvershootGrowth` = 3").
inline constexpr double kOvershootGrowth = 3.0;
inline constexpr double kOvershootDamping = 0.5;
/// Each new step of an LCP or affine ICP (ζ none, constant or affine) is followed by this many
/// symmetric projected Gauss–Seidel sweeps before its active set is read: the step leaves a wrong contact band at the
/// free boundary that the next steps would peel one layer each; a sweep frees or activates
/// several layers at the cost of two passes over A (NewtonLevel::projected_gauss_seidel;
/// docs/MEASUREMENTS.md, "`Globalized::kSmoothingSweeps` = 2").
inline constexpr int kSmoothingSweeps = 2;

/// A step that does not reduce Res by this factor is slow: near Res's rounding level it is taken
/// as the floor (Globalized::at_rounding_level), above it as a poor Jacobian's (JacobianCheck).
inline constexpr double kSlowStep = 0.5;

/// A step from Res r_old to r above tol met Res's rounding floor: it did not reduce Res by kSlowStep,
/// and Res before and after it are within kFloorFactor of the rounding level (`level()`, computed only
/// then). Both: a step that leaves the floor band has moved the active set (a non-monotone step) and
/// the iteration goes on (docs/MEASUREMENTS.md, "The rounding floor judged before and after a step").
/// The rule of a level's Newton loop (Globalized) and of the outer fixed point.
template <typename Level>
bool met_floor(double r_old, double r, double tol, Level level) {
  if (r < tol || r < kSlowStep * r_old) return false;
  return std::max(r, r_old) <= kFloorFactor * level();
}

/// A callable ζ's `zeta_jacobian` that does not deliver. With ζ's derivative, Newton solves an
/// active set that has settled in one step (ζ affine) or converges superlinearly on it; with a poor
/// one, each step on the set contracts only as the outer fixed point does, and a wrong one makes Res
/// grow. Judged poor: kPoorSlowSteps accepted steps in a row, each slow (kSlowStep) above the rounding
/// level, or kPoorGrowthSteps steps rejected because Res grew, each on the active set of the step
/// before (a step that moves the set may raise Res with the right Jacobian too: docs/MEASUREMENTS.md,
/// "A Jacobian that does not deliver"). The solve then goes on without it.
inline constexpr int kPoorSlowSteps = 3;
inline constexpr int kPoorGrowthSteps = 2;
/// A Jacobian that misses ζ's difference quotient along the last move by more than this fraction
/// (Plain::jacobian_miss) is not ζ's derivative: negated misses by 1, ten times too large 0.9, zero 1.
inline constexpr double kJacobianMiss = 0.5;
/// Slow steps of a Jacobian that is ζ's derivative (its miss at most kResolvedMiss), stalling while they
/// move z by less than kResolvedMove of its size, stall at what ζ itself resolves (a ζ computed by an
/// inner solve): the outer fixed point goes no further, and the solve ends there. An approximate Jacobian
/// (a miss of 20–50%) stalls by converging linearly, which the outer fixed point cures (docs/MEASUREMENTS.md,
/// "A Jacobian that matches, at what ζ resolves"). Both ratios are in z's units: A's units change no decision.
inline constexpr double kResolvedMove = 1e-8;
inline constexpr double kResolvedMiss = 1e-3;
/// With outer steps (NewtonControl::outer_steps) a step is slow when it does not reduce Res by this
/// factor, on any active set (no peeling excuses it): with ζ's derivative the steps reduce it far more,
/// a poor Jacobian's only as the outer map does (docs/MEASUREMENTS.md, "Matrix-free Newton steps").
inline constexpr double kOuterSlowStep = 0.1;

class JacobianCheck {
 public:
  /// `outer`: the steps are placed by outer steps (NewtonControl::outer_steps).
  explicit JacobianCheck(bool outer = false) : outer_(outer) {}
  bool outer() const { return outer_; }
  /// Whether an accepted step from Res r_old to r is slow (kSlowStep; kOuterSlowStep with outer steps).
  bool slow(double r, double r_old) const { return !(r < (outer_ ? kOuterSlowStep : kSlowStep) * r_old); }
  /// An accepted step: `slow` (above the rounding level) on the same active set as the step before.
  void accepted(bool same_set, bool slow) { slow_ = (same_set || outer_) && slow ? slow_ + 1 : 0; }
  /// A step rejected by the acceptance test (Res grew beyond the non-monotone reference, or is not finite).
  void rejected(bool same_set) { grew_ += same_set || outer_; }
  bool poor() const { return slow_ >= kPoorSlowSteps || grew_ >= kPoorGrowthSteps; }
  /// Poor by slow accepted steps (their last move is the step's; a growth stall's trials were rejected).
  bool slow_stall() const { return slow_ >= kPoorSlowSteps; }
  /// Why (the start of the solve's message). `matches`: ζ′ was found to match ζ's difference quotient
  /// (kJacobianMiss), so the steps, not the Jacobian, failed: said as such.
  std::string message(bool matches = false) const {
    if (!matches && slow_ < kPoorSlowSteps && !grew_)  // (the fallback gave up: no step was judged)
      return "zeta_jacobian looks wrong: its Newton steps did not reduce Res, nor did the fallback from the best iterate";
    if (matches)
      return "the Newton steps with zeta_jacobian stopped converging (" +
             (slow_ >= kPoorSlowSteps ? std::to_string(slow_) + " in a row each reduced Res by less than a factor " +
                                            to_text(1 / (outer_ ? kOuterSlowStep : kSlowStep))
                                      : std::to_string(grew_) + " made Res grow") +
             ") though zeta_jacobian matches zeta's difference quotient: zeta may resolve less than the target asks";
    if (outer_)
      return slow_ >= kPoorSlowSteps
                 ? "zeta_jacobian looks wrong: " + std::to_string(slow_) + " Newton steps in a row each reduced Res by "
                   "less than a factor " + to_text(1 / kOuterSlowStep) + " (with the derivative of zeta they converge superlinearly)"
                 : "zeta_jacobian looks wrong: " + std::to_string(grew_) + " of its Newton steps made Res grow";
    return slow_ >= kPoorSlowSteps
               ? "zeta_jacobian looks wrong: " + std::to_string(slow_) + " Newton steps in a row on one active set each "
                 "reduced Res by less than a factor " + to_text(1 / kSlowStep) + " (with the derivative of zeta one step solves a settled set)"
               : "zeta_jacobian looks wrong: " + std::to_string(grew_) + " of its Newton steps on the active set of the step before made Res grow";
  }

 private:
  bool outer_;
  int slow_ = 0, grew_ = 0;
};

/// The message of a Newton loop that settled at Res's rounding floor above tol (`why`: the evidence,
/// the level's loop's by default).
inline std::string floor_message(double best, double tol, double floor,
                                 const std::string& why = "the active set has settled and a further Newton step does not reduce Res") {
  return "stagnated: Res reached its rounding floor (" + why + "): best Res " + to_text(best) + " >= tol " + to_text(tol) +
         ", rounding level eps ||t|| (t_i: |A||z| + |q| where Res takes w_i, |z| + |zeta(z)| where it takes "
         "z_i - zeta_i(z)) = " + to_text(floor) + "; returning the best iterate";
}

/// A settled set (or a z that stood still) far above the rounding level: no floor to blame, another
/// member may do better (docs/MEASUREMENTS.md, "The rounding floor judged before and after a step").
inline std::string repeat_message(double best, double tol, double floor) {
  return "stagnated: the Newton steps stopped moving (the active set repeated, or a step left z unchanged) at best "
         "Res " + to_text(best) + " >= tol " + to_text(tol) + ", above the rounding level " + to_text(floor) +
         "; returning the best iterate (another member, e.g. 'nrmm' or 'nrm', may converge)";
}

/// The fallback's runs of sweeps from the best iterate: 10, then 20, 40, ... sweeps, within a
/// budget of sweeps in all (a level's loop, and the outer fixed point: newton_run.hpp).
class SweepRuns {
 public:
  explicit SweepRuns(int budget) : budget_(budget) {}
  /// The length of the next run when `spent` sweeps are spent; 0 when the budget is.
  int next(int spent) {
    if (spent >= budget_) return 0;
    const int k = std::min(run_, budget_ - spent);
    run_ = std::min(run_, std::numeric_limits<int>::max() / 2) * 2;  // no overflow to a negative run
    return k;
  }
  /// Why the fallback ends the solve: MAX_ITERATIONS once the budget is spent, else (the run
  /// brought no better iterate) STAGNATED.
  Status give_up(int spent) const { return spent >= budget_ && budget_ > 0 ? Status::MaxIterations : Status::Stagnated; }

 private:
  int budget_, run_ = 10;
};

/// What the Newton loop on one level needs to know and may report to.
struct NewtonControl {
  /// The Monitor's options, in the vocabulary of every solve: Res < solve.tol ends the loop (0:
  /// only a settled active set does); solve.maxiter counts Newton steps (the step counts them:
  /// a fallback run is a loop iteration but not a step); history, verbose, the stall and
  /// divergence rules as for every member.
  SolveOptions solve = coarse();
  /// Warm start by active set: when not empty, the first step uses this inactive set instead of
  /// the one of the start: after a change of the obstacle the old contact set is a far better
  /// guess than the test on the old z (docs/MEASUREMENTS.md, "A warm start by active set").
  std::vector<char> start_set;
  /// An iterative inner solve may stop at forcing × Res (inexact Newton; a direct one is exact
  /// whatever the forcing), the first step at first_forcing × Res. A set so solved that repeats
  /// settles only once Res < repeat_trust × Res(start); before, it is solved again, to a tenth of
  /// max(tol, repeat_trust × Res(start)), and the loop goes on. 0, the finest level (Res must reach
  /// tol; the steps before are on guessed sets): every loosely solved repeat is solved to tol / 10.
  /// Coarse levels (NewtonTuning::coarse_repeat_trust): a start needs no more than the repeat,
  /// unless Res is still near the start's, where a loose solve may not have moved z far enough to
  /// show the set. ∞: a repeat settles.
  double forcing = 0;
  double first_forcing = 0;
  double repeat_trust = std::numeric_limits<double>::infinity();
  /// A loop to a settled set (solve.tol 0) inside a solve to this tol (an outer fixed point's inner
  /// solve): its linear solves reach ‖b − Kz‖ ≤ settled_tol / 10 where the inner solver's own relative
  /// stop would leave more (an h⁻²-scaled A's large ‖b‖: docs/MEASUREMENTS.md, "The outer fixed point
  /// at its floor"). 0: the inner solver's own stop.
  double settled_tol = 0;
  int sweep_budget = 0;       ///< fallback sweeps allowed in all (0: no fallback)
  /// Non-null: the loop is solve_semismooth's, and *outer_steps says whether outer steps place its
  /// steps (each step's active set is then its outer step's, an outer step follows it and its
  /// fallback is one). While they do, no step is exempt from the acceptance test (else the first
  /// after a start or a fallback is: a start is not a Newton iterate) and JacobianCheck judges the
  /// steps on any set by kOuterSlowStep. When it finds them poor, the Jacobian is given up if it misses
  /// ζ's difference quotient by more than kJacobianMiss; else the problem, not the Jacobian, defeated
  /// the outer steps (a matrix that is no M-matrix): they end (*outer_steps = false,
  /// as NewtonRun sets it when an outer step does not solve its obstacle problem) and the loop goes
  /// on from the best iterate with the plain steps (x ≥ 0 at z), as from a start.
  bool* outer_steps = nullptr;
  Callback callback;  ///< finest level only; called with z = y + shift
  Poll poll;
  Progress progress;  ///< finest level only: the verbose report (solve.verbose seconds apart)
  const Eigen::VectorXd* shift = nullptr;  ///< the constant obstacle of a shifted LCP (for the callback)
  const int* number_from = nullptr;  ///< iterates numbered *number_from + k (Monitor::number_from), else k

 private:
  /// An inner loop's options: no tol (to a settled active set), 50 steps, silent.
  static SolveOptions coarse() {
    SolveOptions o;
    o.tol = 0;
    o.maxiter = 50;
    return o;
  }
};

/// A plain Newton step (NewtonStep), globalized: a step of detail::loop.
template <typename Plain>
class Globalized {
 public:
  using Vector = Eigen::VectorXd;

  Globalized(Plain& plain, const NewtonControl& ctl, Iterate& s)
      : plain_(plain), ctl_(ctl), test_(plain.residual()), best_z_(plain.z()), best_r_(plain.residual()),
        start_r_(plain.residual()), exempt_(!outer()), runs_(ctl.sweep_budget), jacobian_(outer()) {
    s.z = plain.z();
  }

  /// Res of z (computed when z was made); s.x from z's w and g, in place (s.step: how far it moved).
  double evaluate(Iterate& s) {
    s.step = plain_.modulus(s.x);
    return plain_.residual();
  }
  /// A Newton step, or the fallback, or the end.
  void move_x(Iterate&) {
    if (still_ || at_floor_) return settle();
    if (jacobian_.outer() && !outer()) plain_steps();
    if (jacobian_.poor() && !jacobian_.outer()) return give_up_jacobian(true);
    if (plain_.steps() >= ctl_.solve.maxiter) return stop(Status::MaxIterations);
    if (!plain_.linearize()) return stop(Status::ZetaFailed);
    if constexpr (!Plain::set_fixes_step)
      if (jacobian_.outer() && jacobian_.poor()) {  // the Jacobian at z, against ζ's difference quotient
        miss_ = plain_.jacobian_miss();
        if (!(miss_ <= kJacobianMiss)) return give_up_jacobian();  // (a miss that cannot be had: NaN, as a miss)
        plain_steps();
        if (!plain_.linearize()) return stop(Status::ZetaFailed);
      }
    if (!newton()) jacobian_.poor() && !jacobian_.outer() ? give_up_jacobian(true) : fall_back();  // (outer: judged next move)
  }
  void update_z(Iterate& s) { s.z = plain_.z(); }
  const StepEnd* end() const { return end_ ? &*end_ : nullptr; }
  void report(Result&) const {}

  /// The active set repeated (or z stood still): z solves the problem to rounding.
  bool settled() const { return settled_; }
  /// The inactive set of the last accepted step (empty if none).
  const std::vector<char>& inactive() const { return last_inactive_; }
  int sweeps() const { return sweeps_; }
  /// The loop ended because ζ's Jacobian does not deliver (JacobianCheck; never for a fixed ζ).
  bool jacobian_poor() const { return jacobian_poor_; }

 private:
  // A Newton step on z's active set (or the guess); false when the fallback must take over.
  bool newton() {
    if (plain_.steps() == 0 && !ctl_.start_set.empty() && sweeps_ == 0)
      inactive_ = ctl_.start_set;
    else
      plain_.active_set(inactive_);
    std::uint64_t h = 0;
    bool repeat = false;
    if constexpr (Plain::set_fixes_step) {
      h = plain_.fingerprint(inactive_);
      repeat = have_last_ && h == last_set_;
      // a repeat settles, unless its z was solved loosely and Res is not below repeat_trust × its
      // start's, or z is not the solve of any set (sweeps changed its active set): then the set
      // is solved again, to repeat_tol()
      const bool trusted = !loose_ || plain_.residual() < ctl_.repeat_trust * start_r_;
      if (repeat && trusted && !moved_set_) return settle(), true;
      if (!repeat && !seen_.insert(h).second) {  // a cycle: the fallback's, unless the sweeps may cause it
        if (!smooth_) return false;
        smooth_ = false;  // (no M-matrix: a projected sweep can move the set back; none from here)
        seen_.clear();
      }
    }
    if (!repeat && !plain_.factorize(inactive_)) return false;  // a repeat keeps its system
    // Loose only where a repeat is recognized (a set fixes the step): the repeat is then solved to repeat_tol().
    const double forcing = repeat || !Plain::set_fixes_step ? 0.0 : plain_.steps() == 0 ? ctl_.first_forcing : ctl_.forcing;
    loose_ = forcing > 0 && plain_.iterative();
    double r = plain_.solve(inactive_, repeat ? repeat_tol() : ctl_.solve.tol, forcing, ctl_.settled_tol);
    bool damped = false;
    if constexpr (Plain::set_fixes_step)
      if (overshoots()) { r = plain_.damp(kOvershootDamping); damped = true; }
    const bool still = Plain::set_fixes_step && plain_.trial_still();  // the solve's own z⁺, before the sweeps
    // a repeat is the exact solve of its set: kept as solved; so is a step that met tol where smoothing
    // is a solve (the semismooth loop's outer step: the loop ends there anyway)
    if (!repeat && !(Plain::smoothing_solves && r < ctl_.solve.tol)) {
      // a damped z⁺, or one whose set the sweeps changed, is no set's exact solve: its repeat is solved again
      moved_set_ = plain_.smooth(smooth_ ? kSmoothingSweeps : 0) || damped;
      r = plain_.trial_residual();
    }
    const bool same_set = have_last_ && plain_.same_set(inactive_, last_inactive_);
    if (!(std::isfinite(r) && (exempt_ || test_.acceptable(r)))) {
      if constexpr (!Plain::set_fixes_step) jacobian_.rejected(same_set);
      return false;
    }
    const double r_old = plain_.residual();
    accept(r, h, still);
    const bool slow = !(r < ctl_.solve.tol) && !(r < kSlowStep * r_old) && !still_;
    if (slow) at_floor_ = met_floor(r_old, r, ctl_.solve.tol, [&] { return floor_ = plain_.rounding_level(); });
    if constexpr (!Plain::set_fixes_step) {
      bool judged = !(r < ctl_.solve.tol) && jacobian_.slow(r, r_old) && !still_ && !at_floor_;
      if (judged && !slow) judged = !at_rounding_level(std::max(r, r_old));  // (slow: at_floor_ says it)
      jacobian_.accepted(same_set, judged);
    }
    return true;
  }
  // Outer steps place the steps (NewtonControl::outer_steps).
  bool outer() const { return ctl_.outer_steps && *ctl_.outer_steps; }
  // The outer steps end: the plain steps go on from the best iterate, as from a start.
  void plain_steps() {
    if (ctl_.outer_steps) *ctl_.outer_steps = false;
    jacobian_ = JacobianCheck();
    const double r = plain_.restart(best_z_);
    test_.reset(r);
    have_last_ = false;
    exempt_ = !outer();
  }
  // What a repeated set is solved to (a tenth of it: NewtonStep::solve): tol, or where a repeat is
  // trusted below repeat_trust × Res(start), that.
  double repeat_tol() const {
    return std::isfinite(ctl_.repeat_trust) ? std::max(ctl_.solve.tol, ctl_.repeat_trust * start_r_) : ctl_.solve.tol;
  }
  // The trial's active set is more than kOvershootGrowth times the (nonempty) one it was solved on.
  // From a set whose contact is far too small (a nested start where A is no M-matrix) the full step
  // sinks below the obstacle well beyond the true contact set, and the next steps peel that excess
  // one layer at a time; half the step lands near the true set (docs/MEASUREMENTS.md,
  // "`Globalized::kOvershootGrowth` = 3").
  bool overshoots() const {
    const std::size_t active = plain_.active_count(inactive_);
    return active > 0 && static_cast<double>(plain_.trial_active_count()) > kOvershootGrowth * static_cast<double>(active);
  }
  // Res r is within kFloorFactor of its rounding level (the floor band of met_floor).
  bool at_rounding_level(double r) {
    floor_ = plain_.rounding_level();
    return r <= kFloorFactor * floor_;
  }
  void accept(double r, std::uint64_t h, bool still) {
    still_ = still && !(r < ctl_.solve.tol);
    plain_.accept();
    if (r < best_r_ || !std::isfinite(best_r_)) { best_r_ = r; best_z_ = plain_.z(); }
    test_.push(r);
    last_inactive_ = inactive_;
    last_set_ = h;
    have_last_ = true;
    exempt_ = false;
  }
  // Sweeps of the fallback member from the best iterate (SweepRuns).
  void fall_back() {
    // a step rejected while the best Res is at its rounding level lost to rounding: no sweeps bring Res lower
    if (at_rounding_level(best_r_)) return settle();
    const int k = runs_.next(sweeps_);
    if (!k) return give_up();
    const Result fr = plain_.sweep(best_z_, k, ctl_.solve.tol);
    if (fr.iterations == 0 && !fr.message.empty())  // no fallback to be had (NewtonLevel::sweep)
      return void(end_ = StepEnd{Status::Stagnated, "Newton's active sets cycled and " + fr.message});
    sweeps_ += fr.iterations;
    seen_.clear();
    have_last_ = false;
    exempt_ = !outer();
    if (!(fr.residual < best_r_)) return give_up();
    const double r = plain_.restart(fr.z);
    test_.reset(r);
    if (r < best_r_) { best_r_ = r; best_z_ = plain_.z(); }
  }
  // The fallback could not go on. With ζ′ given, a ζ′ that misses ζ's difference quotient is the likelier cause
  // (no step accepted, so JacobianCheck had nothing to judge): the outer fixed point goes on without it.
  void give_up() {
    if constexpr (!Plain::set_fixes_step)
      if (plain_.linearize() && !(plain_.jacobian_miss() <= kJacobianMiss)) return give_up_jacobian(true);
    stop(runs_.give_up(sweeps_));
  }
  /// `check`: the plain steps' verdict, not yet checked against ζ's difference quotient (the outer
  /// steps' is: move_x), is checked at z first (one call of ζ, one product).
  void give_up_jacobian(bool check = false) {
    if constexpr (!Plain::set_fixes_step)
      if (check) {
        if (!plain_.linearize()) return stop(Status::ZetaFailed);
        miss_ = plain_.jacobian_miss();
      }
    const bool checked = (jacobian_.outer() || check) && !std::isnan(miss_);  // (NaN: ζ or J failed at the check)
    const bool matched = checked && miss_ <= kJacobianMiss;
    double move = std::numeric_limits<double>::infinity();
    if constexpr (!Plain::set_fixes_step)
      if (matched && miss_ <= kResolvedMiss && jacobian_.slow_stall()) move = plain_.move_ratio();
    jacobian_poor_ = !(move <= kResolvedMove);  // (poor: the outer fixed point goes on without it)
    std::string why = jacobian_.message(matched);
    if (checked)
      why += ", and zeta_jacobian(z) v misses zeta's difference quotient along the last step v by " + to_text(100 * miss_) + "%";
    if (!jacobian_poor_)
      why += "; its last step moved z by " + to_text(move) + " of its size: the solve ends at what zeta resolves";
    end_ = StepEnd{Status::Stagnated, why};
  }
  // The active set repeated, z stood still, or a step at the rounding level did not reduce Res.
  void settle() {
    settled_ = true;
    if (!(floor_ > 0)) floor_ = plain_.rounding_level();
    end_ = StepEnd{Status::Stagnated, best_r_ <= kFloorFactor * floor_ ? floor_message(best_r_, ctl_.solve.tol, floor_)
                                                                       : repeat_message(best_r_, ctl_.solve.tol, floor_)};
  }
  void stop(Status s) { end_ = StepEnd{s, std::string()}; }

  Plain& plain_;
  const NewtonControl& ctl_;
  NonMonotone test_;
  Vector best_z_;
  double best_r_;
  double start_r_;  // Res of the start (NewtonControl::repeat_trust)
  std::vector<char> inactive_, last_inactive_;
  std::unordered_set<std::uint64_t> seen_;
  std::uint64_t last_set_ = 0;
  bool exempt_;
  bool have_last_ = false, still_ = false, settled_ = false, at_floor_ = false;
  bool loose_ = false;  // the last step was solved to a forcing: a repeat of its set may be solved again (repeat_trust)
  bool smooth_ = true;  // the steps are followed by kSmoothingSweeps (until a cycle)
  bool moved_set_ = false;  // the sweeps after the last step changed its active set: a repeat of it is solved again
  double floor_ = 0;  // the rounding level of Res (computed when a stop at it is considered)
  SweepRuns runs_;
  int sweeps_ = 0;
  JacobianCheck jacobian_;
  double miss_ = 0;  // the Jacobian's miss of ζ's difference quotient (the outer steps' check)
  bool jacobian_poor_ = false;
  std::optional<StepEnd> end_;
};

}  // namespace nrmicp::detail
