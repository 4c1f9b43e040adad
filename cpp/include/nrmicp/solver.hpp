// nrmicp — Method 3.1 of the paper, written once for every splitting:
//
//   x⁽ᵏ⁺¹⁾ = x⁽ᵏ⁾ + Lm⁻¹ [Ω2(|x⁽ᵏ⁾| − x⁽ᵏ⁾) − γ(A ẑ + q)],   ẑ = ζ(z⁽ᵏ⁾) + Ω1(|x⁽ᵏ⁾| + x⁽ᵏ⁾)/γ,
//
// which is the paper's Lm x⁽ᵏ⁺¹⁾ = (N + φ)Ω1 x⁽ᵏ⁾ + (Ω2 − AΩ1)|x⁽ᵏ⁾| − γAζ(z⁽ᵏ⁾) − γq with
// N = M − A rearranged (no cancellation of large terms). See docs/SPEC.md.
// Bounds lower ≤ z ≤ upper (ζ none or constant): the same iteration on the box problem in
// y = z − s with m(x) = 2 mid(lo', x, hi') − x in place of |x| (detail/modulus.hpp).
//
// The loop (detail::loop below, shared by Solver and the Newton member, newton.hpp) is
//
//   for k = 0, 1, ...:  r = step.evaluate(s);  if (monitor.stop(k, r, s)) break;
//                       step.move_x(s);  if (step.end()) break;  step.update_z(s);
//
// THE STEP INTERFACE. A step is a small type (detail/steps.hpp) with one job: advance the
// iterate s (detail::Iterate: the modulus vector s.x, s.z, ζ(z) in s.zeta_z, ζ(z⁽ᵏ⁻¹⁾) in
// s.zeta_prev, the last step size s.step, s.zeta_ok). It reads the problem from a
// detail::Context (A, q, ζ, the resolved Parameters, the z-update, the timers, and the shared
// operations spmv, eval_zeta, from_modulus, z_update, next_z, residual). It provides
//   double evaluate(Iterate& s)  Res(z⁽ᵏ⁾) of s.z, accumulated with detail::ResidualSum, and
//                                ζ(z⁽ᵏ⁾) in s.zeta_z via ctx.eval_zeta. It may already do the
//                                work of the next step (the one-pass sweep moves s.x and sets
//                                s.step here); it must not depend on being followed by move_x.
//   void move_x(Iterate& s)      s.x ← x⁽ᵏ⁺¹⁾; s.step = ‖x⁽ᵏ⁺¹⁾ − x⁽ᵏ⁾‖∞.
//   void update_z(Iterate& s)    s.z ← z⁽ᵏ⁺¹⁾ (usually ctx.next_z(s); s.z may be stale on entry:
//                                the Monitor may have taken its buffer as the best iterate).
//   const Eigen::VectorXd& dx()  x⁽ᵏ⁺¹⁾ − x⁽ᵏ⁾ of the plain step (Anderson mixes these).
//   void report(Result&) const   extra counters (e.g. linear solves) into Result::counters;
//                                inherit detail::StepBase for none.
//   const StepEnd* end() const   the step's own end of the solve, asked after move_x: null to go
//                                on (detail::StepBase), else the status (and message) that end the
//                                loop at once (detail::Monitor::end). Only rules the Monitor cannot
//                                know belong here: the Newton member ends on a settled active set,
//                                a fallback that brings nothing, or maxiter Newton steps
//                                (detail::Globalized, detail/globalization.hpp).
//   The Newton member's step (detail/newton_step.hpp) works in z: its move_x takes the Newton
//   step (or the fallback) and computes Res of the new z at once (the acceptance test needs it),
//   so its evaluate only returns that Res and sets s.x from w and g.
// Everything else is shared: the stopping rules, the history, the best iterate and the
// Ctrl-C poll live in detail::Monitor (detail/stopping.hpp); Anderson acceleration wraps any
// step (detail::Accelerated, detail/anderson.hpp); Res is defined once (detail/residual.hpp).
//
// ONE LOOP, TWO ENGINES. Solver<MatrixType> runs over any engine's matrix (detail/engine.hpp): an
// Eigen sparse matrix (every row this process's), or petsc::Matrix (petsc/engine.hpp), whose
// processes each own a block of rows. There the member is the modulus-based synchronous
// multisplitting (the paper's reference [49]): each process splits its diagonal block by the serial
// Splitting (so one process takes exactly the serial member's iterates), the couplings to other
// processes' unknowns enter through the global product A ẑ, and every Res, step norm and decision of
// the Monitor is reduced over the processes (detail/comm.hpp). The z-update 'solve' needs a
// factorization of the whole A: serial only.
#pragma once

#include "detail/anderson.hpp"
#include "detail/iterate.hpp"
#include "detail/steps.hpp"
#include "detail/stopping.hpp"
#include "detail/timer.hpp"
#include "inner_solver.hpp"
#include "options.hpp"
#include "result.hpp"
#include "splitting.hpp"
#include "zeta.hpp"

#include <Eigen/SparseCore>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <mutex>
#include <optional>
#include <stdexcept>

namespace nrmicp {

namespace detail {

/// The loop of every member: evaluate Res(z⁽ᵏ⁾), ask the Monitor, step x, then (unless the step
/// ended the solve) update z. The step interface is described at the top of this file.
template <typename Step>
void loop(Step& step, Iterate& s, Monitor& monitor) {
  for (int k = 0;; ++k) {
    const double r = step.evaluate(s);
    if (monitor.stop(k, r, s)) break;
    step.move_x(s);
    if (const StepEnd* end = step.end()) {
      monitor.end(*end);
      break;
    }
    step.update_z(s);
  }
  step.report(monitor.result());
}

}  // namespace detail

/// Set-up (splitting, factorization) once; solve(q, ζ) many times.
/// `A` is held by reference: it must outlive the Solver (as with Eigen's solvers).
template <typename MatrixType>
class Solver {
 public:
  using StorageIndex = typename MatrixType::StorageIndex;
  using Vector = Eigen::VectorXd;
  using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, StorageIndex>;
  /// Called for every iterate with (k, z⁽ᵏ⁾, Res), the last one too; return true to stop.
  using Callback = detail::Callback;
  /// Called about every 50 ms during a solve; may throw to abort (e.g. on Ctrl-C).
  using Poll = detail::Poll;
  /// Progress lines (Options::verbose > 0): (k, Res, best Res, seconds, final message or empty).
  using Progress = detail::Progress;

  Solver(const MatrixType& A, Options options)
      : A_(A), block_(detail::block_of(A)),
        options_(std::move(options)) {
    if (!is_stationary(options_.method))
      throw std::invalid_argument("Solver: method 'newton' is the Newton member: use nrmicp::Newton (newton.hpp), "
                                  "not nrmicp::Solver");
    detail::collective_check(comm(), [&] { using detail::check_operator; check_operator(A); });  // (the engine's layout first)
    detail::collective_check(comm(), [&] {  // (rows and columns are this process's)
      if (A.rows() != A.cols())
        throw std::invalid_argument("Solver: A must be square, got " + std::to_string(A.rows()) + "x" +
                                    std::to_string(A.cols()));
      options_.check(A.rows(), detail::Engine<MatrixType>::serial);
    });
    const auto t0 = std::chrono::steady_clock::now();
    detail::collective_check(comm(), [&] {  // (Ω2 = diag(A) and the splitting read this process's rows)
      params_ = resolve_parameters(A, options_);
      detail::ScopedTimer t(setup_factorization_);
      splitting_.emplace(block_, options_.method, params_, options_.inner);
    });
    // given on any process (one without rows holds an empty Ω2): z_update 'auto' then resolves alike on all
    omega2_given_ = !comm().all(options_.omega2.size() == 0);
    if (options_.z_update == ZUpdate::Solve) factorize_A();
    setup_timings_.setup = detail::ScopedTimer::seconds_since(t0);
    setup_timings_.factorization = setup_factorization_ + a_factorization_;
  }

  /// The constructor's seconds: setup (parameters, splitting, factorizations) and the
  /// factorization part of it. A solve's Result::timings count only that solve's call (result.hpp).
  const Timings& setup_timings() const { return setup_timings_; }

  const Options& options() const { return options_; }
  const Parameters& parameters() const { return params_; }
  const char* inner_name() const { return splitting_->inner_name(); }
  const Splitting<StorageIndex>& splitting() const { return *splitting_; }

  /// Solves ICP(q, A, ζ) from the initial guess z0 (zeros when null). `solve_options`, when
  /// given, replace the constructor's per-solve options (the splitting stays); the merged
  /// options are checked against the method.
  Result solve(const Vector& q, const Zeta<StorageIndex>& given = Zeta<StorageIndex>::none(),
               const Vector* z0 = nullptr, const Callback& callback = {}, const Poll& poll = {},
               const SolveOptions* solve_options = nullptr, const Progress& progress = {}) const {
    const auto t0 = std::chrono::steady_clock::now();
    const Eigen::Index n = A_.rows();
    Options o = options_;
    detail::collective_check(comm(), [&] {
      if (solve_options) o = options_.with(solve_options, n);
      detail::check_solve_input("Solver::solve", q, z0, given, n);
      check_bounds(given);
    });
    const auto agreed = detail::agree_upper(given, n, comm());
    const Zeta<StorageIndex>& zeta = agreed ? *agreed : given;
    resolve_tolerance(o, q, zeta, comm());
    Result r;
    if (comm().any(zeta.bounded())) {  // (a free row on one process: the box problem on all)
      r = solve_box(q, zeta, z0, {callback, poll, progress}, o);
    } else if (zeta.kind() == ZetaKind::Constant) {
      // ζ ≡ c: LCP(q + Ac, A) in y = z − c. Res and w are the same in both variables.
      Vector q_shift = q;
      add_product(zeta.c(), q_shift);
      // y0 = z0 − c (z0 = 0 by default), so that the iterates are exactly those of the ICP.
      const Vector y0 = z0 ? Vector(*z0 - zeta.c()) : Vector(-zeta.c());
      r = iterate(q_shift, Zeta<StorageIndex>::none(), &y0, {callback, poll, progress}, o, zeta.c());
      r.z += zeta.c();
    } else {
      r = iterate(q, zeta, z0, {callback, poll, progress}, o, Vector());
    }
    r.timings.total = detail::ScopedTimer::seconds_since(t0);
    r.inner = splitting_->inner_name();
    return r;
  }

 private:
  void factorize_A() const {
    if constexpr (!detail::Engine<MatrixType>::serial) {
      throw std::invalid_argument(
          "Solver: z_update 'solve' (the paper's Step 1, a solve with A; what 'auto' means for method 'nrm' on an "
          "ICP with omega2 = I, and for 'mms') needs a factorization of the whole A, which the distributed "
          "engine does not have: use z_update='explicit'");
    } else {
      std::lock_guard<std::mutex> lock(a_mutex_);
      if (a_solver_.ready()) return;
      detail::ScopedTimer t(a_factorization_);
      a_solver_.compute(ColMatrix(A_), options_.inner, "A (for the z-update 'solve')");
    }
  }
  /// out += A v (the engine's product).
  void add_product(const Vector& v, Vector& out) const {
    using detail::multiply_add;
    multiply_add(A_, v, out);
  }
  /// The processes that own the other rows (serial_comm() for an Eigen matrix).
  const detail::Comm& comm() const {
    using detail::comm_of;
    return comm_of(A_);
  }

  using Hooks = detail::Hooks;

  /// The bounds the modulus members take: constant ones, with ζ none or constant.
  static void check_bounds(const Zeta<StorageIndex>& zeta) {
    if (!zeta.bounded()) return;
    if (zeta.implicit_upper())
      throw std::invalid_argument("Solver: an implicit upper bound (affine or functor) is solved by the Newton member "
                                  "(nrmicp::Newton, its outer fixed point); the modulus members take a constant upper bound");
    if (zeta.kind() == ZetaKind::Affine || zeta.kind() == ZetaKind::Functor)
      throw std::invalid_argument("Solver: an affine or functor zeta with an upper bound is solved by the Newton member "
                                  "(nrmicp::Newton, its outer fixed point); the modulus members take bounds with zeta "
                                  "none or constant");
  }

  // Bounds (ζ none or constant lower, upper): the box problem in y = z − s, q' = q + As, started
  // from y0 = z0 − s as the constant obstacle's LCP is; m(x) replaces |x| (detail/modulus.hpp).
  Result solve_box(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector* z0, const Hooks& hooks,
                   const Options& o) const {
    const detail::BoxModulus box(zeta.kind() == ZetaKind::Constant ? zeta.c() : Vector(), zeta.upper(),
                                 params_.omega1, params_.gamma);
    Vector q_shift = q;
    add_product(box.s, q_shift);
    const Vector y0 = z0 ? Vector(*z0 - box.s) : Vector(-box.s);
    Result r = iterate(q_shift, Zeta<StorageIndex>::none(), &y0, hooks, o, box.s, &box);
    r.z = detail::unshift(r.z, box.s, zeta.upper().size() ? box.box.hi : Vector(), zeta.upper());
    return r;
  }

  // One solve of ICP(q, A, ζ) by Method 3.1. `shift` is the constant obstacle (only to report
  // z to the callback), or empty; `box` the box problem's modulus (ζ is then none), or null.
  Result iterate(const Vector& q, const Zeta<StorageIndex>& zeta, const Vector* z0, const Hooks& hooks,
                 const Options& o, const Vector& shift, const detail::BoxModulus* box = nullptr) const {
    const ZUpdate zu = resolve_z_update(o.z_update, options_.method, omega2_given_,
                                        zeta.kind() != ZetaKind::None);
    Result res;
    if (zu == ZUpdate::Solve) {
      const double before = a_factorization_;
      factorize_A();
      res.timings.factorization += a_factorization_ - before;  // only if this solve paid for it
      res.timings.setup += a_factorization_ - before;          // a lazy set-up, before the loop
    }
    detail::Context<MatrixType> ctx(A_, q, zeta, params_, zu, a_solver_, res.timings);
    ctx.box = box;
    detail::Monitor monitor(o, hooks.callback, hooks.poll, hooks.progress, shift, res, A_.rows());
    monitor.reduce_with(ctx.comm);
    detail::Iterate s;
    if (!ctx.start(z0, s)) {
      res.status = Status::ZetaFailed;
      res.z = s.z;
      res.w = q;
      add_product(s.z, res.w);
      res.residual = std::numeric_limits<double>::quiet_NaN();
      res.message = std::string(to_string(res.status)) + " at the initial guess";
      return res;
    }
    run_steps(ctx, s, monitor, o);
    monitor.finish(z0 ? *z0 : Vector::Zero(A_.rows()), ctx.start_residual);
    Vector Az(A_.rows());
    ctx.spmv(res.z, Az);  // w of the returned iterate (honest even if it is not the last one)
    res.timings.iterations = monitor.seconds();  // its product counted in spmv: inside the loop's time
    res.w = Az + q;
    detail::refuse_overflow(res);
    return res;
  }

  // Picks the step for the method: the one-pass sweep for the AOR-type members with the explicit
  // update on a row-major A, the two-sweep step, or the generic splitting step. (The Newton
  // member's step runs in the same detail::loop, driven by nrmicp::Newton: it has its own set-up.)
  void run_steps(detail::Context<MatrixType>& ctx, detail::Iterate& s, detail::Monitor& monitor,
                 const Options& o) const {
    const bool two_sweep = splitting_->two_sweep();
    if constexpr (MatrixType::IsRowMajor) {
      if (is_aor_type(options_.method) && !two_sweep && ctx.zu == ZUpdate::Explicit) {
        detail::SweepStep<MatrixType> step(ctx, *splitting_);
        return run(step, ctx, s, monitor, o);
      }
    }
    if (two_sweep) {
      detail::TwoSweepStep<MatrixType> step(ctx, *splitting_, o.theta, s);
      return run(step, ctx, s, monitor, o);
    }
    detail::SplittingStep<MatrixType> step(ctx, *splitting_);
    run(step, ctx, s, monitor, o);
  }

  // Method 3.1: evaluate Res(z⁽ᵏ⁾), ask the Monitor, step x, update z (with Anderson if asked).
  template <typename Step>
  static void run(Step& step, detail::Context<MatrixType>& ctx, detail::Iterate& s, detail::Monitor& monitor,
                  const Options& o) {
    if (o.accelerate == Accelerate::Anderson) {
      detail::Accelerated<Step, detail::Context<MatrixType>> accelerated(step, ctx, o.anderson_m);
      return detail::loop(accelerated, s, monitor);
    }
    detail::loop(step, s, monitor);
  }

  // The matrix each process splits: A itself serially (a reference), else its diagonal block (a view).
  using Block = decltype(detail::block_of(std::declval<const MatrixType&>()));

  const MatrixType& A_;
  Block block_;
  Options options_;
  bool omega2_given_ = false;  // Ω2 given (on any process)
  Parameters params_;
  std::optional<Splitting<StorageIndex>> splitting_;
  Timings setup_timings_;
  double setup_factorization_ = 0;
  mutable std::mutex a_mutex_;
  mutable InnerSolver<StorageIndex> a_solver_;
  mutable double a_factorization_ = 0;
};

/// One call: set up and solve.
template <typename MatrixType>
Result solve(const MatrixType& A, const Eigen::VectorXd& q,
             const Zeta<typename MatrixType::StorageIndex>& zeta = Zeta<typename MatrixType::StorageIndex>::none(),
             const Options& options = Options(), const Eigen::VectorXd* z0 = nullptr) {
  return Solver<MatrixType>(A, options).solve(q, zeta, z0);
}

}  // namespace nrmicp
