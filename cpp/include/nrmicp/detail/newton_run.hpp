// nrmicp — one solve of the Newton member (nrmicp::Newton, newton.hpp): the Newton loop on one
// level, the levels of nested iteration, and the four strategies by ζ with the tally of their
// statistics across levels and outer steps.
//   newton_loop              one level: a plain step (detail/newton_step.hpp), globalized
//                            (detail/globalization.hpp), in the family's loop with its Monitor
//   NewtonRun::solve_obstacle   ζ none or constant: the (shifted) LCP, nested coarse to fine
//                            (ObstacleSolver, which also solves the other strategies' obstacle problems)
//   NewtonRun::solve_affine     ζ = Bz + c: Newton on the full system, from the obstacle problem
//   NewtonRun::solve_outer_fixed_point  a callable ζ: z ← S(ζ(z)) (detail/outer_fixed_point.hpp)
//   NewtonRun::solve_semismooth a callable ζ with its Jacobian: semismooth Newton on the ICP
#pragma once

#include "../options.hpp"
#include "../result.hpp"
#include "../zeta.hpp"
#include "active_set.hpp"
#include "box.hpp"
#include "globalization.hpp"
#include "multigrid.hpp"
#include "newton_level.hpp"
#include "newton_step.hpp"
#include "outer_fixed_point.hpp"
#include "residual.hpp"
#include "semismooth.hpp"
#include "stopping.hpp"
#include "timer.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace nrmicp::detail {

/// What the Newton loop on one level did, as a Result (z: the best iterate; its Res, status,
/// message and history; newton.linear_solves, .inner_iterations, .fallback_sweeps), and what
/// nested iteration and the outer fixed point take on from it.
struct LevelOutcome : Result {
  int steps = 0;               ///< Newton steps (the Monitor's nit is the best iterate's index)
  bool settled = false;        ///< the active set repeated: z solves the problem to rounding
  std::vector<char> inactive;  ///< the inactive set of z's last step (empty if no step was taken)
  bool jacobian_poor = false;  ///< ζ's Jacobian did not deliver (JacobianCheck): the loop gave up on it
};

/// The Newton member on one level: the plain step `plain` (at its start), globalized, in the
/// family's loop (detail::loop, solver.hpp) with the family's Monitor.
/// `z_start`: the iterate plain started from (returned if no iterate has a finite Res).
template <typename Plain>
LevelOutcome newton_loop(Plain& plain, const NewtonControl& ctl, const Eigen::VectorXd& z_start) {
  static const Eigen::VectorXd no_shift;
  SolveOptions mo = ctl.solve;
  mo.maxiter = std::numeric_limits<int>::max();  // Newton steps are the step's to count (ctl.solve.maxiter)
  LevelOutcome o;
  Monitor monitor(mo, ctl.callback, ctl.poll, ctl.progress, ctl.shift ? *ctl.shift : no_shift, o, plain.size());
  Iterate s;
  monitor.reduce_with(plain.comm());
  if (ctl.number_from) monitor.number_from(ctl.number_from);
  Globalized<Plain> step(plain, ctl, s);
  loop(step, s, monitor);
  monitor.finish(z_start);
  o.steps = plain.steps();
  o.settled = step.settled();
  o.inactive = step.inactive();
  o.jacobian_poor = step.jacobian_poor();
  o.newton.fallback_sweeps = step.sweeps();
  o.newton.linear_solves = plain.solves();
  o.newton.inner_iterations = plain.inner_iterations();
  return o;
}

/// The (shifted) LCP (B null) or the affine ICP ζ(z) = Bz + c on `level`, with the reduced system
/// `K` (analysed for this problem), from z.
/// `box` (B null): the LCP's bounds lo ≤ z ≤ hi (null or empty: z ≥ 0).
template <typename MatrixType>
LevelOutcome newton_loop(NewtonLevel<MatrixType>& level, typename Engine<MatrixType>::System& K,
                         const Eigen::VectorXd& q, const typename NewtonLevel<MatrixType>::RowMatrix* B,
                         const Eigen::VectorXd* c, const Eigen::VectorXd& z, const NewtonControl& ctl,
                         const Box* box = nullptr) {
  NewtonStep<MatrixType, FixedLinearization<MatrixType>> plain(
      level, {level, K, q, B, c, box && !box->empty() ? box : nullptr}, z);
  return newton_loop(plain, ctl, z);
}

/// The levels of nested iteration (built by nrmicp::Newton): the finest on A, the coarser ones on
/// the Galerkin operators of `hierarchy`.
template <typename MatrixType>
struct NewtonLevels {
  using StorageIndex = typename MatrixType::StorageIndex;
  using RowMatrix = typename Engine<MatrixType>::Coarse;
  const MatrixType& A;
  std::vector<typename Engine<MatrixType>::Level> hierarchy;  ///< below the finest: P, R = Pᵀ, A = R A_finer P
  std::unique_ptr<NewtonLevel<MatrixType>> finest;
  std::vector<std::unique_ptr<NewtonLevel<RowMatrix>>> coarse;  ///< coarse[l] on hierarchy[l].A
  int count() const { return 1 + static_cast<int>(coarse.size()); }
};

/// What a solve gathers over levels and outer steps (Result::newton, nit, iterations, the
/// finest level's history), and the Result it returns.
template <typename MatrixType>
class NewtonTally {
 public:
  using Vector = Eigen::VectorXd;

  NewtonTally(const MatrixType& A, int levels) : A_(A) {
    tally_.newton.level_steps.assign(levels, 0);
    tally_.newton.level_seconds.assign(levels, 0.0);
  }

  int nit() const { return tally_.nit; }
  /// The phases' seconds of this solve (the levels record into it: NewtonLevel::record_into).
  Timings& timings() { return tally_.timings; }
  /// nit, for a Monitor that numbers its iterates by it (Monitor::number_by).
  const int* nit_counter() const { return &tally_.nit; }
  int fallback_sweeps() const { return tally_.newton.fallback_sweeps; }
  void outer_step() { ++tally_.newton.outer_iterations; }
  /// The solve left Newton with ζ's Jacobian for the outer fixed point (path "newton+outer").
  void switch_to_outer() { outer_after_newton_ = true; }
  /// A count of Result::counters.
  void count(const std::string& key, long long k) { tally_.counters[key] += k; }
  /// Sweeps of the fallback member outside a level's loop (the outer fixed point's).
  void sweeps(int k) {
    tally_.newton.fallback_sweeps += k;
    tally_.iterations += k;
  }
  /// The history and counters of the outer fixed point's Monitor (numbered by nit already), after the Newton steps' if any.
  void take_history(const Result& from) {
    for (const auto& [key, count] : from.counters) tally_.counters[key] += count;
    auto append = [](auto& to, const auto& v) { to.insert(to.end(), v.begin(), v.end()); };
    append(tally_.history_iteration, from.history_iteration);
    append(tally_.history_seconds, from.history_seconds);
    append(tally_.history_residual, from.history_residual);
  }

  /// A level's loop into the tally (the finest level's history too, numbered by its Monitor: NewtonControl::number_from).
  void absorb(const LevelOutcome& out, int level, double seconds) {
    tally_.newton.level_steps[level] += out.steps;
    tally_.newton.level_seconds[level] += seconds;
    tally_.newton.linear_solves += out.newton.linear_solves;
    tally_.newton.inner_iterations += out.newton.inner_iterations;
    if (level != 0) return;
    tally_.newton.fallback_sweeps += out.newton.fallback_sweeps;
    for (std::size_t i = 0; i < out.history_iteration.size(); ++i) {
      tally_.history_iteration.push_back(out.history_iteration[i]);  // (numbered as nit counts: finest_control)
      tally_.history_seconds.push_back(out.history_seconds[i]);
      tally_.history_residual.push_back(out.history_residual[i]);
    }
    tally_.nit += out.steps;
    tally_.iterations += out.steps + out.newton.fallback_sweeps;
  }

  /// ζ failed at the start z: ZETA_FAILED.
  Result zeta_failed(const Vector& z, const Vector& q) const {
    return finish(z, std::numeric_limits<double>::quiet_NaN(), Status::ZetaFailed, to_string(Status::ZetaFailed), q);
  }
  /// The result of a finest-level loop: z (original variables), w, status and message.
  Result finish(const LevelOutcome& out, const Vector& z, const Vector& q) const {
    return finish(z, out.residual, out.status, out.message, q);
  }
  Result finish(const Vector& z, double residual, Status status, std::string message, const Vector& q) const {
    Result r = tally_;
    r.z = z;
    {
      ScopedTimer t(r.timings.spmv);
      multiply(A_, z, r.w);
      r.w += q;
    }
    r.residual = residual;
    r.status = status;
    r.message = std::move(message);
    r.newton.path = outer_after_newton_ ? "newton+outer"
                    : r.newton.fallback_sweeps ? (r.nit ? "newton+fallback" : "fallback") : "newton";
    refuse_overflow(r);
    return r;
  }

 private:
  const MatrixType& A_;
  Result tally_;
  bool outer_after_newton_ = false;
};

/// The Newton member's measured constants, one definition: NewtonRun uses them, and the
/// distributed member (python/nrmicp/distributed.py) reads them through the binding.
struct NewtonTuning {
  /// Newton steps per coarse level: until its active set settles (at most this many), since a
  /// cut-short coarse solve leaves a band of wrong active set that Res does not show
  /// (docs/MEASUREMENTS.md, "`NewtonTuning::coarse_maxiter` = 100").
  static constexpr int coarse_maxiter = 100;
  /// The inner solves on the coarse levels stop at this fraction of the iterate's Res: a start
  /// needs no more; not on the finest level (docs/MEASUREMENTS.md, "`NewtonTuning::coarse_forcing` = 0.1").
  static constexpr double coarse_forcing = 0.1;
  /// A coarse level's loosely solved set that repeats settles once Res is below this fraction of
  /// the level's start (the accuracy of the finest level's first step); before, the set is solved
  /// to a tenth of that and the loop goes on (NewtonControl::repeat_trust): a start whose Res is not
  /// the contact's (a coefficient jump's) would settle after one loose step on a wrong set, level
  /// after level (docs/MEASUREMENTS.md, "`NewtonTuning::coarse_repeat_trust` = 1e-4").
  static constexpr double coarse_repeat_trust = 1e-4;
  /// The first finest-level step from a nested start stops its inner solve at this fraction of the
  /// start's Res: that step's active set is the prolongation's guess, wrong along the free boundary,
  /// and a solve to tol / 10 is spent on it (docs/MEASUREMENTS.md, "`NewtonTuning::nested_first_forcing` = 1e-4").
  static constexpr double nested_first_forcing = 1e-4;
  /// The later finest-level steps from a nested start stop their inner solves at this fraction of
  /// the iterate's Res while their active set is new; a set that repeats is solved to tol / 10
  /// (NewtonControl::repeat_trust; docs/MEASUREMENTS.md, "`NewtonTuning::nested_forcing` = 0.1").
  static constexpr double nested_forcing = 0.1;
  /// A user's start replaces the nested one when its Res is below this fraction of the cold start's
  /// (y = 0): a time step's previous solution lies well below it, a guess no better near it or
  /// above (docs/MEASUREMENTS.md, "Warm starts with a hierarchy").
  static constexpr double warm_start_fraction = 0.5;
  /// Finest steps a user's start gets before the nested start takes over: what a time step from
  /// the last one takes (docs/MEASUREMENTS.md, "Warm starts with a hierarchy").
  static constexpr int warm_steps = 6;
  /// The outer fixed point on a callable ζ without its Jacobian (detail::OuterFixedPoint): Anderson's
  /// memory on the outer map z ↦ S(ζ(z)) (docs/MEASUREMENTS.md, "The outer fixed point, accelerated").
  static constexpr int outer_memory = 3;
  /// The semismooth loop's outer steps (solve_semismooth) are used while their obstacle solve's Res is
  /// below this fraction of the ICP's Res where it started (else the obstacle problem was not solved:
  /// an LCP of a matrix that is no P-matrix may have no solution the steps find).
  static constexpr double outer_trust = 0.1;
};

/// The bounds ψ ≤ z ≤ u of an obstacle problem as the box problem in y = z − s (ShiftedBounds, the
/// Newton member's: a problem with bounds is not shifted), with the q of that problem, q + A s.
template <typename MatrixType>
struct ObstacleFrame {
  using Vector = Eigen::VectorXd;
  ShiftedBounds bounds;
  Vector shifted_q;  ///< q + A s (empty when not shifted: the problem's q itself)

  ObstacleFrame(const MatrixType& A, const Vector& q, const Vector& psi, const Vector& upper, const Comm& comm,
                Timings& tm)
      : bounds(psi, upper, false, comm) {
    if (!bounds.shifted()) return;
    ScopedTimer t(tm.spmv);
    shifted_q = q;
    multiply_add(A, bounds.s, shifted_q);
  }
  const Vector& q(const Vector& q0) const { return bounds.shifted() ? shifted_q : q0; }
  const Box& box() const { return bounds.box; }
  const Vector& s() const { return bounds.s; }
};

/// An obstacle problem of a QVI, its bounds those at an outer step's z: the nested start takes
/// them afresh at each level (NestedStart::refreshed). `at(z, lower, upper)`: the bounds at z, the
/// lower one capped by the upper where they cross, the upper one unchanged unless it is implicit
/// (false: ζ or u failed there). `lower`, `upper`: the bounds the solve was given, then those of the
/// finest level; `z`: where those were taken (z_f); `moved`: whether they changed on the way.
struct RefreshedBounds {
  using Vector = Eigen::VectorXd;
  std::function<bool(const Vector& z, Vector& lower, Vector& upper)> at;
  Vector lower, upper, z;
  bool moved = false;
};

/// The nested start of an obstacle problem: Newton on each coarse level to a settled active set,
/// coarse to fine, each solution prolongated (Box::prolongate) as the next level's start.
template <typename MatrixType>
class NestedStart {
 public:
  using Vector = Eigen::VectorXd;
  using Frame = ObstacleFrame<MatrixType>;

  NestedStart(const NewtonLevels<MatrixType>& levels, NewtonTally<MatrixType>& tally) : levels_(levels), tally_(tally) {}

  /// The start for the box problem `box` of LCP(q_shift, A) (empty: y ≥ 0), its bounds frozen.
  Vector frozen(const Vector& q_shift, const Box& box) {
    levels_.finest->restore_hierarchy();  // the coarse levels solve on the A_l its V-cycle freed
    const Chain c = chain(q_shift, box);
    Vector y = Vector::Zero(levels_.coarse.back()->size());
    for (std::size_t l = levels_.coarse.size(); l >= 1; --l) y = solve_level(l, c, y);
    return y;
  }

  /// The start of a QVI's obstacle problem (bounds ψ = `psi`, `upper` taken at the outer step's z):
  /// the coarsest level on them, each finer one on the bounds at z_f, the finest prolongation of the
  /// coarser answer (fresh.at: one evaluation of ζ a level), from that answer with each row's state
  /// kept (Box::carry: a row at a bound moves with it, so the active set carries over). A bound frozen
  /// at the outer step's z would leave the free boundary where ζ(z) puts it, and the finest solve peel
  /// the rest a grid layer a step; so would a start that keeps z where the bound moved (docs/MEASUREMENTS.md,
  /// "A nested start that re-takes ζ a level", "The refreshed start keeps the active set").
  /// `f` becomes the finest level's frame; fresh says where it was taken. Where the bounds do not
  /// change, nothing else does; after ζ or u failed, the levels keep the last bounds.
  Vector refreshed(const Vector& q, const Vector& psi, const Vector& upper, Frame& f, RefreshedBounds& fresh) {
    levels_.finest->restore_hierarchy();
    fresh.lower = psi;
    fresh.upper = upper;
    Chain c = chain(f.q(q), f.box());
    Vector y = Vector::Zero(levels_.coarse.back()->size()), lower, up;
    bool failed = false;
    for (std::size_t l = levels_.coarse.size(); l >= 1; --l) {
      y = solve_level(l, c, y);
      if (failed) continue;
      Vector z = to_finest(c, y, l - 1, f.s());
      if ((failed = !comm().all(fresh.at(z, lower, up)))) continue;
      fresh.z.swap(z);
      if (comm().all(lower == fresh.lower && up == fresh.upper)) continue;
      f = Frame(levels_.A, q, lower, up, comm(), tally_.timings());
      fresh.lower.swap(lower);
      fresh.upper.swap(up);
      fresh.moved = true;
      const Box old = std::move(c.boxes[l - 1]);
      c = chain(f.q(q), f.box());
      c.boxes[l - 1].carry(old, y);
    }
    return y;
  }

 private:
  /// Each level's q and box: restricted (R q) resp. injected (Box::coarse) from the finer level's.
  struct Chain {
    std::vector<Vector> qs;
    std::vector<Box> boxes;  // empty for the LCP
  };
  Chain chain(const Vector& q_shift, const Box& box) const {
    const std::size_t L = levels_.coarse.size();
    Chain c{std::vector<Vector>(L + 1), std::vector<Box>(L + 1)};
    c.qs[0] = q_shift;
    c.boxes[0] = box;
    for (std::size_t l = 0; l < L; ++l) {
      multiply(levels_.hierarchy[l].R, c.qs[l], c.qs[l + 1]);
      c.boxes[l + 1] = c.boxes[l].coarse(levels_.hierarchy[l].P);
    }
    return c;
  }
  /// Coarse level l's problem from y, to a settled active set; its answer prolongated to level l − 1.
  Vector solve_level(std::size_t l, const Chain& c, const Vector& y) {
    NewtonControl ctl;
    ctl.solve.maxiter = NewtonTuning::coarse_maxiter;
    ctl.forcing = ctl.first_forcing = NewtonTuning::coarse_forcing;
    ctl.repeat_trust = NewtonTuning::coarse_repeat_trust;
    ctl.sweep_budget = 1000;
    const auto t0 = std::chrono::steady_clock::now();
    auto& level = *levels_.coarse[l - 1];
    const auto out = newton_loop(level, level.lcp_system(), c.qs[l], nullptr, nullptr, y, ctl, &c.boxes[l]);
    tally_.absorb(out, static_cast<int>(l), ScopedTimer::seconds_since(t0));
    Vector next = c.boxes[l - 1].prolongate(levels_.hierarchy[l - 1].P, c.boxes[l], out.z);
    level.release();
    return next;
  }
  /// z on the finest level of the start y of level k: prolongated level by level, y + s there.
  Vector to_finest(const Chain& c, Vector y, std::size_t k, const Vector& s) const {
    for (; k > 0; --k) y = c.boxes[k - 1].prolongate(levels_.hierarchy[k - 1].P, c.boxes[k], y);
    if (s.size()) y += s;
    return y;
  }
  /// The reductions over every process (the finest level's engine).
  const Comm& comm() const { return levels_.finest->comm(); }

  const NewtonLevels<MatrixType>& levels_;
  NewtonTally<MatrixType>& tally_;
};

/// One solve's obstacle problems ψ ≤ z (≤ upper): ζ none or constant, and the inner solves of the
/// strategies by ζ. The finest level's loop from the nested start, the user's start or the last
/// inner solve's active set; their statistics go to the solve's tally.
template <typename MatrixType>
class ObstacleSolver {
 public:
  using Vector = Eigen::VectorXd;
  using Frame = ObstacleFrame<MatrixType>;

  /// `upper`: the upper bounds of z (empty: none).
  ObstacleSolver(const NewtonLevels<MatrixType>& levels, const Options& o, const Hooks& hooks, const Vector& upper,
                 NewtonTally<MatrixType>& tally)
      : levels_(levels), o_(o), hooks_(hooks), upper_(upper), tally_(tally) {}

  /// The obstacle problem z ≥ ψ as LCP(q + Aψ, A) in y = z − ψ; an empty ψ is ψ = 0, the LCP itself
  /// (no shifted copy of q, no vector of zeros: two n-vectors of the finest level's peak memory).
  /// `nest`: start from the nested solution. `report`: this is the problem being solved (history,
  /// callback), not an inner one. `set` (optional): the inactive set to start from, replaced by the final one.
  /// z ≤ upper too; ψ and upper may be −∞ resp. +∞ in places (ShiftedBounds: the box problem in y).
  /// tol, maxiter < 0: the solve's. `upper` (optional): this problem's upper bounds in place of the
  /// solve's (an implicit upper bound frozen at an outer step's z). `fresh` (optional): the bounds are
  /// a QVI's, taken afresh at each level of the nested start (NestedStart::refreshed), which then
  /// says where the finest level's were taken; the answer is that problem's.
  Result solve(const Vector& q, const Vector& psi, const Vector* z0, bool nest, double tol, int maxiter, bool report,
               std::vector<char>* set, const Vector* upper = nullptr, RefreshedBounds* fresh = nullptr) {
    const Vector& u = upper ? *upper : upper_;
    Frame f(levels_.A, q, psi, u, comm(), tally_.timings());
    Vector y0 = !z0 ? Vector::Zero(q.size()) : f.bounds.shifted() ? Vector(*z0 - f.s()) : Vector(*z0);
    f.box().project(y0);
    const bool nested = nest && !levels_.coarse.empty();
    const double level_tol = tol >= 0 ? tol : o_.tol;
    int budget = maxiter >= 0 ? maxiter : o_.maxiter;
    // The user's start, where it is closer than a cold one, replaces the nested start for a bounded
    // try (the hierarchy then serves the inner solves): a time step's previous solution is a closer
    // guess than the coarse levels'. A start no closer, or zeros (x0's default), nests; so does one
    // whose active set is far off although its Res is small (another problem's solution: it peels),
    // after warm_steps (docs/MEASUREMENTS.md, "Warm starts with a hierarchy").
    std::optional<LevelOutcome> tried;
    if (nested && report && z0 && !comm().all(z0->isZero(0.0)) && closer_than_cold(f.q(q), y0, f.box())) {
      const auto t0 = std::chrono::steady_clock::now();
      tried = finest_lcp(f.q(q), y0, guess_control(f.s(), level_tol, std::min(budget, NewtonTuning::warm_steps), true), f.box());
      if (tried->status != Status::MaxIterations || budget <= NewtonTuning::warm_steps)
        return finish_obstacle(*tried, *tried, f.s(), q, t0);
      tally_.absorb(*tried, 0, ScopedTimer::seconds_since(t0));
      budget -= tried->steps;
    }
    if (nested) y0 = fresh ? start_.refreshed(q, psi, u, f, *fresh) : start_.frozen(f.q(q), f.box());
    const auto t0 = std::chrono::steady_clock::now();
    const Vector& s = f.s();  // (the finest level's frame: the refreshed start's bounds)
    const auto control = nested ? guess_control(s, level_tol, budget, report) : finest_control(s, level_tol, budget, report);
    const auto out = set && !set->empty() ? from_set(f.q(q), y0, *set, control, f.box()) : finest_lcp(f.q(q), y0, control, f.box());
    if (set && !out.inactive.empty()) *set = out.inactive;
    // maxiter spent on both: the warm try's iterate when the nested run ended no better
    const bool keep_try = tried && out.status != Status::Converged && tried->residual < out.residual;
    return finish_obstacle(out, keep_try ? *tried : out, s, q, t0);
  }

  /// The control of a finest-level loop; `report`: this loop is the problem being solved.
  NewtonControl finest_control(const Vector& shift, double tol, int maxiter, bool report) const {
    NewtonControl c;
    c.solve = o_;
    c.solve.tol = tol;
    c.settled_tol = o_.tol;
    c.solve.maxiter = maxiter;
    c.solve.record_history = report && o_.record_history;
    c.solve.verbose = report ? o_.verbose : 0;
    c.sweep_budget = o_.maxiter;
    if (report) {  // its iterates numbered as nit counts them when each is looked at (history, callback, progress)
      c.callback = hooks_.callback;
      c.number_from = tally_.nit_counter();
      c.progress = hooks_.progress;
    }
    c.shift = &shift;
    c.poll = hooks_.poll;
    return c;
  }

 private:
  /// The reductions over every process (the finest level's engine).
  const Comm& comm() const { return levels_.finest->comm(); }

  /// The obstacle problem's result from the finest level's `answer` (z = y + ψ), after the loop `run`
  /// (from t0) is tallied.
  Result finish_obstacle(const LevelOutcome& run, const LevelOutcome& answer, const Vector& s, const Vector& q,
                         std::chrono::steady_clock::time_point t0) {
    tally_.absorb(run, 0, ScopedTimer::seconds_since(t0));
    return s.size() > 0 ? tally_.finish(answer, answer.z + s, q) : tally_.finish(answer, answer.z, q);
  }

  /// The control of a finest-level loop from a guessed start (nested or the user's): the sets of its
  /// steps are guesses until one repeats, solved loosely till then.
  NewtonControl guess_control(const Vector& psi, double tol, int maxiter, bool report) const {
    auto c = finest_control(psi, tol, maxiter, report);
    c.first_forcing = NewtonTuning::nested_first_forcing;
    c.forcing = NewtonTuning::nested_forcing;
    c.repeat_trust = 0;
    return c;
  }

  /// Res(y) < warm_start_fraction × Res(0) on LCP(q_shift, A): y is a guess worth more than a cold start.
  bool closer_than_cold(const Vector& q_shift, const Vector& y, const Box& box) {
    ScopedTimer t(tally_.timings().spmv);
    Vector w = q_shift;
    multiply_add(levels_.A, y, w);
    const double cold = box.empty() ? comm().stable_norm(q_shift.cwiseMin(0.0))
                                    : box.residual(q_shift, Vector::Zero(y.size()), comm());
    return box.residual(w, y, comm()) < NewtonTuning::warm_start_fraction * cold;
  }

  LevelOutcome finest_lcp(const Vector& q_shift, const Vector& y0, const NewtonControl& control, const Box& box) {
    return newton_loop(*levels_.finest, levels_.finest->lcp_system(), q_shift, nullptr, nullptr, y0, control, &box);
  }
  /// From the inactive set `set` of the last inner solve: a guess, tried without fallback; when its
  /// steps are rejected the loop is rerun from y0 on y0's own active set, as without a guess
  /// (docs/MEASUREMENTS.md, "The outer fixed point's inner solves").
  LevelOutcome from_set(const Vector& q_shift, const Vector& y0, const std::vector<char>& set, NewtonControl control,
                        const Box& box) {
    auto guess = control;
    guess.start_set = set;
    guess.sweep_budget = 0;
    auto tried = finest_lcp(q_shift, y0, guess, box);
    if (tried.settled || tried.status != Status::Stagnated || tried.steps >= control.solve.maxiter) return tried;
    tally_.absorb(tried, 0, 0.0);
    control.solve.maxiter -= tried.steps;
    return finest_lcp(q_shift, y0, control, box);
  }

  const NewtonLevels<MatrixType>& levels_;
  const Options& o_;
  const Hooks& hooks_;
  const Vector& upper_;
  NewtonTally<MatrixType>& tally_;
  NestedStart<MatrixType> start_{levels_, tally_};
};

/// A loop's message whose "returning the best iterate (iteration k)" is the solve's start instead.
inline std::string start_returned(std::string message) {
  const std::string best = "returning the best iterate", start = "returning the start: no iterate had a lower Res";
  const std::size_t at = message.find(best), end = at == std::string::npos ? at : message.find(')', at);
  if (at == std::string::npos) return message + "; " + start;
  return message.replace(at, (end == std::string::npos ? at + best.size() : end + 1) - at, start);
}

/// One solve: the strategies by ζ, and the statistics they gather over levels and outer steps.
template <typename MatrixType>
class NewtonRun {
 public:
  using StorageIndex = typename MatrixType::StorageIndex;
  using Vector = Eigen::VectorXd;
  using Z = Zeta<StorageIndex>;

  /// `nest`: start from the nested coarse-to-fine solution (solve_obstacle may try the user's z0 first).
  /// `upper`: the upper bounds of z (empty: none; solve_obstacle only).
  NewtonRun(const NewtonLevels<MatrixType>& levels, const Options& o, const Hooks& hooks, bool nest,
            const Vector& upper)  // (held by reference: no temporary default)
      : levels_(levels), o_(o), hooks_(hooks), nest_(nest), upper_(upper), tally_(levels.A, levels.count()),
        obstacle_(levels, o, hooks, upper, tally_) {
    record_into(&tally_.timings());
  }
  ~NewtonRun() { record_into(nullptr); }
  NewtonRun(const NewtonRun&) = delete;
  NewtonRun& operator=(const NewtonRun&) = delete;

  /// The obstacle problem z ≥ ψ (ObstacleSolver::solve; tol, maxiter < 0: the solve's).
  Result solve_obstacle(const Vector& q, const Vector& psi, const Vector* z0, bool nest, double tol = -1,
                        int maxiter = -1, bool report = true, std::vector<char>* set = nullptr,
                        const Vector* upper = nullptr, RefreshedBounds* fresh = nullptr) {
    return obstacle_.solve(q, psi, z0, nest, tol, maxiter, report, set, upper, fresh);
  }

  /// ζ(z) = Bz + c: Newton on the full system, from the obstacle problem with ψ = ζ(z0) (or
  /// from z0 itself when it is given and there is no nesting).
  Result solve_affine(const Vector& q, const Z& zeta, const Vector* z0) {
    const Eigen::Index n = q.size();
    Vector psi(n);
    levels_.finest->eval_zeta(zeta, z0 ? *z0 : Vector::Zero(n), psi);
    const Vector start = (z0 && !nest_) ? *z0 : solve_obstacle(q, psi, z0, nest_, 0.0, std::min(start_maxiter, o_.maxiter), false).z;
    const auto t0 = std::chrono::steady_clock::now();
    auto K = levels_.finest->affine_system(zeta.B(), &Timings::setup);  // analysed once for the solve
    const Vector& c = zeta.c();
    const auto out = newton_loop(*levels_.finest, *K, q, &zeta.B(), &c, start,
                                 obstacle_.finest_control(Vector::Zero(n), o_.tol, o_.maxiter, true));
    tally_.absorb(out, 0, ScopedTimer::seconds_since(t0));
    return tally_.finish(out, out.z, q);
  }

  /// A callable ζ, or bounds that depend on z (an affine ζ with an upper bound, an implicit upper
  /// bound): the outer fixed point z ← S(ζ(z), u(z)) as a step of the family's loop, its iterates
  /// numbered by the Newton steps taken (nit). Bounds that cross at the answer are reported in its
  /// message (Outer::crossing).
  Result solve_outer_fixed_point(const Vector& q, const Z& zeta, const Vector* z0) {
    const Eigen::Index n = q.size();
    const Vector z_start = z0 ? *z0 : Vector::Zero(n);
    Outer outer{*this, q, zeta, {}, Vector(n)};
    Iterate s;
    OuterFixedPoint<Outer> step(outer, z_start, z0 != nullptr, s, NewtonTuning::outer_memory);
    Result out;
    static const Vector no_shift;
    Monitor monitor(o_, hooks_.callback, hooks_.poll, hooks_.progress, no_shift, out, n);
    monitor.number_by(tally_.nit_counter());
    monitor.reduce_with(comm());
    loop(step, s, monitor);
    monitor.finish(z_start);
    tally_.take_history(out);
    if (out.status == Status::ZetaFailed && outer.upper_failed)
      out.message += "; upper(z) failed or returned NaN or -inf";
    else if (out.status != Status::Converged && zeta.bounded())
      out.message += outer.crossing(out.z);
    return tally_.finish(out.z, out.residual, out.status, std::move(out.message), q);
  }

  /// A callable ζ with its Jacobian J: semismooth Newton on the whole ICP, each step the affine
  /// step of the linearization ζ(z) + J(v − z) (detail::SemismoothLinearization) on the active set
  /// of z's outer step, followed by an outer step from its result; Res is the ICP's. Start as for
  /// an affine ζ. Newton steps and fallback sweeps of the start count against maxiter.
  ///
  /// The outer steps z ↦ S(ζ(z)) (obstacle solves, nested at the start, then warm: no peeling) place
  /// the free boundary; the Newton step corrects the coupling through ζ. A Newton step on a set it
  /// picks itself (x ≥ 0 at z) peels the free boundary a layer a step, with Res h⁻²-large between
  /// (docs/MEASUREMENTS.md, "Matrix-free Newton steps"): its error is small, its Res is not, and the
  /// outer step after it brings Res down to the error's level. A step whose Res does not fall gives
  /// way to the outer step from the best iterate (the fallback; NewtonControl::outer_steps).
  Result solve_semismooth(const Vector& q, const Z& zeta, const Vector* z0) {
    using Step = NewtonStep<MatrixType, SemismoothLinearization<MatrixType>>;
    const Eigen::Index n = q.size();
    Vector psi(n);
    const Vector z_start = z0 ? *z0 : Vector::Zero(n);
    if (!levels_.finest->eval_zeta(zeta, z_start, psi)) return tally_.zeta_failed(z_start, q);
    outer_z_.resize(0), outer_set_.clear(), step_set_.clear();  // (a new run's outer-step state)
    outer_ok_ = outer_mode_ = true;
    if (!(z0 && !nest_))  // (a given start keeps the frozen nest: its bounds are the better guess than a coarse answer's)
      outer_solve(q, psi, z0, nest_, std::min(start_maxiter, o_.maxiter), z0 ? RefreshedBounds{} : zeta_bounds(zeta));
    const Vector start = (z0 && !nest_) ? *z0 : outer_z_;
    const auto t0 = std::chrono::steady_clock::now();
    SemismoothRecord record;
    SemismoothLinearization<MatrixType> lin(*levels_.finest, q, zeta, record);
    // A step's set is its outer step's, unless that repeats the last step's set: on it the step would
    // return to the same z⁺ (exactly so for an affine ζ), a cycle when the set is wrong (a matrix that is
    // no M-matrix); the test x ≥ 0 at z picks that step's set instead.
    lin.predict = [this, &q](const Vector& z, const Vector& zeta_z, std::vector<char>& inactive) {
      if (outer_mode_ && !is_outer(z) && !outer_step(q, zeta_z, z)) outer_mode_ = false;
      const bool use = outer_mode_ && !comm().all(outer_set_ == step_set_);
      step_set_ = use ? outer_set_ : std::vector<char>();
      if (use) inactive = outer_set_;
      return use;
    };
    lin.project = [this, &q](Vector& z, const Vector& zeta_z) {
      if (!outer_mode_) return;
      if (outer_step(q, zeta_z, z)) z = outer_z_;
      else outer_mode_ = false;
    };
    // the fallback from z: its outer step, where outer steps solve their obstacle problems, else sweeps
    lin.fallback = [this, &q, &zeta](const Vector& z, int sweeps, double tol) {
      Vector zeta_z(z.size()), w;
      if (!outer_ok_ || !levels_.finest->eval_zeta(zeta, z, zeta_z) || !outer_step(q, zeta_z, z))
        return levels_.finest->sweep(q, zeta, z, sweeps, tol);
      Result r;
      r.iterations = 1;
      r.z = outer_z_;
      r.residual = levels_.finest->icp_residual(q, zeta, r.z, zeta_z, w);
      return r;
    };
    Step plain(*levels_.finest, std::move(lin), start);
    if (std::isnan(plain.residual())) return tally_.zeta_failed(z_start, q);
    static const Vector no_shift;
    auto control = obstacle_.finest_control(no_shift, o_.tol, o_.maxiter - tally_.nit(), true);
    control.sweep_budget = o_.maxiter - tally_.fallback_sweeps();
    control.outer_steps = &outer_mode_;
    const auto out = newton_loop(plain, control, start);
    tally_.absorb(out, 0, ScopedTimer::seconds_since(t0));
    if (record.iterations) {
      tally_.count("matrix_free_iterations", record.iterations);
      tally_.count("matrix_free_preconditioner_iterations", record.preconditioner);
    }
    if (!out.jacobian_poor && out.status != Status::Diverged) return no_worse_than_start(out, q, z_start, psi);
    return without_jacobian(q, zeta, z0, out);
  }

 private:
  /// Where ζ′ did not deliver (JacobianCheck) or diverged: the outer fixed point from its best iterate, else from the start.
  Result without_jacobian(const Vector& q, const Z& zeta, const Vector* z0, const LevelOutcome& out) {
    tally_.switch_to_outer();
    Result r = solve_outer_fixed_point(q, zeta, &out.z);
    std::string from;
    if (r.status == Status::Stagnated || r.status == Status::Diverged) {  // (not a callback's stop, nor maxiter)
      Result again = solve_outer_fixed_point(q, zeta, z0);
      if (again.status == Status::Converged || again.residual < r.residual) r = std::move(again), from = ", from the solve's start";
    }
    r.message += "; " + (out.jacobian_poor ? out.message : "the Newton steps with zeta_jacobian diverged") +
                 ", so the solve went on with the outer fixed point without it (path newton+outer" + from + ")";
    return r;
  }
  /// The semismooth loop's result, or the solve's start z_start (ψ = ζ(z_start)) where the loop did not
  /// converge and no iterate of it has a lower Res: its first outer step, S(ζ(z_start)), may lie far from
  /// the answer where ζ′ is large, and the best iterate is the start's.
  Result no_worse_than_start(const LevelOutcome& out, const Vector& q, const Vector& z_start, const Vector& psi) {
    Vector w;
    const double res_start = levels_.finest->icp_residual_at(q, z_start, psi, w);
    if (out.status == Status::Converged || out.residual <= res_start || !std::isfinite(res_start))
      return tally_.finish(out, out.z, q);
    return tally_.finish(z_start, res_start, out.status, start_returned(out.message), q);
  }

  /// The start of an affine or semismooth solve: at most this many Newton steps of the obstacle problem.
  static constexpr int start_maxiter = 100;

  /// The obstacle problem's solution S(ψ) from z (null: zeros, nested when `nest`), from the active
  /// set of the last one, to a settled set; kept with its inactive set (outer_z_, outer_set_): the
  /// semismooth loop's outer steps. `fresh`: ψ = ζ(z), taken afresh a level when nested (the
  /// solution is then S(ζ(z_f)): the start of the Newton steps, wherever it came from).
  /// Returns its Res (of the obstacle problem).
  double outer_solve(const Vector& q, const Vector& psi, const Vector* z, bool nest, int maxiter,
                     RefreshedBounds fresh = {}) {
    Result inner = solve_obstacle(q, psi, z, nest, 0.0, maxiter, false, &outer_set_, nullptr,
                                  nest && fresh.at ? &fresh : nullptr);
    outer_z_.swap(inner.z);
    return inner.residual;
  }
  /// An outer step of the semismooth loop from z, with ψ = ζ(z) given: S(ψ) into outer_z_. Whether
  /// it solved its obstacle problem, to NewtonTuning::outer_trust × Res(z) (an LCP of a matrix that
  /// is no P-matrix may not be solved): outer_ok_.
  bool outer_step(const Vector& q, const Vector& psi, const Vector& z) {
    Vector w;
    const double res_z = levels_.finest->icp_residual_at(q, z, psi, w);  // (+inf where w overflowed: the same test)
    tally_.outer_step();
    const double res_obstacle = outer_solve(q, psi, &z, false, std::max(1, o_.maxiter - tally_.nit()));
    outer_ok_ = !(res_obstacle > NewtonTuning::outer_trust * res_z);
    return outer_ok_;
  }
  /// The bounds of the semismooth loop's outer steps at z: ζ(z), the run's upper bound.
  RefreshedBounds zeta_bounds(const Z& zeta) const {
    return {[this, &zeta](const Vector& z, Vector& lower, Vector& upper) {
      upper = upper_;
      return comm().all(levels_.finest->eval_zeta(zeta, z, lower));
    }};
  }
  /// z is the last outer step's solution (its active set is outer_set_).
  /// (on every process: a step taken on some processes only would leave the others waiting)
  bool is_outer(const Vector& z) const { return comm().all(outer_z_.size() == z.size() && outer_z_ == z); }
  Vector outer_z_;               // the last outer step's solution (semismooth loop)
  std::vector<char> outer_set_;  // its inactive set (the next one starts from it)
  bool outer_ok_ = true;         // the last outer step solved its obstacle problem (the fallback may take one)
  bool outer_mode_ = true;       // outer steps place the Newton steps' sets (NewtonControl::outer_steps)
  std::vector<char> step_set_;   // the last Newton step's set, when its outer step's (empty: the test x ≥ 0's)

  /// The outer fixed point's view of this run (the interface of detail::OuterFixedPoint).
  struct Outer;

  /// The reductions over every process (the finest level's engine).
  const Comm& comm() const { return levels_.finest->comm(); }
  /// Every level records its work into this solve's timings (nullptr: into none).
  void record_into(Timings* tm) const {
    levels_.finest->record_into(tm);
    for (const auto& level : levels_.coarse) level->record_into(tm);
  }

  const NewtonLevels<MatrixType>& levels_;
  const Options& o_;
  const Hooks& hooks_;
  const bool nest_;
  const Vector& upper_;
  NewtonTally<MatrixType> tally_;
  ObstacleSolver<MatrixType> obstacle_;   // every obstacle problem of this solve, tallied into tally_
};

/// The outer fixed point's view of a NewtonRun: its inner obstacle solves, Res of the ICP and the
/// fallback's sweeps, counted in the run's tally.
template <typename MatrixType>
struct NewtonRun<MatrixType>::Outer {
  /// The bounds an outer step freezes at its z: ζ(z), and u(z) when the upper bound is implicit
  /// (else empty: the run's constant one).
  struct Frozen {
    Vector lower, upper;
    explicit Frozen(Eigen::Index n) : lower(n) {}
    void swap(Frozen& o) { lower.swap(o.lower); upper.swap(o.upper); }
  };
  NewtonRun& run;
  const Vector& q;
  const Z& zeta;
  std::vector<char> set;  // the last inner solve's inactive set: the next one starts from it
  Vector w, capped;
  Vector start_z;         // z_f of the first inner solve's nested start, when it moved (moved)
  Frozen start_b{0};      // the bounds taken there
  bool moved = false;
  bool upper_failed = false;  // an implicit u(z) failed (the Monitor ends the solve: ZETA_FAILED)
  const Comm& comm() const { return run.comm(); }
  /// The upper bound of the box frozen in b (empty: none).
  const Vector& upper(const Frozen& b) const { return zeta.implicit_upper() ? b.upper : run.upper_; }
  /// The inner box problem, solved to Res < tol (0: to a settled active set). Without z, it starts
  /// at y = 0 (z = ψ) rather than at z = 0 (docs/MEASUREMENTS.md, "The outer fixed point's inner
  /// solves").
  /// Where the frozen bounds cross (ζ(z) > u(z)) the inner problem takes u as both bounds there,
  /// min(ζ, u) ≤ z ≤ u: the upper bound wins. The box then always has a point, so every outer step
  /// is defined and its Newton member's rules apply unchanged; Res keeps the crossing on those rows
  /// (bounded_residual's term max(z − u, ζ − z) > 0), so a z where the bounds cross by more than tol is
  /// never declared converged (crossing() says why in the message).
  /// The first one, nested, takes the bounds afresh a level (NestedStart::refreshed): it is S at z_f,
  /// and moved_start() makes z_f the iterate it was taken at.
  Result obstacle(const Frozen& b, const Vector* z, bool first, double tol) {
    const Vector& u = upper(b);
    const Vector& lower = u.size() ? (capped = b.lower.cwiseMin(u)) : b.lower;
    const bool nest = first && run.nest_;
    RefreshedBounds fresh{[this](const Vector& v, Vector& lo, Vector& up) { return bounds_at(v, lo, up); }};
    Result inner = run.solve_obstacle(q, lower, z, nest, tol, run.o_.maxiter - run.tally_.nit(), false, &set, &u,
                                      nest && !z ? &fresh : nullptr);  // (a given start: the frozen nest)
    moved = fresh.moved;
    if (moved) start_z.swap(fresh.z);
    run.tally_.outer_step();
    return inner;
  }
  /// After the first inner solve: when its nested start took the bounds at z_f, z becomes z_f, b its
  /// bounds and r its Res (no evaluation of ζ: those of the start), and true.
  bool moved_start(Vector& z, Frozen& b, double& r) {
    if (!moved) return false;
    moved = false;
    z.swap(start_z);
    b.swap(start_b);
    r = run.levels_.finest->icp_residual_at(q, z, b.lower, w, upper(b));
    return true;
  }
  /// The bounds at v into start_b (ζ(v), u(v) when implicit) and as the inner problem's: lo = ζ(v)
  /// capped by the upper bound, up = that bound; false when ζ or u failed (start_b then unchanged).
  bool bounds_at(const Vector& v, Vector& lo, Vector& up) {
    auto& level = *run.levels_.finest;
    Frozen b(v.size());
    if (!comm().all(level.eval_zeta(zeta, v, b.lower))) return false;
    if (zeta.implicit_upper() && !comm().all(level.eval_upper(zeta, v, b.upper))) return false;
    start_b.swap(b);
    up = upper(start_b);
    lo = up.size() ? start_b.lower.cwiseMin(up) : start_b.lower;
    return true;
  }
  /// Res of the mixed problem at v with the bounds at v (an implicit u evaluated there, timed as ζ is).
  double icp_residual(const Vector& v, Frozen& b) {
    auto& level = *run.levels_.finest;
    if (zeta.implicit_upper()) {
      if (!comm().all(v.allFinite())) return std::numeric_limits<double>::infinity();  // a runaway, as for ζ
      upper_failed = !comm().all(level.eval_upper(zeta, v, b.upper));
      if (upper_failed) return std::numeric_limits<double>::quiet_NaN();
    }
    return level.icp_residual(q, zeta, v, b.lower, w, upper(b));
  }
  /// The message part saying where ζ(z) > u(z) at z, every process's rows counted ("" where none
  /// do): no z satisfies both bounds on those rows.
  std::string crossing(const Vector& z) {
    Frozen b(z.size());
    if (!std::isfinite(icp_residual(z, b))) return "";  // (a runaway z, or ζ or u failed: said elsewhere)
    const Vector& u = upper(b);
    double count = 0, most = 0;
    for (Eigen::Index i = 0; i < u.size(); ++i)
      if (b.lower[i] > u[i]) {
        count += 1;
        most = std::max(most, b.lower[i] - u[i]);
      }
    count = comm().sum(count);
    if (count == 0) return "";
    return "; the bounds cross at the returned z: zeta(z) > upper(z) on " + std::to_string(static_cast<long long>(count)) +
           " rows (by up to " + to_text(comm().max(most)) + "), where no z lies between them (each outer step took " +
           "upper(z) as the lower bound there)";
  }
  double rounding_level(const Vector& v, const Frozen& b) const {
    return run.levels_.finest->rounding_level(v, q, v - b.lower, w, upper(b));
  }
  double tol() const { return run.o_.tol; }
  /// (none with an upper bound: the fallback member has no box; the outer loop then ends at its best iterate)
  Result sweep(const Vector& z0, int sweeps) {
    if (zeta.bounded()) {
      Result none;
      none.z = z0;
      none.residual = std::numeric_limits<double>::infinity();
      return none;
    }
    const Result sw = run.levels_.finest->sweep(q, zeta, z0, sweeps, run.o_.tol);
    run.tally_.sweeps(sw.iterations);
    return sw;
  }
  int sweeps_spent() const { return run.tally_.fallback_sweeps(); }
  int sweep_budget() const { return run.o_.maxiter; }
};

}  // namespace nrmicp::detail
