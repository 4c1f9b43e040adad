// nrmicp — when a solve stops, for every step kind: converged, diverged, stagnated (rounding
// floor, no progress), the user's callback, maxiter, and the Ctrl-C poll. The Monitor also
// keeps the history and the best iterate, so that a step does nothing but step.
#pragma once

#include "../options.hpp"
#include "../result.hpp"
#include "comm.hpp"
#include "iterate.hpp"
#include "timer.hpp"

#include <Eigen/Core>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <optional>
#include <string>

namespace nrmicp::detail {

/// Called for every iterate k = 0, 1, ... that has a Res (the last one too, whatever ends the
/// solve) with (k, z⁽ᵏ⁾, Res); return true to stop.
using Callback = std::function<bool(int, const Eigen::VectorXd&, double)>;
/// Called about every 50 ms during a solve; may throw to abort (e.g. on Ctrl-C).
using Poll = std::function<void()>;
/// Progress report (Options::verbose): (k, Res of iterate k, best Res, seconds, message); the
/// message is empty while iterating and the result's message at the end.
using Progress = std::function<void(int, double, double, double, const std::string&)>;

/// What the caller hooks into a solve (any may be empty).
struct Hooks {
  const Callback& callback;
  const Poll& poll;
  const Progress& progress;
};

/// A step's own end of the loop (a rule only that step kind knows: the Newton member's settled
/// active set, or a fallback that brings nothing): the status, and a message that replaces the
/// status's standard one when not empty.
struct StepEnd {
  Status status;
  std::string message;
};

/// Stuck: Res bit-identical for kStuck iterates in a row, and either x did not move in those
/// steps (a fixed point of the iteration that is not a solution) or ‖z‖∞ grew at each of them
/// (a runaway Res does not see: nrm on a zero row with q_i < 0 grows z_i by the same amount
/// each step, forever). z moving otherwise is not stuck: Res can stay bit-identical while z falls
/// steadily, then converge (docs/MEASUREMENTS.md, "The stall rule's windows and the stuck rule");
/// and a run where z stays and x moves is a plateau (StallWindows). ‖z‖∞ is computed only on the
/// iterates of a run.
class StuckRule {
 public:
  static constexpr int kStuck = 5;
  enum class Stuck { None, FixedPoint, Runaway };
  /// The iterate s with Res r, the one before with Res last_r.
  void track(double r, double last_r, const Iterate& s, const Comm& comm) {
    if (!(r == last_r)) {
      same_ = 0;
      return;
    }
    const double znorm = comm.inf_norm(s.z);
    if (same_++ == 0) {
      x_still_ = z_grows_ = true;
    } else {
      z_grows_ = z_grows_ && znorm > run_znorm_;
    }
    run_znorm_ = znorm;
    x_still_ = x_still_ && s.step == 0;
    if (same_ < kStuck) return;
    if (x_still_) stuck_ = Stuck::FixedPoint;
    else if (z_grows_) stuck_ = Stuck::Runaway;
  }
  Stuck stuck() const { return stuck_; }

 private:
  int same_ = 0;
  bool x_still_ = true, z_grows_ = true;
  double run_znorm_ = 0;
  Stuck stuck_ = Stuck::None;
};

/// No progress, two ways, judged at the end of each window of stall_iterations iterates.
/// (1) In 3 consecutive windows the smallest Res of a window is not below the previous
/// window's (a cycle, or a slow divergence). Windows, not the global best: Res may jump up at
/// first and then fall steadily. (2) Out of reach: the best Res has not been improved for
/// kOutOfReach windows' worth of iterations, and at the rate the window minima fell in the last
/// window Res would not get back to the best within maxiter; a slow return that fits in the
/// budget goes on. A window of bit-identical Res is neutral for both: the iteration can sit on
/// such a plateau for thousands of steps while x moves towards the solution, and plateau
/// iterations do not count as iterations without improvement (docs/MEASUREMENTS.md, "The stall
/// rule's windows and the stuck rule").
/// A window whose largest step ‖Δx‖∞ is below the previous window's is no bad window whatever Res
/// did: the iteration still contracts (a box problem's Res rises for hundreds of sweeps while its
/// contact zones form: docs/MEASUREMENTS.md, "The stall rule and a contracting box iteration").
class StallWindows {
 public:
  static constexpr int kOutOfReach = 10;
  /// Iterate k with Res r and step ‖Δx‖∞; `best`: the best Res so far, `since_best` the iterations
  /// without improvement.
  void track(int k, double r, double step, double best, int since_best, const SolveOptions& o) {
    win_min_ = std::min(win_min_, r);
    win_max_ = std::max(win_max_, r);
    win_step_ = std::max(win_step_, step);
    if (++win_count_ < o.stall_iterations) return;
    if (win_max_ != win_min_) {
      const bool contracts = win_step_ < prev_win_step_;
      bad_windows_ = (win_min_ < prev_win_min_ || contracts) ? 0 : bad_windows_ + 1;
      out_of_reach_ = since_best >= double(kOutOfReach) * o.stall_iterations && !reachable(k, best, o);
    }
    prev_win_min_ = win_min_;
    prev_win_step_ = win_step_;
    win_min_ = std::numeric_limits<double>::infinity();
    win_max_ = -win_min_;
    win_step_ = 0;
    win_count_ = 0;
  }
  bool stalled() const { return bad_windows_ >= 3 || out_of_reach_; }
  bool out_of_reach() const { return out_of_reach_; }

 private:
  // Would Res, falling from prev_win_min_ to win_min_ per window, reach the best by maxiter?
  bool reachable(int k, double best, const SolveOptions& o) const {
    if (!(win_min_ < prev_win_min_) || !(best > 0)) return false;
    const double windows = std::log(best / win_min_) / std::log(win_min_ / prev_win_min_);
    return k + windows * o.stall_iterations <= double(o.maxiter);
  }

  int win_count_ = 0, bad_windows_ = 0;
  bool out_of_reach_ = false;
  double win_min_ = std::numeric_limits<double>::infinity(), win_max_ = -win_min_, prev_win_min_ = win_min_;
  double win_step_ = 0, prev_win_step_ = std::numeric_limits<double>::infinity();  // largest ‖Δx‖∞ of a window
};

class Monitor {
 public:
  using Vector = Eigen::VectorXd;
  using clock = std::chrono::steady_clock;

  /// `shift`: the constant obstacle c when the core iterates the shifted LCP in y = z − c (the
  /// callback sees z = y + c), else empty.
  Monitor(const SolveOptions& o, const Callback& callback, const Poll& poll, const Progress& progress,
          const Vector& shift, Result& res, Eigen::Index n)
      : o_(o), callback_(callback), poll_(poll), progress_(o.verbose > 0 ? progress : Progress()), shift_(shift),
        res_(res), best_z_(n), t_start_(clock::now()), last_poll_(t_start_), last_report_(t_start_) {
    res_.status = Status::MaxIterations;
  }

  /// Looks at iterate k with Res r (s.z is z⁽ᵏ⁾); true when the solve must stop, and then
  /// res.status says why. May take s.z as the best iterate (s.z is then stale: the step's
  /// z-update rewrites it).
  bool stop(int k, double r, Iterate& s) {
    if (count_) k = *count_;
    const bool first = k == 0;  // (the loop's first iterate, however numbered: its progress line)
    if (offset_) k += *offset_;
    if (!s.finite) return finish_with(Status::Diverged, k);
    if (!s.zeta_ok) return finish_with(Status::ZetaFailed, k);
    record(k, r);
    stuck_.track(r, last_r_, s, *comm_);
    const bool improved = track_best(k, r, s);
    windows_.track(k, r, s.step, best_, since_best_, o_);
    res_.iterations = k;
    const std::optional<Status> end = verdict(r);
    // The callback sees every iterate that has a Res (those of the history), the last one too;
    // asking to stop at an iterate that ends the solve anyway does not change why it ended.
    const bool asked = callback_ && comm_->any(call_back(k, improved ? best_z_ : s.z, r));
    if (end) return finish_with(*end, k);
    if (asked) return finish_with(Status::CallbackStop, k);
    if (poll_ && ScopedTimer::seconds_since(last_poll_) > 0.05) {
      poll_();
      last_poll_ = clock::now();
    }
    if (progress_ && (first || ScopedTimer::seconds_since(last_report_) >= o_.verbose)) {
      progress_(k, r, best_, seconds(), std::string());
      last_report_ = clock::now();
    }
    if (k >= o_.maxiter) return finish_with(Status::MaxIterations, k);
    return false;
  }

  Result& result() { return res_; }

  /// Number the iterates by `*count` instead of the loop's k (history, callback, maxiter, the
  /// best iterate's number): the outer fixed point numbers them by the Newton steps taken, as
  /// its nit counts them.
  void number_by(const int* count) { count_ = count; }
  /// Number iterate k as *offset + k: a loop whose steps interleave steps counted elsewhere (the semismooth
  /// loop's outer steps), numbered as nit counts them when each iterate is looked at.
  void number_from(const int* offset) { offset_ = offset; }
  /// The processes that own the other rows of s.x and s.z (detail/comm.hpp; serial by default):
  /// the norms the rules read are theirs together, and a callback that asks to stop on one stops all.
  void reduce_with(const Comm& comm) { comm_ = &comm; }

  /// The step ended the solve after its last iterate was looked at (the loop's step.end()).
  void end(const StepEnd& e) {
    res_.status = e.status;
    step_message_ = e.message;
  }

  /// Seconds since the Monitor was made (the start of the iterations).
  double seconds() const { return ScopedTimer::seconds_since(t_start_); }

  /// The returned iterate: the best one (the last when converged), its Res, nit and message.
  /// `z_start` (finite) is returned when no finite Res was ever seen, and also when its Res
  /// `start_residual` is below every iterate's: iterate 0 is the modulus image of the start, not
  /// the start itself, and can be worse (docs/SPEC.md).
  void finish(const Vector& z_start, double start_residual = std::numeric_limits<double>::quiet_NaN()) {
    const bool any = std::isfinite(best_);
    const bool start = res_.status != Status::Converged && start_residual < best_;
    res_.nit = (res_.status == Status::Converged) ? res_.iterations : best_k_;
    res_.z = any && !start ? std::move(best_z_) : z_start;
    res_.residual = start ? start_residual : any ? best_ : std::numeric_limits<double>::quiet_NaN();
    if (start) res_.nit = 0;
    res_.message = step_message_.empty() ? message(start) : step_message_;
    if (progress_) progress_(res_.iterations, res_.residual, res_.residual, seconds(), res_.message);
  }

 private:
  // Converged, diverged or stagnated at this iterate (after record, the stuck rule, track_best, the windows).
  std::optional<Status> verdict(double r) const {
    if (r < o_.tol) return Status::Converged;
    if (!std::isfinite(r) || r > o_.divergence_factor * best_ || x_runaway_) return Status::Diverged;
    if (floor_count_ >= o_.stall_iterations || windows_.stalled() || stuck_.stuck() != StuckRule::Stuck::None)
      return Status::Stagnated;
    return std::nullopt;
  }

  // The status's text, with why and which iterate is returned.
  std::string message(bool start) const {
    std::string m = to_string(res_.status);
    if (x_runaway_) m += " (the modulus vector x grew by more than divergence_factor while Res did not improve)";
    if (res_.status == Status::Stagnated && windows_.out_of_reach())
      m += " (the best Res was not improved in " + std::to_string(since_best_) +
           " iterations, and at the rate Res fell in the last " + std::to_string(o_.stall_iterations) +
           " it would not get back to it within maxiter)";
    if (res_.status == Status::Stagnated && stuck_.stuck() == StuckRule::Stuck::FixedPoint)
      m += " (the iterate no longer changes: a fixed point of the iteration that is not a solution; Res was "
           "bit-identical for " + std::to_string(StuckRule::kStuck) + " iterations)";
    if (res_.status == Status::Stagnated && stuck_.stuck() == StuckRule::Stuck::Runaway)
      m += " (Res was bit-identical for " + std::to_string(StuckRule::kStuck) + " iterations while max|z| kept growing: the "
           "iterate runs away along a direction Res does not see, e.g. on a zero row of A with q_i < 0)";
    if (start)
      m += "; returning the initial guess z0 (no iterate had a lower Res)";
    else if (res_.status != Status::Converged && res_.status != Status::ZetaFailed)
      m += "; returning the best iterate (iteration " + std::to_string(best_k_) + ")";
    if (res_.status == Status::ZetaFailed) m += " at iteration " + std::to_string(res_.iterations);
    return m;
  }
  bool finish_with(Status s, int k) {
    res_.status = s;
    res_.iterations = k;
    return true;
  }
  void record(int k, double r) {
    if (!o_.record_history) return;
    res_.history_iteration.push_back(k);
    res_.history_seconds.push_back(seconds());
    res_.history_residual.push_back(r);
  }
  // The best iterate is kept by swapping buffers, not copying. The rounding floor: Res does not
  // improve while the steps are at rounding level (tol below what floating point reaches).
  bool track_best(int k, double r, Iterate& s) {
    if (k == 0) x_scale_ = comm_->inf_norm(s.x);
    if (r < best_) {
      best_ = r;
      best_k_ = k;
      x_ref_k_ = -1;
      best_z_.swap(s.z);
      floor_count_ = 0;
      since_best_ = 0;
      last_r_ = r;
      return true;
    }
    if (r != last_r_) ++since_best_;  // iterations on a plateau of bit-identical Res do not count
    last_r_ = r;
    if (k > 0) {
      const double xnorm = comm_->inf_norm(s.x);
      track_x(k, xnorm);
      floor_count_ = (s.step <= 1e-8 * (xnorm > 0 ? xnorm : 1.0)) ? floor_count_ + 1 : 0;
    }
    return false;
  }
  // A runaway modulus vector: x grows without bound while Res does not improve (Res can stay
  // exactly constant while x triples every step, until it overflows). The scale of x is taken
  // at x⁽⁰⁾ and at the first iterate after each best one; xnorm is what the rounding-floor rule
  // computes anyway, so the check costs nothing on the way to a new best.
  void track_x(int k, double xnorm) {
    if (x_ref_k_ < 0) {
      x_ref_k_ = k;
      x_ref_ = std::max(x_scale_, xnorm);
    }
    if (!(xnorm <= o_.divergence_factor * x_ref_) || !std::isfinite(xnorm)) x_runaway_ = true;
  }
  bool call_back(int k, const Vector& z, double r) const {
    return shift_.size() ? callback_(k, z + shift_, r) : callback_(k, z, r);
  }

  const SolveOptions& o_;
  const Callback& callback_;
  const Poll& poll_;
  const Progress progress_;
  const Vector& shift_;
  Result& res_;
  std::string step_message_;
  Vector best_z_;
  StuckRule stuck_;
  StallWindows windows_;
  double best_ = std::numeric_limits<double>::infinity();
  int best_k_ = 0, floor_count_ = 0, since_best_ = 0;
  bool x_runaway_ = false;
  int x_ref_k_ = -1;
  const int* count_ = nullptr;
  const int* offset_ = nullptr;
  const Comm* comm_ = &serial_comm();
  double x_scale_ = 0, x_ref_ = 0;
  double last_r_ = std::numeric_limits<double>::quiet_NaN();
  clock::time_point t_start_, last_poll_, last_report_;
};

}  // namespace nrmicp::detail
